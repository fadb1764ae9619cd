"""sb3-pola collect on tiny budgets: loadable datasets with reference scores."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from sb3_pola import collect
from sb3_pola.common.datasets import load_offline_dataset
from sb3_pola.common.errors import UsageError


def test_random_with_given_refs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a relative --out, as in the README's command
    out = tmp_path / "out"
    argv = ["--env", "InvertedPendulum-v5", "--kind", "random", "--steps", "200", "--out", "out"]
    argv += ["--ref-max-score", "1000", "--no-progress", "--seed", "1"]
    assert collect.main(argv) == 0
    data = load_offline_dataset(out / "invertedpendulum" / "random-v0")
    assert len(data) == 200 and data.env_id == "InvertedPendulum-v5"
    assert data.ref_max_score == 1000.0 and data.ref_min_score is not None and data.ref_min_score > 0
    # random InvertedPendulum episodes all terminate; only the last may be cut (not terminal) by the budget
    assert data.dones.sum() in (len(data.episode_returns) - 1, len(data.episode_returns))
    assert data.actions.min() >= -1 and data.actions.max() <= 1
    # exists: refused without --overwrite
    assert collect.main(argv) == 1
    assert collect.main([*argv, "--overwrite"]) == 0


def test_sac_path_all_kinds(tmp_path, monkeypatch):
    threads = th.get_num_threads()
    th.set_num_threads(1)  # two xdist workers on a small machine: avoid oversubscription
    try:
        _sac_path_all_kinds(tmp_path, monkeypatch)
    finally:
        th.set_num_threads(threads)


def _sac_path_all_kinds(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    argv = ["--env", "InvertedPendulum-v5", "--kind", "medium", "medium-replay", "medium-expert", "expert"]
    # 60 gradient steps only: the SAC path is exercised, not trained
    argv += ["--steps", "150", "--train-steps", "200", "--eval-freq", "100", "--eval-episodes", "2"]
    argv += ["--learning-starts", "140", "--no-progress", "--save-policies", str(tmp_path / "policies")]
    assert collect.main(argv) == 0
    sizes = {}
    for kind in ("medium", "medium-replay", "medium-expert", "expert"):
        data = load_offline_dataset(f"invertedpendulum/{kind}-v0")  # found through MINARI_DATASETS_PATH
        assert data.ref_min_score is not None and data.ref_max_score is not None
        assert np.isfinite(data.normalized_score(data.episode_returns))
        sizes[kind] = len(data)
    assert sizes["medium"] == sizes["expert"] == 150 and sizes["medium-expert"] == 300
    assert 0 < sizes["medium-replay"] <= 200
    # the medium-replay episodes chain: next_obs[t] == obs[t + 1] unless the episode ended
    replay = load_offline_dataset("invertedpendulum/medium-replay-v0")
    same = np.all(replay.next_observations[:-1] == replay.observations[1:], axis=1)
    n_episodes = len(replay.episode_returns)
    assert (~same).sum() == n_episodes - 1
    assert (tmp_path / "policies" / "invertedpendulum-medium.zip").exists()
    # a given policy zip is used instead of training
    out = tmp_path / "given"
    policy = str(tmp_path / "policies" / "invertedpendulum-medium.zip")
    argv = ["--env", "InvertedPendulum-v5", "--kind", "medium", "--steps", "100", "--policy", policy]
    argv += ["--expert-policy", policy, "--out", str(out), "--no-progress"]
    assert collect.main(argv) == 0
    assert len(load_offline_dataset(out / "invertedpendulum" / "medium-v0")) == 100


def test_bad_arguments(tmp_path):
    assert collect.main(["--env", "Pendulum-v1", "--ref-episodes", "3", "--out", str(tmp_path)]) == 2
    assert collect.main(["--env", "CartPole-v1", "--kind", "random", "--out", str(tmp_path)]) == 2
    with pytest.raises(UsageError, match="argument --kind: invalid choice"):  # sb3-pola prints it as one line
        collect.main(["--env", "Pendulum-v1", "--kind", "bogus"])
