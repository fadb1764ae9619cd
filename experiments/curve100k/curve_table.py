"""Markdown table of the #12 long run: POLA T=0 and BC (one sample of the chain) and d3rlpy TD3+BC, per evaluation.

python experiments/curve100k/curve_table.py   (reads experiments/curve100k/scores.csv and experiments/peers100k/peers.csv)
"""

import csv
import pathlib

root = pathlib.Path(__file__).resolve().parent
curves: dict[str, dict[int, float]] = {}
for path in (root / "scores.csv", root.parent / "peers100k" / "peers.csv"):
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            curves.setdefault(row["variant"], {})[int(row["step"])] = float(row["score"])
variants = [v for v in ("T0", "BC", "d3rlpy-TD3+BC") if v in curves]
steps = sorted({s for v in variants for s in curves[v]})
print("| step | " + " | ".join(variants) + " |")
print("|---|" + "---|" * len(variants))
for step in steps:
    cells = [f"{curves[v][step]:.1f}" if step in curves[v] else "-" for v in variants]
    print(f"| {step} | " + " | ".join(cells) + " |")
