"""The main job (``sb3-pola run`` / ``make train``) end to end on the shipped dataset, at a tiny budget."""

from __future__ import annotations

import json
import pathlib

from sb3_pola import POLA
from sb3_pola.cli import run


def test_main_job_writes_model_curve_and_results(tmp_path: pathlib.Path, capsys) -> None:
    out = tmp_path / "main"
    extra = {
        "backprop_through_model": False,
        "batch_size": 16,
        "policy_kwargs": {"net_arch": [16]},
        "dynamics_kwargs": {"n_members": 2, "n_elites": 1, "hidden_dim": 16, "n_layers": 2},
        "dynamics_fit_kwargs": {"max_epochs": 1},
    }
    argv = ["--steps", "6", "--eval-freq", "3", "--eval-episodes", "1", "--final-episodes", "1", "--out", str(out)]
    assert run.main([*argv, "--extra", json.dumps(extra)]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["dataset"] == "invertedpendulum/medium-v0" and results["gradient_steps"] == 6
    assert results["hyperparameters"]["backprop_through_model"] is False  # --extra reaches the model
    assert results["hyperparameters"]["n_critics"] == run.LIGHT_CONFIG["n_critics"]
    assert results["curve"]["steps"] == [0, 3, 6, 6]
    assert results["normalized_score"] is not None
    assert (out / "learning_curve.png").stat().st_size > 0
    model = POLA.load(out / "model.zip", device="cpu")
    assert model.num_timesteps == 6 and model.backprop_through_model is False
    saved = capsys.readouterr().out.splitlines()[-1]  # every file written is named
    assert saved.startswith("saved: ") and all(f"{out / name}" in saved for name in ("model.zip", "evaluations.npz"))


def test_main_job_on_the_shipped_maze_reports_its_success_rate(tmp_path: pathlib.Path) -> None:
    """``make train DATASET=pointmaze/umaze-v0``: Dict observations, sparse reward, the success rate reported."""
    out = tmp_path / "maze"
    extra = {
        "rollout_length": 1,
        "batch_size": 16,
        "policy_kwargs": {"net_arch": [16]},
        "dynamics_kwargs": {"n_members": 2, "n_elites": 1, "hidden_dim": 16, "n_layers": 2},
        "dynamics_fit_kwargs": {"max_epochs": 1},
    }
    argv = ["--dataset", "pointmaze/umaze-v0", "--steps", "4", "--eval-freq", "4", "--eval-episodes", "1"]
    assert run.main([*argv, "--final-episodes", "2", "--out", str(out), "--extra", json.dumps(extra)]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["dataset"] == "pointmaze/umaze-v0"
    assert results["success_rate"] in (0.0, 0.5, 1.0)  # two episodes, each reporting info["success"]
    model = POLA.load(out / "model.zip", device="cpu")
    assert model.dict_observation_space is not None and "desired_goal" in model.dict_observation_space.spaces


def test_success_tracker_counts_episodes_and_envs_without_success() -> None:
    callback, episodes = run.success_tracker()
    steps = [(0, {"success": False}, False), (0, {"success": True}, False), (0, {"success": False}, True)]
    steps += [(0, {"success": False}, True), (0, {}, True)]
    for i, info, done in steps:
        callback({"i": i, "info": info, "done": done}, {})
    assert episodes == [True, False, None]
    assert run.success_rate(episodes) == 0.5 and run.success_rate([None]) is None
