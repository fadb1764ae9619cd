"""The rows of ``screen.jsonl`` (``screen.py``'s output) as a table: every seed and the mean ± std of each screen.

    python experiments/policy_quality/screen_table.py --names RNW T0RNW BCRNW --collection amd
    python experiments/policy_quality/screen_table.py --names RNW BCRNW --collection amd-mode --against obsnoise --rule mode

One line per (dataset, name) in the file's order, seeds ascending; a seed screened twice keeps its last row.
"""

from __future__ import annotations

import argparse
import json
import pathlib
from typing import Any

from sb3_pola.grid.report import fmt_scores

HERE = pathlib.Path(__file__).resolve().parent


def read(path: pathlib.Path, names: list[str], rule: str, collection: str | None) -> dict[tuple[str, str], dict[int, Any]]:
    """(dataset, name) -> seed -> the row, for the rows of these names (and collection) that have the rule's score."""
    cells: dict[tuple[str, str], dict[int, Any]] = {}
    for line in path.read_text().splitlines():
        row = json.loads(line)
        if row["name"] not in names or rule not in row:
            continue
        if collection is not None and row.get("collection") != collection:
            continue
        cells.setdefault((row["dataset"], row["name"]), {})[row["seed"]] = row
    return cells


def table(cells: dict[tuple[str, str], dict[int, Any]], rule: str) -> str:
    """A markdown table: dataset, name, the seeds' scores in seed order, mean ± std, the success rates if any."""
    lines = ["| dataset | screen | seeds | scores | mean ± std | success |", "|---|---|---|---|---|---|"]
    for (dataset, name), by_seed in cells.items():
        seeds = sorted(by_seed)
        scores = [by_seed[s][rule] for s in seeds]
        success = [by_seed[s].get(f"{rule}_success") for s in seeds]
        known = [x for x in success if x is not None]
        success_txt = ", ".join(f"{x:.1f}" for x in known) or "-"
        if len(known) > 3 and len(set(known)) == 1:
            success_txt = f"{known[0]:.1f} on every seed"
        lines.append(
            f"| {dataset} | {name} | {', '.join(map(str, seeds))} | {', '.join(f'{x:.1f}' for x in scores)} | "
            f"{fmt_scores(scores)} | {success_txt} |"
        )
    return "\n".join(lines)


def paired(cells: dict[tuple[str, str], dict[int, Any]], rule: str, against: str) -> str:
    """Two rules on the same saved models: each rule's seeds and mean ± std, and the per-seed difference."""
    lines = [
        f"| dataset | screen | seeds | {against} | {rule} | {rule} - {against} |",
        "|---|---|---|---|---|---|",
    ]
    for (dataset, name), by_seed in cells.items():
        seeds = [s for s in sorted(by_seed) if against in by_seed[s]]
        if not seeds:
            continue
        base, new = [by_seed[s][against] for s in seeds], [by_seed[s][rule] for s in seeds]
        diff = [b - a for a, b in zip(base, new, strict=True)]
        lines.append(
            f"| {dataset} | {name} | {', '.join(map(str, seeds))} | {', '.join(f'{x:.1f}' for x in base)} = "
            f"{fmt_scores(base)} | {', '.join(f'{x:.1f}' for x in new)} = {fmt_scores(new)} | {fmt_scores(diff)} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--file", type=pathlib.Path, default=HERE / "screen.jsonl")
    parser.add_argument("--names", nargs="+", required=True, help="the screens' --name values")
    parser.add_argument("--rule", default="obsnoise", help="the evaluation rule's column (screen.py --rules)")
    parser.add_argument("--collection", default=None, help="only rows of this collection (e.g. amd)")
    parser.add_argument("--against", default=None, help="a second rule: both side by side, and their difference")
    args = parser.parse_args()
    cells = read(args.file, args.names, args.rule, args.collection)
    print(paired(cells, args.rule, args.against) if args.against else table(cells, args.rule))


if __name__ == "__main__":
    main()
