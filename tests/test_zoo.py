"""rl-zoo3 integration: YAML entries, launchers (train, enjoy, resume), normalised scores, shared-storage optimize."""

from __future__ import annotations

import argparse
import os
import pathlib
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import yaml
from helpers import record_random_dataset

pytest.importorskip("rl_zoo3")
pytest.importorskip("optuna")

from sb3_pola import cli, zoo
from sb3_pola.pola.pola import POLA

REPO = pathlib.Path(__file__).resolve().parent.parent
CONFIG = zoo.default_config()  # sb3_pola/hyperparams/pola.yml, installed with the package
DATASET = "testpend/random-v0"  # env id == dataset id (one slash)
REF_MIN, REF_MAX = 0.0, 100.0
# keeps every run tiny: 2 critics, small nets, a 1-epoch 2-member dynamics model
LIGHT_PARAMS = [
    "-params",
    "n_critics:2",
    "batch_size:32",
    "policy_kwargs:dict(net_arch=[16, 16])",
    "dynamics_kwargs:dict(n_members=2, n_elites=1, hidden_dim=16, n_layers=2)",
    "dynamics_fit_kwargs:dict(max_epochs=1)",
]


def write_env_dataset(root: pathlib.Path, dataset_id: str, env_id: str, n_steps: int, seed: int = 0) -> None:
    """A random-action Minari dataset recorded in a real env (so it carries an ``env_spec``), with reference scores."""
    record_random_dataset(root, dataset_id, env_id, n_steps, seed=seed, ref_scores=(REF_MIN, REF_MAX))


@pytest.fixture(scope="module")
def pendulum_root(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    root = tmp_path_factory.mktemp("zoo_minari")
    write_env_dataset(root, DATASET, "InvertedPendulum-v5", n_steps=300)
    return root


@pytest.fixture
def pendulum(pendulum_root: pathlib.Path, monkeypatch: pytest.MonkeyPatch, tmp_path: pathlib.Path) -> pathlib.Path:
    """MINARI_DATASETS_PATH on the pendulum dataset; runs in a fresh working folder, which is returned."""
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(pendulum_root))
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    monkeypatch.chdir(tmp_path)
    return tmp_path


# ----------------------------------------------------------------------------- naming


def test_env_id_mapping() -> None:
    assert zoo.env_id_for_dataset("halfcheetah/medium-v0") == "halfcheetah/medium-v0"
    assert zoo.env_id_for_dataset("mujoco/hopper/medium-v0") == "mujoco-hopper/medium-v0"
    assert zoo.env_id_for_dataset("D4RL/pen/human-v2") == "D4RL-pen/human-v2"
    with pytest.raises(gym.error.Error):
        zoo.env_id_for_dataset("bad id with spaces")


def test_zoo_arguments_defaults() -> None:
    args = zoo.zoo_arguments("optimize", ["--env", "a/b-v0"])
    assert args[:2] == ["--algo", "pola"] and "-optimize" in args
    assert args[args.index("-conf") + 1] == str(CONFIG)
    # user-given values are kept
    args = zoo.zoo_arguments("train", ["--algo", "sac", "-conf", "x.yml"])
    assert args.count("--algo") == 1 and args[args.index("-conf") + 1] == "x.yml"
    assert "-conf" not in zoo.zoo_arguments("enjoy", ["--env", "a/b-v0"])


def test_dataset_env_is_the_datasets_env(pendulum: pathlib.Path) -> None:
    zoo.register_dataset_envs()
    assert zoo.dataset_for_env(DATASET) == DATASET
    env = gym.make(DATASET)
    assert env.action_space.shape == (1,) and env.observation_space.shape == (4,)
    assert env.unwrapped.__class__.__name__ == "InvertedPendulumEnv"
    env.close()
    # a known dataset that is not on disk falls back to its family's env
    assert zoo.dataset_for_env("mujoco-hopper/medium-v0") == "mujoco/hopper/medium-v0"
    env = gym.make("mujoco-hopper/medium-v0")
    assert env.unwrapped.__class__.__name__ == "HopperEnv"
    env.close()


# ----------------------------------------------------------------------------- YAML


def yaml_entries() -> list[str]:
    return [key for key in yaml.safe_load(CONFIG.read_text()) if not key.startswith("x-")]


def test_yaml_has_every_table_one_task() -> None:
    config = yaml.safe_load(CONFIG.read_text())
    datasets = {entry.get("dataset") for entry in config.values() if isinstance(entry, dict)}
    for env in ("halfcheetah", "hopper", "walker2d"):
        assert f"mujoco/{env}/medium-v0" in datasets  # Minari publishes medium
        for kind in ("medium-expert", "medium-replay", "random"):
            assert f"{env}/{kind}-v1" in datasets  # made by `sb3-pola collect`
    for key, entry in config.items():
        if "dataset" in entry:
            assert zoo.env_id_for_dataset(entry["dataset"]) == key, key
    assert "default" in config and "invertedpendulum/medium-v0" in config


def test_yaml_paper_entries_are_the_papers_form_and_light_ones_the_package_defaults() -> None:
    """Table I's entries run the paper's form (``PAPER_FORM``, #23: also its ``eta = 1`` and eq. 3's weights); the
    light CPU entries leave every choice of ``PAPER_FORM`` and ``eta`` to the package defaults."""
    from sb3_pola import PAPER_FORM

    config = yaml.safe_load(CONFIG.read_text())
    for key in ("mujoco-hopper/medium-v0", "halfcheetah/medium-replay-v1"):
        assert {k: config[key][k] for k in PAPER_FORM} == PAPER_FORM, key
    for key in ("default", "invertedpendulum/medium-v0"):
        assert not set(config[key]) & (set(PAPER_FORM) | {"eta"}), key


@pytest.mark.parametrize("env_id", yaml_entries())
def test_yaml_entry_builds_model(env_id: str, tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each entry goes through the zoo's own parsing and builds POLA on a tiny stand-in of its dataset."""
    from rl_zoo3.exp_manager import ExperimentManager  # noqa: F401  (the zoo must import)

    zoo.register_pola()
    manager_cls = zoo._manager_class()
    config = yaml.safe_load(CONFIG.read_text())
    dataset_id = config[env_id].get("dataset", "stand-in/default-v0")
    family_env = zoo._family_env(dataset_id) or "InvertedPendulum-v5"
    root = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    write_env_dataset(root, dataset_id, family_env, n_steps=20)
    zoo.register_dataset_envs(config=CONFIG)
    if env_id == "default":
        env_id = zoo.register_dataset_env(dataset_id)

    manager = manager_cls(argparse.Namespace(), "pola", env_id, str(tmp_path / "logs"), config=str(CONFIG))
    hyperparams, saved = manager.read_hyperparameters()
    assert hyperparams["dataset"] == saved["dataset"] == dataset_id
    hyperparams, _, _, _ = manager._preprocess_hyperparams(hyperparams)
    env = manager.create_envs(1, no_log=True)
    model = POLA(env=env, seed=0, device="cpu", **hyperparams)
    entry = {**config[env_id if env_id in config else "default"]}
    for key in ("n_critics", "top_k", "rollout_length", "eta", "max_grad_norm"):
        if key in entry:
            assert getattr(model, key) == entry[key], key
    assert model.dataset == dataset_id
    assert model.ref_min_score == REF_MIN
    action, _ = model.predict(env.reset(), deterministic=True)
    assert action.shape == (1, *env.action_space.shape)
    env.close()


# ----------------------------------------------------------------------------- launchers


def scalars(tb_dir: pathlib.Path, tag: str) -> dict[int, float]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    values: dict[int, float] = {}
    for events in tb_dir.rglob("events.out.tfevents.*"):
        accumulator = EventAccumulator(str(events.parent))
        accumulator.Reload()
        if tag in accumulator.Tags()["scalars"]:
            values.update({event.step: event.value for event in accumulator.Scalars(tag)})
    return values


def test_train_enjoy_resume(pendulum: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    common = ["--env", DATASET, "-f", "logs", "--seed", "0", *LIGHT_PARAMS]
    status = cli.main(
        ["train", *common, "-n", "200", "--eval-freq", "100", "--eval-episodes", "2", "--save-freq", "100", "-tb", "tb", "-P"]
    )
    assert status == 0
    run = pendulum / "logs" / "pola" / "testpend-random-v0_1"
    assert (run / "testpend-random-v0.zip").is_file() and (run / "best_model.zip").is_file()
    assert (run / "rl_model_100_steps.zip").is_file() and (run / "rl_model_200_steps.zip").is_file()
    config = yaml.load((run / "testpend-random-v0" / "config.yml").read_text(), Loader=yaml.UnsafeLoader)
    assert config["dataset"] == DATASET  # injected from --env, saved for reproduction

    # normalised score: in the eval table, in evaluations.npz, in tensorboard at the eval steps
    out = capsys.readouterr().out
    assert "eval/" in out and "normalized_score" in out
    log = np.load(run / "evaluations.npz")
    assert list(log["timesteps"]) == [100, 200]
    np.testing.assert_allclose(log["normalized_scores"], 100 * (log["results"] - REF_MIN) / (REF_MAX - REF_MIN))
    tb_scores = scalars(pendulum / "tb", "eval/normalized_score")
    tb_rewards = scalars(pendulum / "tb", "eval/mean_reward")
    assert sorted(tb_scores) == sorted(tb_rewards) == [100, 200]
    assert tb_scores[200] == pytest.approx(100 * (tb_rewards[200] - REF_MIN) / (REF_MAX - REF_MIN), rel=1e-5)

    # enjoy the final model and a checkpoint
    assert cli.main(["enjoy", "--env", DATASET, "-f", "logs", "--no-render", "-n", "200", "--deterministic"]) == 0
    out = capsys.readouterr().out
    assert "Loading logs/pola/testpend-random-v0_1/testpend-random-v0.zip" in out and "Mean reward" in out
    assert cli.main(["enjoy", "--env", DATASET, "-f", "logs", "--no-render", "-n", "20", "--load-checkpoint", "100"]) == 0
    assert "rl_model_100_steps.zip" in capsys.readouterr().out

    # resume with -i: a new run that continues the step count of the loaded model
    trained = run / "testpend-random-v0.zip"
    assert cli.main(["train", *common, "-n", "50", "--eval-freq", "-1", "-i", str(trained), "--save-replay-buffer"]) == 0
    assert "--save-replay-buffer ignored" in capsys.readouterr().out
    resumed_run = pendulum / "logs" / "pola" / "testpend-random-v0_2"
    assert not (resumed_run / "replay_buffer.pkl").exists()
    before, after = POLA.load(trained), POLA.load(resumed_run / "testpend-random-v0.zip")
    assert before.num_timesteps == 200 and after.num_timesteps == 250 and after._n_updates == 250
    assert bool(after.policy.dynamics_fitted)
    changed = [
        not np.allclose(p.detach().numpy(), q.detach().numpy())
        for p, q in zip(before.policy.actor.parameters(), after.policy.actor.parameters(), strict=True)
    ]
    assert any(changed)  # it trained from the loaded weights


def test_unknown_command_and_env(pendulum: pathlib.Path) -> None:
    assert zoo.main(["fly"]) == 2
    with pytest.raises(ValueError, match="'nothere/none-v0' is neither a local dataset nor a Gymnasium env"):
        zoo.main(["train", "--env", "nothere/none-v0", "-f", "logs"])  # sb3-pola prints it as one line


# ----------------------------------------------------------------------------- optimize


@pytest.mark.slow  # two Optuna workers; the sampler and launch: test_train_enjoy_resume, test_yaml_entry_builds_model
def test_optimize_two_workers_share_a_study(pendulum: pathlib.Path) -> None:
    import optuna

    storage = pendulum / "study" / "optuna.log"  # JournalFileBackend: safe for concurrent processes
    command = [
        sys.executable, "-m", "sb3_pola.zoo", "optimize",
        "--env", DATASET, "-f", "logs", "-n", "30", "--n-trials", "1", "--n-evaluations", "1",
        "--eval-episodes", "1", "--sampler", "random", "--pruner", "none", "--no-optim-plots",
        "--storage", str(storage), "--study-name", "pola-test", "--verbose", "0", *LIGHT_PARAMS,
    ]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    workers = [
        subprocess.Popen([*command, "--seed", str(seed)], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for seed in (1, 2)
    ]
    outputs = [worker.communicate(timeout=240)[0] for worker in workers]
    for worker, output in zip(workers, outputs, strict=True):
        assert worker.returncode == 0, output[-3000:]

    study = optuna.load_study(
        study_name="pola-test",
        storage=optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(storage))),
    )
    trials = study.get_trials(states=[optuna.trial.TrialState.COMPLETE])
    assert len(trials) == 2
    assert len({trial.user_attrs["worker"] for trial in trials}) == 2  # one trial from each process
    for trial in trials:
        assert set(trial.params) == {"rollout_length", "eta", "n_critics", "top_k", "learning_rate", "n_diffusion_steps"}
        assert trial.user_attrs["normalized_score"] == pytest.approx(100 * (trial.value - REF_MIN) / (REF_MAX - REF_MIN))
    # --trial-id loading converts the parameters back into POLA arguments
    params = zoo.convert_pola_params(trials[0].params)
    assert params["top_k"] <= params["n_critics"]


def test_hyperparameter_file_has_no_repeated_key() -> None:
    """YAML loaders keep the last of a repeated key silently: a key written twice in pola.yml is an editing slip."""

    def check(node: yaml.Node, where: str) -> None:
        if isinstance(node, yaml.MappingNode):
            keys = [key.value for key, _ in node.value if isinstance(key, yaml.ScalarNode)]
            assert len(keys) == len(set(keys)), (where, sorted(k for k in keys if keys.count(k) > 1))
            for key, value in node.value:
                check(value, f"{where}/{getattr(key, 'value', '?')}")
        elif isinstance(node, yaml.SequenceNode):
            for item in node.value:
                check(item, where)

    check(yaml.compose(CONFIG.read_text()), str(CONFIG.name))
