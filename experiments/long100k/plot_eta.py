"""hopper/medium over 100,000 steps at the two values of eta (#23 twentieth pass), one figure:

    python experiments/long100k/plot_eta.py [--out experiments/long100k/lrc/fig_eta_hopper_medium-v0.png]

Reads the score grid's CSVs in ``experiments/long100k/`` (``lrc/scores.csv`` the defaults, eta 3.94;
``lrc/t3_eta1_scores.csv``, ``lrc/t0_scores.csv``, ``lrc/t0_eta1_scores.csv``, ``lrc/bc_scores.csv`` and d3rlpy's
``peers.csv``) and draws the mean over seeds with a band of one standard deviation.
"""

from __future__ import annotations

import argparse
import pathlib
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from sb3_pola.grid.rows import read_rows

HERE = pathlib.Path(__file__).parent
DATASET = "hopper/medium-v0"
# (label, file, variant, colour, line style)
CURVES = [
    ("POLA defaults (T = 3, eta 3.94)", "lrc/scores.csv", "T3", "tab:red", "-"),
    ("POLA T = 3, eta 1", "lrc/t3_eta1_scores.csv", "T3", "tab:purple", "-"),
    ("POLA T = 0, eta 3.94", "lrc/t0_scores.csv", "T0", "tab:blue", "-"),
    ("POLA T = 0, eta 1", "lrc/t0_eta1_scores.csv", "T0", "tab:cyan", "-"),
    ("BC, package actor", "lrc/bc_scores.csv", "BC", "tab:gray", "--"),
    ("d3rlpy TD3+BC", "peers.csv", "d3rlpy-TD3+BC", "black", "--"),
]


def curve(path: pathlib.Path, variant: str) -> tuple[list[int], np.ndarray, np.ndarray, int]:
    """Steps, mean and std over seeds, number of seeds of one variant's evaluations."""
    by_step: dict[int, list[float]] = defaultdict(list)
    for row in read_rows(path):
        if row["dataset"] == DATASET and row["variant"] == variant:
            by_step[row["step"]].append(row["score"])
    steps = sorted(by_step)
    values = [by_step[s] for s in steps]
    return steps, np.array([np.mean(v) for v in values]), np.array([np.std(v) for v in values]), max(map(len, values))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(HERE / "lrc" / "fig_eta_hopper_medium-v0.png"))
    args = parser.parse_args()
    fig, ax = plt.subplots(figsize=(6.5, 4.0), dpi=90)
    for label, name, variant, color, style in CURVES:
        steps, mean, std, n = curve(HERE / name, variant)
        ax.plot(steps, mean, style, marker="o", ms=3, color=color, label=f"{label} (n={n})")
        ax.fill_between(steps, mean - std, mean + std, color=color, alpha=0.12)
    ax.set_title(f"{DATASET}: the Q term's weight over 100,000 steps", fontsize=10)
    ax.set_xlabel("gradient steps")
    ax.set_ylabel("D4RL-normalised score")
    ax.set_ylim(10, 80)
    ax.legend(fontsize=7, loc="upper left", ncol=2)
    fig.tight_layout()
    fig.savefig(args.out)
    print(args.out)


if __name__ == "__main__":
    main()
