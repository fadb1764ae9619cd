"""#14: learning curves on the two point mazes in the style of the paper's Fig. 3 (docs/maze_curves.png).

Normalised score per evaluation (10 episodes), mean over seeds with a band of ± one sample std, for BC,
POLA T = 0 / 1 / 3 (the package defaults) and d3rlpy's TD3+BC (dashed), from the score and peers CSVs; the
third panel is the medium maze's success rate (the U-maze runs predate the per-evaluation success column).
Run from the repository root:

    python experiments/maze/fig_maze.py [out.png]
"""

import pathlib
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import pandas as pd

REPO = pathlib.Path(__file__).resolve().parents[2]  # the paths below are relative to the repository

PANELS = [  # dataset, folder, title, column
    ("pointmaze/umaze-v0", "experiments/maze_hint", "U-maze", "score"),
    ("pointmaze/medium-v0", "experiments/maze_medium", "medium maze", "score"),
    ("pointmaze/medium-v0", "experiments/maze_medium", "medium maze", "success"),
]
YLABELS = {"score": "normalised score", "success": "success rate"}
CURVES = [  # variant, label, colour, line style
    ("BC", "BC (same actor, eta = 0)", "tab:gray", "-"),
    ("T0", "POLA T = 0", "tab:blue", "-"),
    ("T1", "POLA T = 1", "tab:orange", "-"),
    ("T3", "POLA T = 3", "tab:red", "-"),
    ("d3rlpy-TD3+BC", "d3rlpy TD3+BC", "black", "--"),
]


def main(out: str = str(REPO / "docs" / "maze_curves.png")) -> None:
    fig, axes = plt.subplots(1, len(PANELS), figsize=(14, 3.8), sharey=False)
    for ax, (dataset, folder, title, column) in zip(axes, PANELS, strict=True):
        frames = [pd.read_csv(p) for p in (REPO / folder / n for n in ("scores.csv", "peers.csv")) if p.is_file()]
        rows = pd.concat(frames, ignore_index=True)
        rows = rows[rows["dataset"] == dataset]
        for variant, label, colour, style in CURVES:
            runs = rows[rows["variant"] == variant]
            if runs.empty:
                continue
            by_step = runs.groupby("step")[column]
            mean, std, n = by_step.mean(), by_step.std().fillna(0.0), runs["seed"].nunique()
            ax.plot(mean.index, mean.values, style, color=colour, marker="o", ms=3, label=f"{label} (n={n})")
            ax.fill_between(mean.index, mean - std, mean + std, color=colour, alpha=0.15)
        ax.set_title(f"{title} ({dataset}), sparse reward", fontsize=10)
        ax.set_xlabel("gradient steps")
        ax.set_ylabel(YLABELS[column])
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(*sys.argv[1:])
