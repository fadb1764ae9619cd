"""``sb3-pola score --reevaluate RULE ...``: the saved final models evaluated again under other evaluation rules."""

from __future__ import annotations

import csv
import json
import math
import pathlib
from collections import defaultdict
from typing import Any

from sb3_pola.common.datasets import make_env
from sb3_pola.grid.cell import evaluation_scores
from sb3_pola.grid.report import fmt_rates, fmt_scores
from sb3_pola.grid.rows import REEVAL_FIELDS, csv_header
from sb3_pola.grid.variants import apply_eval_rule, parse_eval_rule
from sb3_pola.pola import POLA


def reevaluate(out: pathlib.Path, rules: list[str], episodes: int, device: str, verbose: int = 1) -> list[dict[str, Any]]:
    """Evaluate every saved final model of ``out/models`` under each rule; rows go to ``reeval.csv``, a table to ``reeval.md``.

    Episodes use the same reset seeds as the score run, so ``ema`` reproduces the run's final evaluation.
    Finished (model, rule) pairs in ``reeval.csv`` are skipped.
    """
    for rule in rules:  # unknown rules fail before any model is loaded
        parse_eval_rule(rule)
    csv_path = out / "reeval.csv"
    done: set[tuple[str, str]] = set()
    if csv_path.exists():
        with csv_path.open(newline="") as f:
            done = {(r["dataset"] + r["variant"] + r["seed"], r["rule"]) for r in csv.DictReader(f)}
    for path in sorted((out / "models").glob("*.zip")):
        marker_path = out / "cells" / f"{path.stem}.json"
        if not marker_path.exists():  # a cell finishing right now: its marker follows its model
            continue
        marker = json.loads(marker_path.read_text())
        dataset, variant, seed = marker["dataset"], marker["variant"], int(marker["seed"])
        model = POLA.load(path, device=device)
        env = make_env(dataset)
        for rule in rules:
            if (dataset + variant + str(seed), rule) in done:
                continue
            deterministic = apply_eval_rule(model, rule)
            row = {
                "dataset": dataset,
                "variant": variant,
                "seed": seed,
                "rule": rule,
                "step": model.num_timesteps,
                **evaluation_scores(model, env, episodes, seed, deterministic=deterministic),
            }
            if csv_path.exists() and csv_header(csv_path) != REEVAL_FIELDS:  # a file from before the success column
                with csv_path.open(newline="") as f:
                    old_rows = list(csv.DictReader(f))
                with csv_path.open("w", newline="") as f:
                    writer = csv.DictWriter(f, fieldnames=REEVAL_FIELDS, restval="nan")
                    writer.writeheader()
                    writer.writerows(old_rows)
            new = not csv_path.exists()
            with csv_path.open("a", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=REEVAL_FIELDS)
                if new:
                    writer.writeheader()
                writer.writerow(row)
            if verbose:
                print(f"[score] re-evaluated {path.stem} under {rule}: {row['score']:.1f}")
        env.close()
    with csv_path.open(newline="") as f:
        rows: list[dict[str, Any]] = [dict(r) for r in csv.DictReader(f)]
    by_key: dict[tuple[str, str, str], list[float]] = defaultdict(list)
    success_by_key: dict[tuple[str, str, str], list[float]] = defaultdict(list)
    for r in rows:
        by_key[(r["dataset"], r["variant"], r["rule"])].append(float(r["score"]))
        success_by_key[(r["dataset"], r["variant"], r["rule"])].append(float(r.get("success") or "nan"))
    with_success = any(not math.isnan(v) for values in success_by_key.values() for v in values)
    head = "| dataset | variant | rule | score | seeds |" + (" success rate | seeds |" if with_success else "")
    lines = [head, "|---|---|---|---|---|" + ("---|---|" if with_success else "")]
    for (dataset, variant, rule), values in sorted(by_key.items()):
        per_seed = ", ".join(f"{v:.1f}" for v in values)
        line = f"| {dataset} | {variant} | {rule} | {fmt_scores(values)} | {per_seed} |"
        if with_success:
            rates = success_by_key[(dataset, variant, rule)]
            line += f" {fmt_rates(rates)} | {', '.join(f'{v:.2f}' for v in rates)} |"
        lines.append(line)
    (out / "reeval.md").write_text("\n".join(lines) + "\n")
    return rows
