"""#12: the critic-diversity runs next to the 10k grid, the detached-states runs and the d3rlpy baselines; Hopper.

Final score (step 10,000) per cell, mean ± sample std over seeds with every seed listed, from the cells'
``scores.csv`` (noise-free chain, the run's own evaluation) and, where present, ``reeval.csv`` (rule
``stochastic``: one sample of the reverse chain). ``python experiments/edac/table.py`` prints a Markdown table.
"""

from __future__ import annotations

import csv
import pathlib
import statistics

ROOT = pathlib.Path(__file__).resolve().parents[1]
STEP = 10_000
# (label, folder, variant filter): the rows of the table, in order
SOURCES = [
    ("BC", "score10k", "BC"),
    ("T0", "score10k", "T0"),
    ("T0 + critic_diversity 1", "edac/div1.0", "T0"),
    ("T3 (through the model)", "score10k", "T3"),
    ("T3 + critic_diversity 1", "edac/div1.0", "T3"),
    ("T3 + critic_diversity 1 on states and actions", "edac/div1.0_sa", "T3"),
    ("T3 detached", "nobackprop", "T3"),
    ("T3 detached", "nobackprop_replay", "T3"),
    ("T3 detached + critic_diversity 1", "edac/div1.0_detached", "T3"),
    ("d3rlpy-TD3+BC", "peers10k", "d3rlpy-TD3+BC"),
    ("d3rlpy-IQL", "peers10k", "d3rlpy-IQL"),
    ("d3rlpy-BC", "peers10k", "d3rlpy-BC"),
]
# our Hopper-v5 medium dataset (experiments/hopper/collect.sh): the defaults before 2026-12-02 (the paper's form, the
# CPU preset) against the new ones (the weakened Q term, critic_diversity 1, detached states), and BC
HOPPER = [
    ("BC", "hopper/score", "BC"),
    ("T3, the paper's form (the defaults before)", "hopper/score", "T3"),
    ("T3, paper's form + critic_diversity 1 + detached", "hopper/paper_edac_detached", "T3"),
    ("T3, the new defaults", "hopper/floor_edac_detached", "T3"),
]


def finals(path: pathlib.Path, variant: str, step_key: str = "step") -> dict[str, dict[int, float]]:
    """``{dataset: {seed: score}}`` of ``variant`` at ``STEP`` in one CSV."""
    out: dict[str, dict[int, float]] = {}
    if not path.exists():
        return out
    for row in csv.DictReader(path.open()):
        if row["variant"] == variant and int(float(row.get(step_key) or STEP)) == STEP:
            out.setdefault(row["dataset"], {})[int(row["seed"])] = float(row["score"])
    return out


def stochastic(folder: pathlib.Path, variant: str) -> dict[str, dict[int, float]]:
    """The ``stochastic`` re-evaluations of the final models (``sb3-pola score --reevaluate stochastic``)."""
    out: dict[str, dict[int, float]] = {}
    path = folder / "reeval.csv"
    if not path.exists():
        return out
    for row in csv.DictReader(path.open()):
        if row["variant"] == variant and row["rule"] == "stochastic":
            out.setdefault(row["dataset"], {})[int(row["seed"])] = float(row["score"])
    return out


def cell(scores: dict[int, float]) -> str:
    if not scores:
        return "-"
    values = [scores[s] for s in sorted(scores)]
    spread = f" ± {statistics.stdev(values):.1f}" if len(values) > 1 else ""
    return f"{statistics.mean(values):.1f}{spread} ({', '.join(f'{v:.1f}' for v in values)})"


def main() -> None:
    print("| dataset | variant | noise-free chain (seeds 0, 1, 2) | one sample (seeds 0, 1, 2) |")
    print("|---|---|---|---|")
    groups = [("halfcheetah/medium-v0", SOURCES), ("halfcheetah/medium-replay-v0", SOURCES), ("hopper/medium-v0", HOPPER)]
    for dataset, sources in groups:
        for label, folder, variant in sources:
            base = ROOT / folder
            scores = finals(base / ("peers.csv" if variant.startswith("d3rlpy") else "scores.csv"), variant)
            if dataset not in scores:
                continue
            one = stochastic(base, variant).get(dataset, {})
            print(f"| {dataset} | {label} | {cell(scores[dataset])} | {cell(one)} |")


if __name__ == "__main__":
    main()
