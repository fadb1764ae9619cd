"""Saving and loading: clear errors for missing, truncated, corrupt and foreign files and for an env of other spaces."""

from __future__ import annotations

import json
import pathlib
import zipfile

import gymnasium as gym
import pytest
from soak import LIGHT_CONFIG, make_light_model

from sb3_pola.common.integrity import ModelFileError
from sb3_pola.pola.pola import POLA

make_model = make_light_model


@pytest.fixture
def saved_model(tiny_dataset: str, tmp_path: pathlib.Path) -> tuple[POLA, pathlib.Path]:
    model = make_model(tiny_dataset).learn(3)
    path = tmp_path / "model.zip"
    model.save(path)
    return model, path


def test_load_missing_file(tmp_path: pathlib.Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"No model file at .*nothing"):
        POLA.load(tmp_path / "nothing")


@pytest.mark.parametrize("keep", [0.0, 0.5, 0.99])
def test_load_truncated_file(saved_model, keep: float) -> None:
    _, path = saved_model
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(ModelFileError, match="truncated or corrupt zip"):
        POLA.load(path)


def test_load_corrupt_member(saved_model) -> None:
    _, path = saved_model
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo("policy.pth")
    data = bytearray(path.read_bytes())
    offset = info.header_offset + 30 + len(info.filename) + len(info.extra) + info.compress_size // 2
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(ModelFileError, match=r"corrupt|not a valid"):
        POLA.load(path)


def test_load_foreign_zip(tmp_path: pathlib.Path) -> None:
    path = tmp_path / "foreign.zip"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("hello.txt", "not a model")
    with pytest.raises(ModelFileError, match=r"not a saved POLA model file: it has no data, policy\.pth"):
        POLA.load(path)


def test_load_other_algorithm(tmp_path: pathlib.Path) -> None:
    from stable_baselines3 import TD3

    path = tmp_path / "td3.zip"
    TD3("MlpPolicy", "Pendulum-v1", policy_kwargs=dict(net_arch=[8]), device="cpu").save(path)
    with pytest.raises(ModelFileError, match="policy TD3Policy, not a POLA model"):
        POLA.load(path)


def test_load_onto_env_with_other_spaces(saved_model) -> None:
    _, path = saved_model
    env = gym.make("Pendulum-v1")
    with pytest.raises(
        ValueError, match=r"model has observation space Box.*\(3,\).*the env has observation space Box.*\(3,\)"
    ):
        POLA.load(path, env=env)


def test_check_finite_freq_is_a_saved_hyperparameter(tiny_dataset: str, tmp_path: pathlib.Path) -> None:
    assert make_model(tiny_dataset).check_finite_freq == 100  # the default
    model = make_model(tiny_dataset, check_finite_freq=7)
    assert model.check_finite_freq == 7
    model.save(tmp_path / "model.zip")
    assert POLA.load(tmp_path / "model.zip", device="cpu").check_finite_freq == 7
    with pytest.raises(ValueError, match="check_finite_freq"):
        make_model(tiny_dataset, check_finite_freq=-1)


def test_actor_activation_is_the_actors_own_and_saved(tiny_dataset: str, tmp_path: pathlib.Path) -> None:
    from torch import nn

    def kinds(module: nn.Module) -> set[type]:
        return {type(m) for m in module.modules()}

    # the default (#23): the raw state and ReLU; with the paper's products, the critics' activation_fn
    default = make_model(tiny_dataset).policy
    assert not default.use_state_products and nn.ReLU in kinds(default.actor) and nn.ReLU in kinds(default.actor_ema)
    assert nn.ReLU not in kinds(make_model(tiny_dataset, use_state_products=True).policy.actor)
    mish = {**LIGHT_CONFIG.get("policy_kwargs", {}), "actor_activation_fn": nn.Mish}
    assert nn.ReLU not in kinds(make_model(tiny_dataset, policy_kwargs=mish).policy.actor)  # named: kept
    policy_kwargs = {**LIGHT_CONFIG.get("policy_kwargs", {}), "actor_activation_fn": nn.ReLU}
    model = make_model(tiny_dataset, policy_kwargs=policy_kwargs).learn(3)
    assert nn.ReLU in kinds(model.policy.actor) and nn.Mish not in kinds(model.policy.actor)
    assert nn.ReLU in kinds(model.policy.actor_ema)
    assert nn.ReLU not in kinds(model.policy.critic)  # the critics keep activation_fn
    model.save(tmp_path / "model.zip")
    loaded = POLA.load(tmp_path / "model.zip", device="cpu")
    assert nn.ReLU in kinds(loaded.policy.actor) and nn.ReLU not in kinds(loaded.policy.critic)
    obs = model.policy.observation_space.sample()[None]
    assert (model.predict(obs, deterministic=True)[0] == loaded.predict(obs, deterministic=True)[0]).all()


def test_saved_data_holds_no_network(saved_model) -> None:
    """The file's JSON part keeps hyperparameters and spaces only: the networks are in ``policy.pth``, and what
    ``_setup_model`` rebuilds (the chain's sampler holds the actor) must not be pickled into it as well."""
    _, path = saved_model
    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data"))
    pickled = {
        key: len(value[":serialized:"]) for key, value in data.items() if isinstance(value, dict) and ":serialized:" in value
    }
    assert "policy_class" in pickled and max(pickled.values()) < 16_000, pickled  # the light model's actor pickled: ~70 kB


def test_file_from_before_an_argument_loads_with_its_default(saved_model, tmp_path: pathlib.Path) -> None:
    """A file saved before an argument existed has no key for it: loading runs ``__init__`` first, so the model gets
    the argument's default (no ``getattr`` fallback needed where the argument is read) and trains."""
    _, path = saved_model
    newer = {"q_term_confidence": "auto", "lookahead_trust_margin": None, "lookahead_trust_rule": "value"}
    newer |= {"bc_learning_rate": None, "dynamics_cache": True, "bc_top_fraction": "auto"}
    old_path = tmp_path / "old.zip"
    with zipfile.ZipFile(path) as source, zipfile.ZipFile(old_path, "w") as target:
        for item in source.infolist():
            content = source.read(item.filename)
            if item.filename == "data":
                data = json.loads(content)
                assert newer.keys() <= data.keys()
                content = json.dumps({k: v for k, v in data.items() if k not in newer}).encode()
            target.writestr(item, content)
    model = POLA.load(old_path, device="cpu")
    assert {key: getattr(model, key) for key in newer} == newer
    model.learn(2)
