"""The paper's 10 critics against the CPU preset's 5, at 10,000 steps (docs/results.md, twenty-sixth pass).

    python experiments/critics10/table.py

Reads the final evaluations kept here (``n10_*``, ``n5_*``, ``bc_mmaze_scores.csv``: ``experiments/critics10/run.sh``)
and, for the hopper files' 5 critics and BC, the files.sh rows kept in ``experiments/hopper/``. Prints a markdown
table: every seed, mean ± sample std, the difference of the means.
"""

from __future__ import annotations

import pathlib

import numpy as np

from sb3_pola.grid.report import fmt_scores
from sb3_pola.grid.rows import read_rows

HERE = pathlib.Path(__file__).resolve().parent
HOPPER = HERE.parent / "hopper"
STEPS = 10_000

# row label -> (10 critics, 5 critics, BC with the package's actor); a CSV and the variant to read from it
ROWS: dict[str, tuple[tuple[pathlib.Path, str], tuple[pathlib.Path, str], tuple[pathlib.Path, str] | None]] = {
    "halfcheetah/medium": (
        (HERE / "n10_halfcheetah_medium_scores.csv", "T3"),
        (HERE / "n5_halfcheetah_medium_scores.csv", "T3"),
        None,
    ),
    "halfcheetah/medium-replay": (
        (HERE / "n10_halfcheetah_medium-replay_scores.csv", "T3"),
        (HERE / "n5_halfcheetah_medium-replay_scores.csv", "T3"),
        None,
    ),
    "pointmaze/umaze": ((HERE / "n10_umaze_scores.csv", "T3"), (HERE / "n5_umaze_scores.csv", "T3"), None),
    "pointmaze/medium": (
        (HERE / "n10_mmaze_scores.csv", "T3"),
        (HERE / "n5_mmaze_scores.csv", "T3"),
        (HERE / "bc_mmaze_scores.csv", "BC"),
    ),
    "hopper/medium, second file (SEED=0)": (
        (HERE / "n10_hopper_file0_scores.csv", "T3"),
        (HOPPER / "grid10k_amd/medium/scores.csv", "T3"),
        (HOPPER / "grid10k_amd/medium/scores.csv", "BC"),
    ),
    "hopper/medium, third file (SEED=1)": (
        (HERE / "n10_hopper_file1_scores.csv", "T3"),
        (HOPPER / "grid10k_seed1/medium/t3_scores.csv", "T3"),
        (HOPPER / "grid10k_seed1/medium/bc_scores.csv", "BC"),
    ),
    "hopper/medium, fourth file (SEED=2)": (
        (HERE / "n10_hopper_file2_scores.csv", "T3"),
        (HOPPER / "files/seed2/medium/t3_scores.csv", "T3"),
        (HOPPER / "files/seed2/medium/bc_scores.csv", "BC"),
    ),
    "hopper/medium, fifth file (SEED=3)": (
        (HERE / "n10_hopper_file3_scores.csv", "T3"),
        (HOPPER / "files/seed3/medium/t3_scores.csv", "T3"),
        (HOPPER / "files/seed3/medium/bc_scores.csv", "BC"),
    ),
    "hopper/medium-replay, second file (SEED=0)": (
        (HERE / "n10_hopper_replay_file0_scores.csv", "T3"),
        (HOPPER / "grid10k_amd/medium-replay/scores.csv", "T3"),
        (HOPPER / "grid10k_amd/medium-replay/scores.csv", "BC"),
    ),
}


def finals(source: tuple[pathlib.Path, str] | None) -> list[float]:
    """The final evaluations of a variant, by seed."""
    if source is None:
        return []
    path, variant = source
    rows = [r for r in read_rows(path) if r["variant"] == variant and r["step"] == STEPS]
    return [r["score"] for r in sorted(rows, key=lambda r: r["seed"])]


def cell(values: list[float]) -> str:
    if not values:
        return "-"
    return f"{', '.join(f'{v:.1f}' for v in values)} = {fmt_scores(values)}" if len(values) > 1 else f"{values[0]:.1f}"


def main() -> None:
    print("| 10,000 steps, T = 3 | 10 critics | 5 critics (the CPU preset) | 10 - 5 | BC, package actor |")
    print("|---|---|---|---|---|")
    for label, (ten, five, bc) in ROWS.items():
        n10, n5 = finals(ten), finals(five)
        diff = f"{np.mean(n10) - np.mean(n5):+.1f}" if n10 and n5 else "-"
        print(f"| {label} | {cell(n10)} | {cell(n5)} | {diff} | {cell(finals(bc))} |")


if __name__ == "__main__":
    main()
