"""#12: end-of-training critic statistics of the critic-diversity cells next to the 10k grid's (means of the last
1,000 steps, seeds pooled). ``python experiments/edac/diag.py`` prints a Markdown table."""

from __future__ import annotations

import csv
import math
import os
import pathlib
import statistics

ROOT = pathlib.Path(__file__).resolve().parents[1]
# the recipes' raw outputs (train/, models/): outputs/<run> unless RUNS names another folder
RUNS = pathlib.Path(os.environ.get("RUNS", ROOT.parent / "outputs"))
FOLDERS = {
    "grid": "score10k",
    "diversity": "edac/div1.0",
    "diversity, detached": "edac/div1.0_detached",
    "detached": "nobackprop",
    "detached ": "nobackprop_replay",
    "diversity, states and actions": "edac/div1.0_sa",
}
KEYS = ["q_mean", "q_ensemble_std", "policy_q_ensemble_std", "critic_similarity", "action_saturation"]


def tail_means(folder: pathlib.Path) -> dict[str, float]:
    rows = []
    for path in folder.glob("progress_from*.csv"):
        rows += list(csv.DictReader(path.open()))
    rows = [r for r in rows if r.get("time/total_timesteps")]
    rows.sort(key=lambda r: float(r["time/total_timesteps"]))
    last = [r for r in rows if float(r["time/total_timesteps"]) > 9_000]
    out = {}
    for key in KEYS:
        values = [float(r[f"train/{key}"]) for r in last if r.get(f"train/{key}") not in (None, "")]
        out[key] = statistics.mean(values) if values else math.nan
    return out


def main() -> None:
    columns = ["dataset", "variant", "critics", "seeds", "Q at data", "critics' std at data"]
    columns += ["at actor's actions (ratio)", "similarity", "saturation"]
    print("| " + " | ".join(columns) + " |")
    print("|---|---|---|---|---|---|---|---|---|")
    for dataset in ("halfcheetah_medium-v0", "halfcheetah_medium-replay-v0"):
        for variant in ("T0", "T3"):
            for label, folder in FOLDERS.items():
                cells = sorted((RUNS / folder / "train").glob(f"{dataset}__{variant}__seed*"))
                if not cells:
                    continue
                stats = [s for s in (tail_means(c) for c in cells) if not math.isnan(s["q_mean"])]  # finished cells
                if not stats:
                    continue
                cells = cells[: len(stats)]
                m = {k: statistics.mean(s[k] for s in stats) for k in KEYS}  # nan where a key was not logged
                ratio = m["policy_q_ensemble_std"] / m["q_ensemble_std"]
                fmt = lambda v: "-" if math.isnan(v) else f"{v:.3g}"  # noqa: E731
                print(
                    f"| {dataset.split('_')[1]} | {variant} | {label.strip()} | {len(cells)} | {fmt(m['q_mean'])} | "
                    f"{fmt(m['q_ensemble_std'])} | {fmt(m['policy_q_ensemble_std'])} ({fmt(ratio)}) | "
                    f"{fmt(m['critic_similarity'])} | {fmt(m['action_saturation'])} |"
                )


if __name__ == "__main__":
    main()
