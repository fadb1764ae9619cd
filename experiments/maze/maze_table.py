"""#14: the sparse-reward maze table (README and docs/results.md) from the score and peers CSVs.

Final evaluation (step 10,000) of every run: the normalised score and the success rate (the fraction of the
10 episodes that came within 0.45 of the goal), mean ± sample std over seeds, every seed listed. POLA runs
of the U-maze made before the success column existed take their success rate from the re-evaluation of
the same final model under the same rule (`reeval.csv`, rule `ema`, which reproduces each run's score).
Run from the repository root:

    python experiments/maze/maze_table.py
"""

import math
import pathlib

import pandas as pd

REPO = pathlib.Path(__file__).resolve().parents[2]  # the paths below are relative to the repository

SOURCES = {  # dataset -> (folders of scores.csv / peers.csv / reeval.csv, label)
    "pointmaze/umaze-v0": (["experiments/maze_hint", "experiments/maze_detached"], "U-maze"),
    "pointmaze/medium-v0": (["experiments/maze_medium"], "medium maze"),
}
VARIANTS = {  # (folder, variant) -> row label; None = every folder
    "BC": "BC (same actor, eta = 0)",
    "T0": "POLA T = 0",
    "T1": "POLA T = 1",
    "T3": "POLA T = 3",
    "T3 detached": "POLA T = 3, detached look-ahead states",
    "d3rlpy-TD3+BC": "d3rlpy TD3+BC",
    "d3rlpy-IQL": "d3rlpy IQL",
    "d3rlpy-BC": "d3rlpy BC",
}
STEP = 10_000


def read(folder: pathlib.Path, name: str) -> pd.DataFrame:
    path = folder / name
    return pd.read_csv(path) if path.is_file() else pd.DataFrame()


def final_rows(folder: pathlib.Path) -> pd.DataFrame:
    rows = pd.concat([read(folder, "scores.csv"), read(folder, "peers.csv")], ignore_index=True)
    if rows.empty:
        return rows
    rows = rows[rows["step"] == STEP].copy()
    if "success" not in rows:
        rows["success"] = math.nan
    reeval = read(folder, "reeval.csv")
    if not reeval.empty:  # the success rate of runs from before the column, by the same rule
        ema = reeval[(reeval["rule"] == "ema") & (reeval["step"] == STEP)].set_index(["dataset", "variant", "seed"])
        for i, row in rows[rows["success"].isna()].iterrows():
            key = (row["dataset"], row["variant"], row["seed"])
            if key in ema.index:
                rows.loc[i, "success"] = ema.loc[key, "success"]
    if folder.name == "maze_detached":
        rows["variant"] = rows["variant"] + " detached"
    return rows


def cell(values: pd.Series, digits: int) -> str:
    values = values.dropna()
    if values.empty:
        return "-"
    per_seed = ", ".join(f"{v:.{digits}f}" for v in values)
    if len(values) == 1:
        return f"{values.iloc[0]:.{digits}f} (one seed)"
    return f"{values.mean():.{digits}f} ± {values.std():.{digits}f} ({per_seed})"


def main() -> None:
    print("| maze | method | normalised score (per seed) | success rate (per seed) |")
    print("|---|---|---|---|")
    for dataset, (folders, label) in SOURCES.items():
        rows = pd.concat([final_rows(REPO / f) for f in folders], ignore_index=True)
        rows = rows[rows["dataset"] == dataset] if not rows.empty else rows
        for variant, name in VARIANTS.items():
            runs = rows[rows["variant"] == variant].sort_values("seed") if not rows.empty else rows
            if runs.empty:
                continue
            print(f"| {label} | {name} | {cell(runs['score'], 1)} | {cell(runs['success'], 2)} |")


if __name__ == "__main__":
    main()
