"""Issue #23, fifteenth pass: POLA, BC with the package's actor and d3rlpy's baselines over more seeds than the
done-when's three, from the screen's rows (``screen.jsonl``) and ``sb3-pola peers``' rows (``peers.csv``, the
final evaluation at ``--step``).

    python experiments/policy_quality/more_seeds.py --screen experiments/policy_quality/screen.jsonl \\
        --peers experiments/policy_quality/more_seeds/peers.csv \\
        --dataset pointmaze/umaze-v0 --names GRLRC BCLRC --variants d3rlpy-BC --seeds 0 1 2 3 4 5 6 7

Prints one markdown row per method: every seed's score, the mean and sample std over all seeds and over seeds 0-2, and
the difference of means to the first method with Welch's standard error (``sqrt(s1^2/n1 + s2^2/n2)``). A screen's
row is read under ``--rule`` (the obs-noise rule, the package's ``predict``). The last row of a (name, seed) wins.
``--source COLLECTION RULE`` (repeatable; thirty-fourth pass) reads only the rows of those collections, each under its
own rule column, a later source overriding an earlier one on the same seed: e.g. seeds 0-2 from ``amd-mode-50ep``'s
``mode_first10`` (the README's scores) and seeds 3-7 from ``amd-mode-seeds``' ``mode``. ``--paired``: the difference
to the first method is the mean of the per-seed differences on the seeds both have, ± its standard error.

    python experiments/policy_quality/more_seeds.py --screen experiments/policy_quality/screen.jsonl \\
        --dataset hopper/medium-v0 --names T0RNW RNW --paired \\
        --source amd-mode-50ep mode_first10 --source amd-mode-seeds mode
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib

import numpy as np

from sb3_pola.grid.report import fmt_rates, fmt_scores
from sb3_pola.grid.rows import read_rows


def screen_scores(
    paths: list[str], dataset: str, name: str, rule: str, sources: list[tuple[str, str]] | None = None
) -> dict[int, float]:
    """``{seed: score}`` of a screen's rows (``rule`` may be ``<rule>_success``, the success rate); with ``sources``,
    only the rows of those (collection, rule) pairs, a later pair overriding an earlier one on a seed."""
    scores: dict[int, float] = {}
    for collection, column in sources or [(None, rule)]:
        for path in paths:
            with open(path) as f:
                for line in f:
                    row = json.loads(line)
                    if collection is not None and row.get("collection") != collection:
                        continue
                    if row["dataset"] == dataset and row["name"] == name and column in row:
                        scores[int(row["seed"])] = float(row[column])
    return scores


def peer_scores(paths: list[str], dataset: str, variant: str, step: int, column: str = "score") -> dict[int, float]:
    """``{seed: value}`` of the peers' rows at ``step`` (``column``: ``score`` or ``success``)."""
    scores: dict[int, float] = {}
    for path in paths:
        for row in read_rows(pathlib.Path(path)):
            if row["dataset"] == dataset and row["variant"] == variant and row["step"] == step:
                scores[row["seed"]] = row[column]
    return scores


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--screen", nargs="+", default=[])
    parser.add_argument("--peers", nargs="+", default=[])
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--names", nargs="*", default=[], help="screen names (first: the reference of the differences)")
    parser.add_argument("--variants", nargs="*", default=[], help="peers' variants, e.g. d3rlpy-BC")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4, 5, 6, 7])
    parser.add_argument("--rule", default="obsnoise")
    parser.add_argument("--step", type=int, default=10_000)
    parser.add_argument(
        "--success", action="store_true", help="the success rates (goal-conditioned data) in place of the scores"
    )
    parser.add_argument("--source", nargs=2, action="append", metavar=("COLLECTION", "RULE"), help="screen rows' source")
    parser.add_argument("--paired", action="store_true", help="per-seed differences to the first method")
    args = parser.parse_args()
    rule, column = (args.rule + "_success", "success") if args.success else (args.rule, "score")
    sources = [(c, r + "_success" if args.success else r) for c, r in args.source] if args.source else None
    methods = [(n, screen_scores(args.screen, args.dataset, n, rule, sources)) for n in args.names]
    methods += [(v, peer_scores(args.peers, args.dataset, v, args.step, column)) for v in args.variants]
    what = "success rate" if args.success else "score"
    print(f"{args.dataset}, {what}, seeds {' '.join(map(str, args.seeds))}, step {args.step}")
    print("| method | per seed | mean ± std (all) | n | seeds 0-2 | difference to the first (± Welch s.e.) |")
    print("|---|---|---|---|---|---|")
    ref: np.ndarray | None = None
    f, fmt = (".2f", fmt_rates) if args.success else (".1f", fmt_scores)
    first = methods[0][1] if methods else {}
    for name, scores in methods:
        values = np.array([scores[s] for s in args.seeds if s in scores])
        if len(values) == 0:
            print(f"| {name} | (no rows) | | 0 | | |")
            continue
        per_seed = ", ".join(f"{scores[s]:{f}}" if s in scores else "-" for s in args.seeds)
        diff = ""
        both = [s for s in args.seeds if s in scores and s in first]
        if ref is None:
            ref = values
        elif args.paired and len(both) > 1:
            d = np.array([scores[s] - first[s] for s in both])
            se = d.std(ddof=1) / math.sqrt(len(d))
            diff = f"{d.mean():+{f}} ± {se:{f}} (paired, {len(d)} seeds; {int((d >= 0).sum())} at or above)"
        elif len(values) > 1 and len(ref) > 1:
            se = math.sqrt(ref.var(ddof=1) / len(ref) + values.var(ddof=1) / len(values))
            diff = f"{values.mean() - ref.mean():+{f}} ± {se:{f}}"
        print(
            f"| {name} | {per_seed} | {fmt(list(values))} | {len(values)} | "
            f"{fmt([scores[s] for s in (0, 1, 2) if s in scores])} | {diff} |"
        )


if __name__ == "__main__":
    main()
