"""#23: where T = 3 is behind T = 0, what the training statistics say. *Needs the screens' outputs.*

Reads ``OUT/<dataset>/<name>/seed<S>/progress.csv`` that ``screen.py`` writes (``OUT``: ``outputs/policy_quality``, or
``--out``) for the package defaults (T = 3) and T = 0, and prints per dataset the mean over seeds of the statistics
over the last 1,000 steps: the critics' Q at the data's actions (``q_mean``) and at the actor's (``lookahead_q_0``),
the actor's pessimistic Q at the third predicted state (``lookahead_q_3``), the ensemble's spread at the actor's
actions over its spread at the data's, the model's disagreement at the third step and the Q term's gradient over the
BC term's. With the scores of ``OUT/screen.jsonl`` (``--rule``, the one-chain rule by default; the last row of a seed,
over the seeds whose statistics are there). ``python experiments/policy_quality/lookahead_diag.py [--runs
DATASET:T3_NAME:T0_NAME ...] [--rule mode]`` (default: the eighth pass's names below).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import statistics

import pandas as pd

# dataset -> (T = 3 screen name, T = 0 screen name): the defaults of 2026-12-04 (run.sh, seventh and eighth passes)
RUNS = {
    "halfcheetah/medium-v0": ("MCCI-LN", "T0MCCI-LN"),
    "halfcheetah/medium-replay-v0": ("MCCI-LN", "T0MCCI-LN"),
    "hopper/medium-v0": ("MCCI-LN", "T0MCCI-LN"),
    "hopper/medium-replay-v0": ("MCCI-LN", "T0MCCI-LN"),
    "pointmaze/umaze-v0": ("FGMCCI-LN", "T0MCCI-LN"),
    "pointmaze/medium-v0": ("FGMCCI-LN", "T0MCCI-LN"),
}
COLUMNS = {  # printed name -> how it is made from the last rows of progress.csv
    "Q data": lambda d: d["train/q_mean"].mean(),
    "Q actor": lambda d: d["train/lookahead_q_0"].mean(),
    "Q s3": lambda d: d["train/lookahead_q_3"].mean() if "train/lookahead_q_3" in d else float("nan"),
    "spread actor/data": lambda d: (d["train/policy_q_ensemble_std"] / d["train/q_ensemble_std"]).mean(),
    "model u3": lambda d: d["train/lookahead_uncertainty_3"].mean() if "train/lookahead_uncertainty_3" in d else float("nan"),
    "grad Q/BC": lambda d: d["train/q_bc_grad_ratio"].dropna().mean(),
}


def seeds_of(folder: pathlib.Path) -> list[int]:
    """The seeds whose training statistics ``folder`` holds."""
    return sorted(int(path.parent.name.removeprefix("seed")) for path in folder.glob("seed*/progress.csv"))


def stats(folder: pathlib.Path) -> dict[str, float] | None:
    runs = []
    for path in sorted(folder.glob("seed*/progress.csv")):
        d = pd.read_csv(path)
        runs.append(
            {name: float(fn(d[d["train/n_updates"] > d["train/n_updates"].max() - 1000])) for name, fn in COLUMNS.items()}
        )
    if not runs:
        return None
    return {name: statistics.mean(r[name] for r in runs) for name in COLUMNS}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="outputs/policy_quality")
    parser.add_argument("--runs", nargs="*", help="DATASET:T3_NAME:T0_NAME, e.g. hopper/medium-v0:LRC:T0LRC")
    parser.add_argument("--rule", default="obsnoise", help="the score column of screen.jsonl (e.g. mode)")
    args = parser.parse_args()
    out = pathlib.Path(args.out)
    runs = RUNS if not args.runs else {r.split(":")[0]: tuple(r.split(":")[1:3]) for r in args.runs}
    scores: dict[tuple[str, str], dict[int, float]] = {}  # the last row of each seed with the rule's score
    for line in (out / "screen.jsonl").read_text().splitlines():
        row = json.loads(line)
        if args.rule in row:
            scores.setdefault((row["dataset"], row["name"]), {})[int(row["seed"])] = row[args.rule]
    print("| dataset | T | seeds | score | " + " | ".join(COLUMNS) + " |")
    print("|---|---|---|---|" + "---|" * len(COLUMNS))
    for dataset, names in runs.items():
        for horizon, name in zip((3, 0), names, strict=True):
            folder = out / dataset.replace("/", "_") / name
            row = stats(folder)
            if row is None:
                continue
            seeds = seeds_of(folder)
            scored = [scores[(dataset, name)][s] for s in seeds if s in scores.get((dataset, name), {})]
            score = f"{statistics.mean(scored):.1f}" if scored else "-"
            print(
                f"| {dataset} | {horizon} | {' '.join(map(str, seeds))} | {score} | "
                + " | ".join(f"{v:.3g}" for v in row.values())
                + " |"
            )


if __name__ == "__main__":
    main()
