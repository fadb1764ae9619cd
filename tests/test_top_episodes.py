"""``experiments/policy_quality/top_episodes.py``: a dataset of a file's best episodes by return (filtered BC's data),
and with ``--keep-all`` every episode with the best first (the thirty-ninth pass's screens)."""

from __future__ import annotations

import json
import math
import os
import pathlib
import subprocess
import sys

import minari
import numpy as np
from helpers import record_random_dataset

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "experiments" / "policy_quality" / "top_episodes.py"


def run(root: pathlib.Path, *args: str) -> dict:
    env = {**os.environ, "MINARI_DATASETS_PATH": str(root), "OMP_NUM_THREADS": "1"}
    result = subprocess.run([sys.executable, str(SCRIPT), *args], check=True, capture_output=True, text=True, env=env)
    return json.loads(result.stdout.splitlines()[-1])


def episodes(root: pathlib.Path, dataset_id: str) -> list:
    return list(minari.MinariDataset(root / dataset_id / "data").iterate_episodes())


def test_best_episodes_only_and_best_first(tmp_path):
    root = tmp_path / "datasets"
    record_random_dataset(root, "pendulum/src-v0", "Pendulum-v1", 300, ref_scores=(-300.0, 0.0), max_episode_steps=30)
    source = episodes(root, "pendulum/src-v0")
    returns = np.array([episode.rewards.sum() for episode in source])
    assert len(source) == 10 and len(set(returns.tolist())) == 10
    best = sorted(np.argsort(-returns)[:3].tolist())  # ceil(0.25 * 10) = 3 episodes, in the file's order

    out = run(root, "--dataset", "pendulum/src-v0", "--fraction", "0.25", "--out-id", "pendulum/best-v0")
    written = episodes(root, "pendulum/best-v0")
    assert [episode.rewards.tolist() for episode in written] == [source[i].rewards.tolist() for i in best]
    np.testing.assert_array_equal(written[0].observations, source[best[0]].observations)
    assert out["episodes"] == out["best_episodes"] == 3 and out["of"] == 10
    assert out["steps"] == out["first_rows"] == 90
    to_score = 100 * (returns[best].mean() + 300.0) / 300.0
    assert math.isclose(out["mean_score"], round(to_score, 1)) and out["mean_score"] > out["source_mean_score"]
    metadata = json.loads((root / "pendulum/best-v0/data/metadata.json").read_text())
    assert (metadata["ref_min_score"], metadata["ref_max_score"]) == (-300.0, 0.0)  # scores normalised as the source's
    assert metadata["source_dataset"] == "pendulum/src-v0" and metadata["top_rows"] == 90
    assert json.loads(metadata["env_spec"])["id"] == "Pendulum-v1"

    out = run(root, "--dataset", "pendulum/src-v0", "--fraction", "0.25", "--out-id", "pendulum/all-v0", "--keep-all")
    written = episodes(root, "pendulum/all-v0")
    rest = [i for i in range(10) if i not in best]
    assert [episode.rewards.tolist() for episode in written] == [source[i].rewards.tolist() for i in best + rest]
    assert out["episodes"] == 10 and out["best_episodes"] == 3 and out["first_rows"] == 90 and out["steps"] == 300
