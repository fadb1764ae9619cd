"""``experiments/policy_quality/more_seeds.py``: the per-seed tables of the fifteenth pass (screen rows and
``sb3-pola peers`` rows, the difference of means with Welch's standard error)."""

from __future__ import annotations

import json
import math
import pathlib
import subprocess
import sys

import numpy as np

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "experiments" / "policy_quality" / "more_seeds.py"


def run(*args: str) -> list[str]:
    result = subprocess.run([sys.executable, str(SCRIPT), *args], check=True, capture_output=True, text=True)
    return result.stdout.splitlines()


def test_more_seeds_table(tmp_path):
    screen = tmp_path / "screen.jsonl"
    rows = [
        {"dataset": "d/x-v0", "name": "A", "seed": 0, "obsnoise": 10.0, "obsnoise_success": 1.0},
        {"dataset": "d/x-v0", "name": "A", "seed": 1, "obsnoise": 99.0},  # replaced by the next row of seed 1
        {"dataset": "d/x-v0", "name": "A", "seed": 1, "obsnoise": 20.0, "obsnoise_success": 0.5},
        {"dataset": "d/x-v0", "name": "A", "seed": 2, "obsnoise": 30.0, "obsnoise_success": 1.0},
        {"dataset": "d/y-v0", "name": "A", "seed": 0, "obsnoise": 1000.0},  # another dataset
    ]
    screen.write_text("".join(json.dumps(r) + "\n" for r in rows))
    peers = tmp_path / "peers.csv"
    peers.write_text(
        "dataset,variant,seed,step,score,score_std,mean_return,eval_episodes,wall_s,success\n"
        "d/x-v0,d3rlpy-BC,0,2000,500.0,0,0,10,1,1.0\n"  # not the final step
        "d/x-v0,d3rlpy-BC,0,10000,12.0,0,0,10,1,1.0\n"
        "d/x-v0,d3rlpy-BC,1,10000,14.0,0,0,10,1,0.0\n"
        "d/x-v0,d3rlpy-BC,3,10000,16.0,0,0,10,1,1.0\n"
    )
    common = ["--screen", str(screen), "--peers", str(peers), "--dataset", "d/x-v0", "--names", "A"]
    lines = run(*common, "--variants", "d3rlpy-BC", "--seeds", "0", "1", "2", "3")
    a = next(line for line in lines if line.startswith("| A |"))
    bc = next(line for line in lines if line.startswith("| d3rlpy-BC |"))
    assert "| 10.0, 20.0, 30.0, - | 20.0 ± 10.0 | 3 | 20.0 ± 10.0 |" in a  # sample std (ddof 1)
    assert "| 12.0, 14.0, -, 16.0 | 14.0 ± 2.0 | 3 | 13.0 ± 1.4 |" in bc
    se = math.sqrt(np.var([10.0, 20.0, 30.0], ddof=1) / 3 + np.var([12.0, 14.0, 16.0], ddof=1) / 3)
    assert bc.endswith(f"| {-6.0:+.1f} ± {se:.1f} |")
    success = run(*common, "--seeds", "0", "1", "2", "--success")
    assert "| 1.00, 0.50, 1.00 | 0.83 ± 0.29 | 3 |" in next(line for line in success if line.startswith("| A |"))
