"""#12: the 100,000-step curves on halfcheetah/medium-replay: POLA with the package defaults of 2026-12-02 (T = 3,
every seed run), POLA T = 0 with the weakened Q term and BC (experiments/curve100k), d3rlpy TD3+BC (experiments/peers100k);
POLA acts with one sample of its chain, d3rlpy deterministically. Prints the table, writes
docs/curve100k_defaults.png. ``python experiments/curve100k_defaults/fig.py``"""

from __future__ import annotations

import csv
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

ROOT = pathlib.Path(__file__).resolve().parents[1]


def read(path: pathlib.Path) -> dict[tuple[str, int], dict[int, float]]:
    curves: dict[tuple[str, int], dict[int, float]] = {}
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            curves.setdefault((row["variant"], int(row["seed"])), {})[int(row["step"])] = float(row["score"])
    return curves


def main() -> None:
    defaults = {("defaults T3", seed): c for (_, seed), c in read(ROOT / "curve100k_defaults" / "scores.csv").items()}
    others = {**read(ROOT / "curve100k" / "scores.csv"), **read(ROOT / "peers100k" / "peers.csv")}
    curves = {**defaults, **{k: v for k, v in others.items() if k[1] == 0}}
    names = sorted(curves, key=lambda k: (k[0] != "defaults T3", k))
    steps = sorted({s for c in curves.values() for s in c})
    print("| step | " + " | ".join(f"{v} (seed {s})" for v, s in names) + " |")
    print("|---|" + "---|" * len(names))
    for step in steps:
        print(f"| {step} | " + " | ".join(f"{curves[n][step]:.1f}" if step in curves[n] else "-" for n in names) + " |")
    fig, ax = plt.subplots(figsize=(7, 4))
    labels = {"defaults T3": "POLA, the defaults (T=3)", "T0": "POLA T=0, weakened Q term", "BC": "BC (same actor)"}
    for name in names:
        xs = sorted(curves[name])
        style = "--" if name[0].startswith("d3rlpy") else "-"
        ax.plot(xs, [curves[name][x] for x in xs], style, label=f"{labels.get(name[0], name[0])}, seed {name[1]}")
    ax.axhline(9.8, color="grey", lw=0.8, ls=":", label="dataset mean")
    ax.set_xlabel("gradient steps")
    ax.set_ylabel("D4RL-normalised score (10 episodes)")
    ax.set_title("halfcheetah/medium-replay-v0, CPU preset")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(ROOT.parent / "docs" / "curve100k_defaults.png", dpi=120)


if __name__ == "__main__":
    main()
