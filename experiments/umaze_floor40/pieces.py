"""Where the U-maze's imitation gap comes from (docs/results.md, twenty-seventh pass).

    python experiments/umaze_floor40/pieces.py

Reads ``pieces.jsonl`` kept here (``PART=pieces bash experiments/umaze_floor40/run.sh``: each imitator of
``experiments/policy_quality/bc_screen.py`` trained in one loop and played on the score's 10 resets) and prints one
markdown row per imitator: its pieces, the seeds, mean ± sample std, the standard error of the mean, the held-out
action MSE (the noise-free chain), sorted by the mean.
"""

from __future__ import annotations

import collections
import json
import math
import pathlib

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent

# variant -> (loss, activation, width, states, products, weight average)
PIECES: dict[str, tuple[str, ...]] = {
    "mse-d3rlpy": ("MSE", "ReLU", "256", "raw", "no", "no"),
    "x0-256-lr1e-3-relu-raw-noprod": ("diffusion", "ReLU", "256", "raw", "no", "no"),
    "x0-d3rlpy-but-256": ("diffusion", "ReLU", "128", "raw", "no", "no"),
    "x0-d3rlpy-but-raw": ("diffusion", "ReLU", "256", "normalised", "no", "no"),
    "x0-d3rlpy-but-relu": ("diffusion", "Mish", "256", "raw", "no", "no"),
    "x0-d3rlpy-but-noprod": ("diffusion", "ReLU", "256", "raw", "yes", "no"),
    "x0-lr1e-3-relu-noprod": ("diffusion", "ReLU", "128", "normalised", "no", "no"),
    "x0-lr1e-3-relu-noprod-ema": ("diffusion", "ReLU", "128", "normalised", "no", "yes"),
    "mse-lr1e-3": ("MSE", "Mish", "128", "normalised", "yes", "no"),
    "x0-lr1e-3-relu": ("diffusion", "ReLU", "128", "normalised", "yes", "no"),
    "x0-lr1e-3-noprod": ("diffusion", "Mish", "128", "normalised", "no", "no"),
    "x0-256-lr1e-3": ("diffusion", "Mish", "256", "normalised", "yes", "no"),
    "x0-lr1e-3-raw": ("diffusion", "Mish", "128", "raw", "yes", "no"),
    "x0-lr1e-3": ("diffusion", "Mish", "128", "normalised", "yes", "no"),
    "x0-lr1e-3-ema": ("diffusion", "Mish", "128", "normalised", "yes", "yes"),
}


def main() -> None:
    rows: dict[str, dict[int, dict]] = collections.defaultdict(dict)
    with open(HERE / "pieces.jsonl") as f:
        for line in f:
            row = json.loads(line)
            rows[row["variant"]][int(row["seed"])] = row  # the last row of a (variant, seed) wins
    header = ["imitator (`bc_screen.py` variant)", "loss", "activation", "width", "states", "products", "EMA"]
    print("| " + " | ".join([*header, "seeds", "score", "s.e.", "held-out MSE"]) + " |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    table = []
    for variant, pieces in PIECES.items():
        if not rows[variant]:
            continue
        scores = np.array([r["score"] for r in rows[variant].values()])
        mse = np.mean([r["mse_det"] for r in rows[variant].values()])
        seeds = sorted(rows[variant])
        table.append((scores.mean(), variant, pieces, seeds, scores, mse))
    for mean, variant, pieces, seeds, scores, mse in sorted(table, key=lambda t: -t[0]):
        std = scores.std(ddof=1)
        print(
            f"| `{variant}` | {' | '.join(pieces)} | {seeds[0]}-{seeds[-1]} ({len(seeds)}) | {mean:.1f} ± {std:.1f} "
            f"| {std / math.sqrt(len(scores)):.1f} | {mse:.4f} |"
        )


if __name__ == "__main__":
    main()
