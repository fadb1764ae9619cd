"""#23: the look-ahead's training statistics of long runs in 5,000-step bins, next to the evaluations' steps.

For each run folder (``<OUT>/train/<dataset>__<variant>__seed<S>`` that ``sb3-pola score`` writes, its
``progress_from*.csv`` read in order) one line per bin: the critic's pessimistic Q at the third predicted state minus
at the current one (``train/lookahead_q_3 - train/lookahead_q_0``; blank at T = 0), the Q term's gradient over the
imitation term's (``train/q_bc_grad_ratio``) and, with ``lookahead_trust_margin``, the share of predicted terms kept
(``train/lookahead_trusted``). ``python experiments/long100k/dip_diag.py RUN_FOLDER ... [--bin 5000]``
"""

from __future__ import annotations

import argparse
import math
import pathlib

import pandas as pd


def binned(folder: pathlib.Path, width: int) -> pd.DataFrame:
    """``[bins, 3]``: the statistics' means over each ``width`` steps, the bin named by its last step."""
    frames = [pd.read_csv(path) for path in sorted(folder.glob("progress_from*.csv"))]
    if not frames:
        raise SystemExit(f"{folder}: no progress_from*.csv")
    d = pd.concat(frames)
    d = d[d["train/n_updates"].notna()]
    column = lambda name: d[name] if name in d else pd.Series(math.nan, index=d.index)  # noqa: E731
    stats = pd.DataFrame(
        {
            "q3_minus_q0": column("train/lookahead_q_3") - column("train/lookahead_q_0"),
            "grad_q_over_bc": column("train/q_bc_grad_ratio"),
            "trusted": column("train/lookahead_trusted"),
        }
    )
    step_bin = ((d["train/n_updates"] - 1) // width + 1) * width
    return stats.groupby(step_bin.astype(int)).mean()  # each column's mean skips its blank rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=pathlib.Path, help="run folders: <OUT>/train/<run>")
    parser.add_argument("--bin", type=int, default=5000, help="steps per bin (the evaluations' spacing)")
    args = parser.parse_args()
    print("| run | step | Q(s_3) - Q(s_0) | grad Q / grad BC | trusted |")
    print("|---|---|---|---|---|")
    for folder in args.runs:
        for step, row in binned(folder, args.bin).iterrows():
            cells = [f"{row[c]:+.2f}" if c == "q3_minus_q0" else f"{row[c]:.2f}" for c in row.index]
            cells = ["-" if c in ("nan", "+nan") else c for c in cells]
            print(f"| {folder.name} | {step} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
