"""Where the U-maze's imitation gap comes from (docs/results.md, twenty-seventh pass).

    python experiments/umaze_floor40/pieces.py

Reads ``pieces.jsonl`` kept here (``PART=pieces bash experiments/umaze_floor40/run.sh``: each imitator of
``experiments/policy_quality/bc_screen.py`` trained in one loop and played on the score's 10 resets) and prints one
markdown row per imitator: its pieces (read from ``bc_screen.VARIANTS``), the seeds, mean ± sample std, the standard
error of the mean, the held-out action MSE (the noise-free chain), sorted by the mean.
"""

from __future__ import annotations

import collections
import json
import math
import pathlib
import sys

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "policy_quality"))
from bc_screen import VARIANTS  # noqa: E402  (the imitators' configs, the one source of each row's pieces)


def pieces(variant: str) -> tuple[str, ...]:
    """(loss, activation, width, states, products, weight average) of a ``bc_screen.py`` variant, from its config."""
    cfg = VARIANTS[variant]
    return (
        "MSE" if cfg.get("kind") == "mse" else "diffusion",
        "ReLU" if cfg.get("relu") else "Mish",
        str(cfg.get("arch", [128, 128])[0]),  # bc_screen's default width
        "raw" if cfg.get("raw") else "normalised",
        "yes" if cfg.get("products", True) else "no",
        "yes" if "ema" in cfg else "no",
    )


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
    for variant in rows:
        scores = np.array([r["score"] for r in rows[variant].values()])
        mse = np.mean([r["mse_det"] for r in rows[variant].values()])
        seeds = sorted(rows[variant])
        table.append((scores.mean(), variant, pieces(variant), seeds, scores, mse))
    for mean, variant, columns, seeds, scores, mse in sorted(table, key=lambda t: -t[0]):
        std = scores.std(ddof=1)
        print(
            f"| `{variant}` | {' | '.join(columns)} | {seeds[0]}-{seeds[-1]} ({len(seeds)}) | {mean:.1f} ± {std:.1f} "
            f"| {std / math.sqrt(len(scores)):.1f} | {mse:.4f} |"
        )


if __name__ == "__main__":
    main()
