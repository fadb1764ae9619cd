"""The U-maze's imitation floor over 40 seeds (docs/results.md, twenty-seventh and thirty-fourth passes).

    python experiments/umaze_floor40/table.py
    python experiments/umaze_floor40/table.py --screen amd-mode-seeds --rule mode

Reads the final evaluations kept here (``bc_scores.csv``: BC with the package's actor; ``peers.csv``: d3rlpy's BC;
``experiments/umaze_floor40/run.sh``), or with ``--screen`` the package's BC from the screens' rows
(``experiments/policy_quality/screen.jsonl``, screen ``BCRNW`` of that collection, scored under ``--rule``), and
prints markdown: every seed, mean ± sample std, the difference of the means
with Welch's standard error and a bootstrap interval over seeds, and how the done-when's 3-seed comparison comes out
on the disjoint triples of seeds (0-2, 3-5, ...): how often BC with the package's actor is at or above d3rlpy's BC.
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys

import numpy as np

from sb3_pola.grid.report import fmt_rates, fmt_scores, summarize
from sb3_pola.grid.rows import read_rows

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "policy_quality"))
from screen_table import read as read_screens  # noqa: E402  (the screens' rows, one reader)

STEPS = 10_000
DATASET = "pointmaze/umaze-v0"
METHODS = {
    "BC, package actor": (HERE / "bc_scores.csv", "BC"),
    "d3rlpy BC": (HERE / "peers.csv", "d3rlpy-BC"),
}


def finals(path: pathlib.Path, variant: str) -> tuple[dict[int, float], dict[int, float]]:
    """``{seed: score}`` and ``{seed: success rate}`` of the runs of a variant that reached ``STEPS``."""
    entry = summarize(read_rows(path)).get((DATASET, variant))
    if entry is None:
        return {}, {}
    done = [i for i, step in enumerate(entry["steps"]) if step == STEPS]
    return (
        {entry["seeds"][i]: entry["final"][i] for i in done},
        {entry["seeds"][i]: entry["success"][i] for i in done},
    )


def screened(collection: str, rule: str) -> tuple[dict[int, float], dict[int, float]]:
    """``{seed: score}`` and ``{seed: success rate}`` of the BC screens (``BCRNW``) of a collection under ``rule``."""
    cells = read_screens(HERE.parent / "policy_quality" / "screen.jsonl", ["BCRNW"], rule, collection)
    rows = cells.get((DATASET, "BCRNW"), {})
    return {s: r[rule] for s, r in rows.items()}, {s: r.get(f"{rule}_success", float("nan")) for s, r in rows.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--screen", default=None, help="the package's BC from the screens of this collection")
    parser.add_argument("--rule", default="mode", help="with --screen: the evaluation rule's column")
    args = parser.parse_args()
    scores, success = {}, {}
    for name, source in METHODS.items():
        scores[name], success[name] = finals(*source)
    if args.screen is not None:
        scores["BC, package actor"], success["BC, package actor"] = screened(args.screen, args.rule)
    seeds = sorted(set.intersection(*(set(s) for s in scores.values())))
    if not seeds:
        raise SystemExit("no seed has both methods' final evaluations: run experiments/umaze_floor40/run.sh first")
    arrays = {name: np.array([s[seed] for seed in seeds]) for name, s in scores.items()}
    print(f"{DATASET}, {STEPS} steps, 10 episodes, seeds {seeds[0]}-{seeds[-1]} ({len(seeds)})\n")
    print("| method | seeds in order | mean ± std | success | seeds 0-2 |")
    print("|---|---|---|---|---|")
    for name, values in arrays.items():
        every = ", ".join(f"{v:.1f}" for v in values)
        rates = [success[name][seed] for seed in seeds]
        print(f"| {name} | {every} | {fmt_scores(list(values))} | {fmt_rates(rates)} | {fmt_scores(list(values[:3]))} |")

    ours, theirs = arrays["BC, package actor"], arrays["d3rlpy BC"]
    diff = ours.mean() - theirs.mean()
    se = math.sqrt(ours.var(ddof=1) / len(ours) + theirs.var(ddof=1) / len(theirs))
    rng = np.random.default_rng(0)
    boot = [rng.choice(ours, len(ours)).mean() - rng.choice(theirs, len(theirs)).mean() for _ in range(10_000)]
    low, high = np.percentile(boot, [2.5, 97.5])
    print(
        f"\npackage - d3rlpy: {diff:+.1f} (Welch's standard error {se:.1f}; "
        f"95% bootstrap interval over seeds {low:+.1f} to {high:+.1f})"
    )
    triples = [seeds[i : i + 3] for i in range(0, len(seeds) - 2, 3)]
    met = [
        np.mean([scores["BC, package actor"][s] for s in t]) >= np.mean([scores["d3rlpy BC"][s] for s in t]) for t in triples
    ]
    won = ", ".join(f"{t[0]}-{t[-1]}" for t, m in zip(triples, met, strict=True) if m) or "none"
    print(
        f"the done-when's 3-seed comparison on the {len(triples)} disjoint triples of seeds: the package's BC at or "
        f"above d3rlpy's BC on {sum(met)} ({won})"
    )


if __name__ == "__main__":
    main()
