"""The rows ``confident_choice.py --model`` wrote as a table: for each dataset, the model's own actor alone
(``pola``), its imitation actor alone (``bc``) and the confident choice at each ``k``, every seed, mean ± std, and
the choice's paired differences to either actor alone.

    python experiments/policy_quality/choice_table.py --collection amd-fallback [--file confident_choice.jsonl]

Paired: the mean of the per-seed differences ± its standard error (the same model, the same resets). A seed written
twice keeps its last row.
"""

from __future__ import annotations

import argparse
import json
import pathlib
from typing import Any

import numpy as np

from sb3_pola.grid.report import fmt_scores

HERE = pathlib.Path(__file__).resolve().parent


def read(path: pathlib.Path, collection: str | None) -> dict[str, dict[int, dict[str, Any]]]:
    """dataset -> seed -> row, for the rows of one model (``--model``; with ``pola`` and ``bc``)."""
    cells: dict[str, dict[int, dict[str, Any]]] = {}
    for line in path.read_text().splitlines():
        row = json.loads(line)
        if "pola" not in row or "bc" not in row:
            continue
        if collection is not None and row.get("collection") != collection:
            continue
        cells.setdefault(row["dataset"], {})[row["seed"]] = row
    return cells


def paired(a: list[float], b: list[float]) -> str:
    """``mean(a - b) ± its standard error`` (one pair: the difference alone)."""
    diff = np.asarray(a) - np.asarray(b)
    if len(diff) == 1:
        return f"{diff[0]:+.1f}"
    return f"{diff.mean():+.1f} ± {diff.std(ddof=1) / np.sqrt(len(diff)):.1f}"


def table(cells: dict[str, dict[int, dict[str, Any]]]) -> str:
    """One markdown line per dataset and column (``pola``, ``bc``, ``k<k>``): seeds, mean ± std, paired differences,
    the share of steps on POLA's own action."""
    lines = [
        "| dataset | actor | seeds | scores | mean ± std | - own actor (paired) | - imitation actor (paired) | own share |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for dataset, by_seed in cells.items():
        seeds = sorted(by_seed)
        rows = [by_seed[s] for s in seeds]
        ks = sorted((c for c in rows[0] if c.startswith("k") and "_" not in c), key=lambda c: float(c[1:]))
        columns = ["pola", "bc", *ks]
        own, imitation = [r["pola"] for r in rows], [r["bc"] for r in rows]
        for column in columns:
            scores = [r[column] for r in rows]
            share = np.mean([r[f"{column}_pola_share"] for r in rows])
            lines.append(
                f"| {dataset} | {column} | {','.join(map(str, seeds))} | {', '.join(f'{v:.1f}' for v in scores)} | "
                f"{fmt_scores(scores)} | {paired(scores, own) if column != 'pola' else ''} | "
                f"{paired(scores, imitation) if column != 'bc' else ''} | {share:.2f} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--file", default=str(HERE / "confident_choice.jsonl"))
    parser.add_argument("--collection", default=None)
    args = parser.parse_args()
    print(table(read(pathlib.Path(args.file), args.collection)))


if __name__ == "__main__":
    main()
