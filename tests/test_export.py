"""``export_policy`` / ``sb3-pola export``: the exported graphs reproduce ``predict(obs, deterministic=True)``."""

from __future__ import annotations

import importlib.util
import json
import os
import pathlib
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from sb3_pola import POLA
from sb3_pola.benchmarks import export_bench
from sb3_pola.benchmarks.bench import format_tables
from sb3_pola.cli import main as cli_main
from sb3_pola.cli.run import LIGHT_CONFIG, PAPER_CONFIG
from sb3_pola.pola.export import DeterministicPolicyGraph, PolicyExportError, export_policy
from sb3_pola.pola.policies import POLAPolicy

# the light CPU configuration and the paper's (3 x 256 networks, N = 10, state products on); untrained weights
CONFIGS = {
    "light": LIGHT_CONFIG,
    "paper": {**PAPER_CONFIG, "policy_kwargs": {"net_arch": [256, 256, 256]}},
    "mode": {**LIGHT_CONFIG, "policy_kwargs": {**LIGHT_CONFIG.get("policy_kwargs", {}), "deterministic_rule": "mode"}},
}
ATOL = 1e-5


def _perturb(model: POLA, seed: int) -> None:
    """Move the online actor away from its EMA copy, so exporting the wrong one would show."""
    generator = th.Generator().manual_seed(seed)
    with th.no_grad():
        for param in model.actor.parameters():
            param.add_(0.02 * th.randn(param.shape, generator=generator))


@pytest.fixture(scope="module")
def models(tiny_datasets_root: pathlib.Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, POLA]:
    """POLA models of every configuration on the tiny dataset (3 observation dims, action bounds [-2, 2] x [0, 4])."""
    mp = pytest.MonkeyPatch()  # module scope: the autouse isolation fixture has not run yet
    mp.setenv("MINARI_DATASETS_PATH", str(tiny_datasets_root))
    mp.setenv("SB3_POLA_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
    try:
        models = {
            name: POLA("MlpPolicy", dataset="test/tiny-v0", seed=0, device="cpu", **config) for name, config in CONFIGS.items()
        }
    finally:
        mp.undo()
    for model in models.values():
        _perturb(model, seed=1)
        model.policy.actor_ema.load_state_dict(model.actor.state_dict())
        _perturb(model, seed=2)
    return models


@pytest.fixture(scope="module", params=sorted(CONFIGS))
def model(request, models: dict[str, POLA]) -> POLA:
    return models[request.param]


@pytest.fixture(scope="module")
def observations(models: dict[str, POLA]) -> np.ndarray:
    """Dataset observations and observations outside the data (3 and 30 standard deviations: clipped actions for
    the actor on the products and for the one on the raw state), float32."""
    model = next(iter(models.values()))  # all on the same dataset
    data = model._offline_data.observations[:40]
    mean, std = model._offline_data.obs_stats()
    noise = np.random.default_rng(0).standard_normal((24, data.shape[1]))
    far = mean + np.where(np.arange(24)[:, None] < 16, 3.0, 30.0) * std * noise
    return np.concatenate([data, far]).astype(np.float32)


@pytest.fixture(scope="module")
def onnx_path(model: POLA, tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    pytest.importorskip("onnxruntime")
    return model.export_policy(tmp_path_factory.mktemp("onnx") / "policy.onnx")


def _session(path: pathlib.Path):
    import onnxruntime as ort

    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


def test_graph_has_the_predict_actor_and_its_steps(model: POLA):
    graph = DeterministicPolicyGraph(model.policy)
    assert graph.n_diffusion_steps == model.policy.n_diffusion_steps
    assert graph.use_state_products == model.policy.use_state_products  # light: the defaults' raw state; paper: products
    assert {type(m) for m in graph.activations} == {th.nn.Mish if model.policy.use_state_products else th.nn.ReLU}
    assert th.equal(graph.obs_mean, model.policy.features_extractor.obs_mean)
    assert not th.equal(model.policy.actor_ema.input_layer.weight, model.actor.input_layer.weight)  # the fixture differs them


def test_onnx_matches_predict_on_a_batch_and_single_observations(model: POLA, onnx_path: pathlib.Path, observations):
    session = _session(onnx_path)
    (inp,), (out,) = session.get_inputs(), session.get_outputs()
    assert (inp.name, out.name) == ("obs", "action")
    assert isinstance(inp.shape[0], str) and inp.shape[1:] == [observations.shape[1]]  # dynamic batch
    assert isinstance(out.shape[0], str) and out.shape[1:] == [2]

    expected, _ = model.predict(observations, deterministic=True)
    actions = session.run(None, {"obs": observations})[0]
    assert actions.shape == expected.shape
    np.testing.assert_allclose(actions, expected, rtol=0, atol=ATOL)
    assert (actions == model.action_space.low).any() or (actions == model.action_space.high).any()  # clip reached
    for obs in observations[[0, 7, 45]]:
        single, _ = model.predict(obs, deterministic=True)
        np.testing.assert_allclose(session.run(None, {"obs": obs[None]})[0][0], single, rtol=0, atol=ATOL)


# the TorchScript file alone in a fresh interpreter: no sb3_pola, no training code
_FRESH_PROCESS = """
import sys
import numpy as np
import torch
obs = np.load(sys.argv[1])
for path in sys.argv[2:]:
    policy = torch.jit.load(path)
    with torch.no_grad():
        batch = policy(torch.from_numpy(obs)).numpy()
        single = np.stack([policy(torch.from_numpy(o[None])).numpy()[0] for o in obs[:3]])
    np.savez(path + ".npz", batch=batch, single=single)
assert "sb3_pola" not in sys.modules
"""


def test_torchscript_in_a_fresh_process_matches_predict(models: dict[str, POLA], observations, tmp_path: pathlib.Path):
    paths = [str(model.export_policy(tmp_path / f"{name}.pt", format="torchscript")) for name, model in models.items()]
    np.save(tmp_path / "obs.npy", observations)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    subprocess.run(  # one interpreter for every configuration: importing torch is the slow part
        [sys.executable, "-c", _FRESH_PROCESS, str(tmp_path / "obs.npy"), *paths],
        check=True,
        cwd=tmp_path,
        env={**env, "OMP_NUM_THREADS": "1"},
        timeout=600,
    )
    for name, model in models.items():
        out = np.load(tmp_path / f"{name}.pt.npz")
        expected, _ = model.predict(observations, deterministic=True)
        np.testing.assert_allclose(out["batch"], expected, rtol=0, atol=ATOL, err_msg=name)
        for obs, action in zip(observations[:3], out["single"], strict=True):
            np.testing.assert_allclose(action, model.predict(obs, deterministic=True)[0], rtol=0, atol=ATOL, err_msg=name)


def test_export_follows_predict_actor(model: POLA, observations, tmp_path: pathlib.Path):
    obs = th.as_tensor(observations)
    ema = th.jit.load(str(model.export_policy(tmp_path / "ema.pt", format="torchscript")))
    model.policy.predict_actor = "online"
    try:
        online = th.jit.load(str(model.export_policy(tmp_path / "online.pt", format="torchscript")))
        expected, _ = model.predict(observations, deterministic=True)
    finally:
        model.policy.predict_actor = "ema"
    with th.no_grad():
        np.testing.assert_allclose(online(obs).numpy(), expected, rtol=0, atol=ATOL)
        assert (online(obs) - ema(obs)).abs().max() > 1e-3


def test_compiled_activations_export_as_plain_mish(tiny_dataset, tmp_path: pathlib.Path):
    policy_kwargs = {"net_arch": [32, 32], "compile_activations": True}
    light = POLA("MlpPolicy", dataset=tiny_dataset, seed=0, device="cpu", policy_kwargs=policy_kwargs)
    observations = np.random.default_rng(0).normal(0.0, 3.0, (16, 3)).astype(np.float32)
    scripted = th.jit.load(str(light.export_policy(tmp_path / "policy.pt", format="torchscript")))
    with th.no_grad():
        actions = scripted(th.as_tensor(observations)).numpy()
    np.testing.assert_allclose(actions, light.predict(observations, deterministic=True)[0], rtol=0, atol=ATOL)


# ---------------------------------------------------------------- what cannot be exported
def test_ranked_candidates_export_with_the_critics_and_match_predict(tiny_dataset, tmp_path: pathlib.Path):
    """The Q-ranked rule (``n_action_samples > 1``): the graph runs the candidates' chains and the target critics
    (LayerNorm ones, the default, and plain ones) and keeps predict's choice, in both formats."""
    observations = np.random.default_rng(0).normal(0.0, 2.0, (32, 3)).astype(np.float32)
    for layer_norm in (True, False):
        policy_kwargs = {"net_arch": [32, 32], "n_action_samples": 6}
        model = POLA(
            "MlpPolicy", dataset=tiny_dataset, seed=0, device="cpu", critic_layer_norm=layer_norm, policy_kwargs=policy_kwargs
        )
        _perturb(model, seed=4)
        model.policy.actor_ema.load_state_dict(model.actor.state_dict())
        with th.no_grad():  # critics that prefer different candidates at different states
            for param in model.policy.critic_target.parameters():
                param.add_(0.5 * th.randn(param.shape, generator=th.Generator().manual_seed(5)))
        expected, _ = model.predict(observations, deterministic=True)
        model.policy.n_action_samples = 1
        noise_free = model.policy.deterministic_rule
        model.policy.deterministic_rule = "noise_free"
        first, _ = model.predict(observations, deterministic=True)  # candidate 0 alone
        model.policy.n_action_samples, model.policy.deterministic_rule = 6, noise_free
        assert not np.allclose(expected, first, atol=1e-4)  # the critics chose other candidates somewhere
        graph = DeterministicPolicyGraph(model.policy)
        assert graph.critic is not None and graph.candidate_noise.shape == (model.policy.n_diffusion_steps + 1, 6, 2)
        scripted = th.jit.load(str(model.export_policy(tmp_path / f"ranked{layer_norm}.pt", format="torchscript")))
        with th.no_grad():
            np.testing.assert_allclose(scripted(th.as_tensor(observations)).numpy(), expected, rtol=0, atol=ATOL)
        if layer_norm and importlib.util.find_spec("onnxruntime") is not None:  # one ONNX export: they are slow
            path = model.export_policy(tmp_path / f"ranked{layer_norm}.onnx")
            np.testing.assert_allclose(_session(path).run(None, {"obs": observations})[0], expected, rtol=0, atol=ATOL)
            single = _session(path).run(None, {"obs": observations[:1]})[0]
            np.testing.assert_allclose(single, expected[:1], rtol=0, atol=ATOL)


def test_confident_choice_exports_both_actors_and_the_critics(tiny_dataset, tmp_path: pathlib.Path):
    """``fallback_confidence``: the graph runs POLA's and the fallback actor's chains and the critics' choice between
    them, and matches predict where it takes either action, in both formats."""
    observations = np.random.default_rng(0).normal(0.0, 2.0, (32, 3)).astype(np.float32)
    policy_kwargs = {"net_arch": [32, 32], "fallback_confidence": 0.0}
    model = POLA("MlpPolicy", dataset=tiny_dataset, seed=0, device="cpu", policy_kwargs=policy_kwargs)
    _perturb(model, seed=4)
    model.policy.actor_ema.load_state_dict(model.actor.state_dict())
    with th.no_grad():  # critics whose members prefer either actor's action at different states
        for param in model.policy.critic.parameters():
            param.add_(0.5 * th.randn(param.shape, generator=th.Generator().manual_seed(5)))
    expected, _ = model.predict(observations, deterministic=True)
    model.policy.fallback_confidence = -1e9
    own, _ = model.predict(observations, deterministic=True)
    model.policy.fallback_confidence = 0.0
    took_own = np.all(expected == own, axis=1)
    assert took_own.any() and not took_own.all()
    graph = DeterministicPolicyGraph(model.policy)
    assert graph.fallback is not None and graph.choice_critic is not None
    scripted = th.jit.load(str(model.export_policy(tmp_path / "choice.pt", format="torchscript")))
    with th.no_grad():
        np.testing.assert_allclose(scripted(th.as_tensor(observations)).numpy(), expected, rtol=0, atol=ATOL)
    if importlib.util.find_spec("onnxruntime") is not None:
        path = model.export_policy(tmp_path / "choice.onnx")
        np.testing.assert_allclose(_session(path).run(None, {"obs": observations})[0], expected, rtol=0, atol=ATOL)


def test_refuses_unknown_formats_and_overridden_predict(tiny_dataset, tmp_path: pathlib.Path):
    model = POLA("MlpPolicy", dataset=tiny_dataset, device="cpu", policy_kwargs={"net_arch": [16]})
    with pytest.raises(ValueError, match="format must be one of"):
        model.export_policy(tmp_path / "policy.tflite", format="tflite")

    class NoisyPolicy(POLAPolicy):
        def _predict(self, observation, deterministic=False):
            return super()._predict(observation, deterministic) + 0.1

    custom = POLA(NoisyPolicy, dataset=tiny_dataset, device="cpu", policy_kwargs={"net_arch": [16]})
    with pytest.raises(PolicyExportError, match=r"overrides POLAPolicy\._predict"):
        custom.export_policy(tmp_path / "policy.pt", format="torchscript")


def test_a_graph_that_disagrees_with_predict_is_not_written(tiny_dataset, tmp_path: pathlib.Path, monkeypatch):
    model = POLA("MlpPolicy", dataset=tiny_dataset, device="cpu", policy_kwargs={"net_arch": [16]})
    forward = DeterministicPolicyGraph.forward
    monkeypatch.setattr(DeterministicPolicyGraph, "forward", lambda self, obs: forward(self, obs) + 1e-3)
    with pytest.raises(PolicyExportError, match=r"differs from predict by [0-9.e-]+ \(> 1e-05\)"):
        model.export_policy(tmp_path / "policy.pt", format="torchscript")
    assert not (tmp_path / "policy.pt").exists()


def test_refuses_unbounded_actions(tmp_path: pathlib.Path):
    policy = POLAPolicy(
        gym.spaces.Box(-np.inf, np.inf, (3,), np.float32),
        gym.spaces.Box(-np.inf, np.inf, (2,), np.float32),
        lambda _: 1e-3,
        net_arch=[16],
    )
    with pytest.raises(PolicyExportError, match="infinite bounds"):
        export_policy(policy, tmp_path / "policy.pt", format="torchscript")


def test_onnx_export_without_onnxscript_names_the_extra(tiny_dataset, tmp_path: pathlib.Path, monkeypatch):
    model = POLA("MlpPolicy", dataset=tiny_dataset, device="cpu", policy_kwargs={"net_arch": [16]})
    monkeypatch.setitem(sys.modules, "onnxscript", None)  # import fails as if not installed
    with pytest.raises(ImportError, match=r"sb3_pola\[export\]"):
        model.export_policy(tmp_path / "policy.onnx")


# ---------------------------------------------------------------- the command and the benchmark
def test_cli_export(tiny_dataset, tmp_path: pathlib.Path, capsys):
    pytest.importorskip("onnxruntime")
    model = POLA("MlpPolicy", dataset=tiny_dataset, seed=0, device="cpu", policy_kwargs={"net_arch": [32, 32]})
    _perturb(model, seed=3)
    model.save(tmp_path / "model.zip")
    obs = model._offline_data.observations[:10].astype(np.float32)
    expected, _ = model.predict(obs, deterministic=True)

    assert cli_main(["export", str(tmp_path / "model.zip"), str(tmp_path / "out" / "policy.onnx")]) == 0
    assert "policy.onnx (onnx): obs [batch, 3] float32 -> action [batch, 2]" in capsys.readouterr().out
    actions = _session(tmp_path / "out" / "policy.onnx").run(None, {"obs": obs})[0]
    np.testing.assert_allclose(actions, expected, rtol=0, atol=ATOL)

    assert cli_main(["export", str(tmp_path / "model.zip"), str(tmp_path / "policy.pt")]) == 0  # format from the suffix
    assert "(torchscript)" in capsys.readouterr().out
    with th.no_grad():
        scripted = th.jit.load(str(tmp_path / "policy.pt"))(th.as_tensor(obs)).numpy()
    np.testing.assert_allclose(scripted, expected, rtol=0, atol=ATOL)

    # a user error is one line
    assert cli_main(["export", str(tmp_path / "model.zip"), str(tmp_path / "y.txt")]) == 2
    err = capsys.readouterr().err
    assert "y.txt" in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "y.txt").exists()


def test_export_bench_runs_and_tabulates():
    pytest.importorskip("onnxruntime")
    result = export_bench.run(task="hopper", configs={"tiny": {"net_arch": [16]}}, n_calls=5)
    rows = result["configs"]["tiny"]
    assert set(rows) == {"onnxruntime", "torchscript", "predict"}
    assert rows["predict"]["over_predict"] == pytest.approx(1.0)
    assert all(r["median_s"] > 0 and r["over_sac"] > 0 for r in rows.values())
    json.dumps(result)
    machine = {"cpu": "test", "cpu_count": 2, "torch_threads": 1, "torch": "x", "device": "cpu", "date": "d", "command": "c"}
    table = format_tables({"machine": machine, "export": result, "total_s": 1.0})
    assert "| tiny: ONNX Runtime |" in table and "| SB3 SAC predict |" in table
