"""``sb3-pola model-check`` on the shipped InvertedPendulum dataset (a MuJoCo env: the simulator rollouts run)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sb3_pola import POLA
from sb3_pola.cli import model_check as model_check_cli
from sb3_pola.common.datasets import load_offline_dataset
from sb3_pola.grid import model_check


def test_chained_starts_stay_in_one_episode():
    data = load_offline_dataset("invertedpendulum/medium-v0")
    starts = model_check.chained_starts(data, 3, 200, np.random.default_rng(0))
    assert len(starts) == 200
    for k in range(2):
        np.testing.assert_array_equal(data.next_observations[starts + k], data.observations[starts + k + 1])


def test_model_check_end_to_end(tmp_path):
    policy = POLA(
        "MlpPolicy",
        dataset="invertedpendulum/medium-v0",
        rollout_length=0,
        n_critics=2,
        batch_size=32,
        policy_kwargs={"net_arch": [16]},
        seed=0,
        device="cpu",
    )
    policy.save(tmp_path / "policy")
    out = tmp_path / "check.json"
    argv = ["--dataset", "invertedpendulum/medium-v0", "--mean-loss", "nll", "mse", "--max-steps", "60", "--starts", "20"]
    argv += ["--horizon", "2", "--policy", str(tmp_path / "policy.zip"), "--out", str(out)]
    assert model_check_cli.main(argv) == 0
    results = json.loads(out.read_text())
    assert set(results["fits"]) == {"nll", "mse"}
    for entry in results["fits"].values():
        for part in ("dataset_actions", "policy_actions"):
            assert len(entry[part]["mse"]) == 2 and all(np.isfinite(entry[part]["mse"]))
            assert all(v >= 0 for v in entry[part]["disagreement"])
    # a trained-for-60-steps model still beats "no change" one step ahead along the data
    first = results["fits"]["nll"]["dataset_actions"]
    assert first["mse"][0] < first["no_change_mse"][0]


def test_model_check_refuses_an_env_it_cannot_set(tmp_path):
    class Sim:
        class model:  # mimics mujoco's attribute names
            nq, nv = 5, 5

    class Env:
        unwrapped = Sim()

    data = load_offline_dataset("invertedpendulum/medium-v0")
    with pytest.raises(ValueError, match="cannot set the simulator"):
        model_check.policy_rollout_errors(None, None, Env(), data, np.array([0]), 1)
