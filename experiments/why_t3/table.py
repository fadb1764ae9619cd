"""#12: why T=3 falls below T=0 -- the critic's view at the end of the 10k runs (3 seeds each).

Reads the training statistics that every score cell writes (train/<cell>/progress_from*.csv) and prints,
per dataset and variant, the mean over steps 9,000-10,000 of: the critics' Q at the data (q_mean), the
growth of Q along the look-ahead (lookahead_q_3 / lookahead_q_0), the fraction of saturated action
components, and the critics' spread at the actor's actions relative to their spread at the data's actions
(policy_q_ensemble_std / q_ensemble_std, in the runs that log it). Run from the repository root:

    python experiments/why_t3/table.py
"""

import glob
import os
import pathlib

import numpy as np
import pandas as pd

RUNS = {  # run folder -> label of its look-ahead states
    "score10k": "through the model",
    "nobackprop": "detached",
    "nobackprop_replay": "detached",
}


def cell_stats(cell: pathlib.Path) -> dict:
    frames = [pd.read_csv(f) for f in sorted(cell.glob("progress_from*.csv"))]
    d = pd.concat(frames).sort_values("train/n_updates")
    t = d[d["train/n_updates"] > 9000]

    def mean(column: str) -> float:
        return float(t[column].mean()) if column in t and t[column].notna().any() else float("nan")

    return {
        "q": mean("train/q_mean"),
        "growth": mean("train/lookahead_q_3") / mean("train/lookahead_q_0"),
        "saturation": mean("train/action_saturation"),
        "spread": mean("train/policy_q_ensemble_std") / mean("train/q_ensemble_std"),
    }


def fmt(values: list[float], digits: int) -> str:
    values = [v for v in values if not np.isnan(v)]
    if not values:
        return "-"
    per_seed = ", ".join(f"{v:.{digits}f}" for v in values)
    return f"{np.mean(values):.{digits}f} ({per_seed})"


def main() -> None:
    root = pathlib.Path(os.environ.get("RUNS", "outputs"))  # the recipes' raw outputs (train/)
    columns = ["dataset", "variant", "look-ahead states", "Q at the data", "q_3 / q_0", "action saturation"]
    print("| " + " | ".join([*columns, "critics' spread, actor / data"]) + " |")
    print("|---|---|---|---|---|---|---|")
    for run, states in RUNS.items():
        groups: dict[tuple[str, str], list[dict]] = {}
        for cell in sorted(glob.glob(str(root / run / "train" / "*"))):
            dataset, variant, _ = pathlib.Path(cell).name.split("__")
            groups.setdefault((dataset, variant), []).append(cell_stats(pathlib.Path(cell)))
        for (dataset, variant), stats in sorted(groups.items()):
            label = states if variant.startswith("T") and variant != "T0" else "-"
            print(
                f"| {dataset.removeprefix('halfcheetah_')} | {variant} | {label} | {fmt([s['q'] for s in stats], 1)} | "
                f"{fmt([s['growth'] for s in stats], 3)} | {fmt([s['saturation'] for s in stats], 3)} | "
                f"{fmt([s['spread'] for s in stats], 2)} |"
            )


if __name__ == "__main__":
    main()
