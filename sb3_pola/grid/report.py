"""The score grid's reports: ``table.md`` (final and best scores next to the paper's Table I, the d3rlpy baselines),
the learning-curve figures, and ``diagnostics.md``, from ``scores.csv`` and ``peers.csv``.
"""

from __future__ import annotations

import json
import math
import pathlib
from collections import defaultdict
from typing import TYPE_CHECKING, Any

import numpy as np

from sb3_pola.common.datasets import load_offline_dataset
from sb3_pola.grid.diagnostics import write_diagnostics
from sb3_pola.grid.rows import read_rows, slug
from sb3_pola.grid.variants import FIGURES, PAPER_TABLE_I, VARIANTS, paper_task

if TYPE_CHECKING:
    from sb3_pola.grid.storage import Workspace


# d3rlpy baselines of ``sb3-pola peers`` (``peers.csv`` next to ``scores.csv``): table rows after POLA's, curves
PEER_VARIANTS = ["d3rlpy-TD3+BC", "d3rlpy-IQL", "d3rlpy-BC"]
PEER_STYLES: dict[str, tuple[str, str]] = {
    "d3rlpy-TD3+BC": ("tab:brown", "--"),
    "d3rlpy-IQL": ("tab:pink", "-."),
    "d3rlpy-BC": ("goldenrod", ":"),
}


def is_peer(variant: str) -> bool:
    """Whether a variant is a d3rlpy baseline (``d3rlpy-*``, from ``peers.csv``)."""
    return variant.startswith("d3rlpy-")


def fmt_rates(values: list[float]) -> str:
    values = [v for v in values if not math.isnan(v)]
    if not values:
        return "-"
    if len(values) == 1:
        return f"{values[0]:.2f}"
    return f"{np.mean(values):.2f} ± {np.std(values, ddof=1):.2f}"


def fmt_scores(values: list[float]) -> str:
    values = [v for v in values if not math.isnan(v)]
    if not values:
        return "-"
    if len(values) == 1:
        return f"{values[0]:.1f}"  # one seed: no spread to show
    return f"{np.mean(values):.1f} ± {np.std(values, ddof=1):.1f}"


def summarize(rows: list[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    """Per (dataset, variant): final and best score per seed, the last step reached and the seeds.

    ``final`` is the score of each seed's last evaluation, ``best`` the maximum over its evaluations.
    """
    by_cell: dict[tuple[str, str, int], list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        by_cell[(row["dataset"], row["variant"], row["seed"])].append(row)
    out: dict[tuple[str, str], dict[str, Any]] = {}
    for (dataset, variant, seed), cell in sorted(by_cell.items()):
        cell.sort(key=lambda r: r["step"])
        entry = out.setdefault(
            (dataset, variant), {"final": [], "best": [], "steps": [], "seeds": [], "wall_s": [], "success": []}
        )
        entry["final"].append(cell[-1]["score"])
        entry["success"].append(cell[-1].get("success", math.nan))
        entry["best"].append(max(r["score"] for r in cell))
        entry["steps"].append(cell[-1]["step"])
        entry["seeds"].append(seed)
        entry["wall_s"].append(cell[-1]["wall_s"])
    return out


def dataset_score(dataset: str) -> float | None:
    """Mean normalised return of the dataset's own episodes (what pure imitation would reach)."""
    try:
        data = load_offline_dataset(dataset)
        if len(data.episode_returns) == 0:
            return None
        return data.normalized_score(data.episode_returns)
    except Exception:  # a report must not fail on a dataset that moved
        return None


def markdown_table(
    rows: list[dict[str, Any]],
    variants: list[str],
    config: dict[str, Any] | None = None,
    peers_config: dict[str, Any] | None = None,
) -> str:
    """Table-I-style markdown: one line per (dataset, variant), final and best score mean ± std over seeds.

    Rows of d3rlpy baselines (variants ``d3rlpy-*``, from ``peers.csv``) come after each dataset's POLA rows;
    ``peers_config`` (``peers_config.json``) describes their budget and d3rlpy version.
    """
    summary = summarize(rows)
    lines = []
    if config:
        lines.append(
            f"Budget: {config.get('steps')} gradient steps per run, evaluation every {config.get('eval_freq')} steps "
            f"on {config.get('eval_episodes')} episodes (preset `{config.get('preset')}`, device {config.get('device')}), "
            f"evaluation rule `{config.get('eval_rule', 'ema')}`."
        )
        lines.append("")
    if any(is_peer(v) for (_, v) in summary):
        text = "Rows `d3rlpy-*`: d3rlpy baselines (`sb3-pola peers`, `peers.csv`) trained on the same arrays"
        if peers_config:
            version = peers_config.get("versions", {}).get("d3rlpy", "?")
            text += (
                f", d3rlpy {version}, {peers_config.get('steps')} gradient steps per run, evaluation every "
                f"{peers_config.get('eval_freq')} steps on {peers_config.get('eval_episodes')} episodes"
            )
        text += (
            " with the same evaluation protocol (deterministic actions, the same reset seeds, D4RL-normalised); "
            "d3rlpy's hyperparameters: TD3+BC alpha 2.5 on standardised states, IQL with return-based reward "
            "scaling (x1000) and a cosine actor learning rate, BC (deterministic, MSE)."
        )
        lines.append(text)
        lines.append("")
    # goal-reaching envs (mazes) report success: a column of the final evaluations' success rates
    with_success = any(not math.isnan(v) for entry in summary.values() for v in entry["success"])
    success_head, success_rule = (" final success rate |", "---|") if with_success else ("", "")
    lines.append(
        "| dataset | variant | final | best | seeds | steps | wall s / run | dataset mean | paper POLA (D4RL v2) |"
        + success_head
    )
    lines.append("|---|---|---|---|---|---|---|---|---|" + success_rule)
    datasets = list(dict.fromkeys(r["dataset"] for r in rows))
    for dataset in datasets:
        task = paper_task(dataset)
        paper = PAPER_TABLE_I.get(task, "-") if task else "-"
        data_score = dataset_score(dataset)
        data_text = "-" if data_score is None else f"{data_score:.1f}"
        ordered = [v for v in variants if (dataset, v) in summary] + sorted(
            v for (d, v) in summary if d == dataset and v not in variants and not is_peer(v)
        )
        peers = [v for (d, v) in summary if d == dataset and is_peer(v)]
        ordered += [v for v in PEER_VARIANTS if v in peers] + sorted(v for v in peers if v not in PEER_VARIANTS)
        for variant in ordered:
            entry = summary[(dataset, variant)]
            steps = "/".join(str(s) for s in sorted(set(entry["steps"])))
            seeds = ",".join(str(s) for s in entry["seeds"])
            wall = f"{np.mean(entry['wall_s']):.0f}"
            lines.append(
                f"| {dataset} | {variant} | {fmt_scores(entry['final'])} | {fmt_scores(entry['best'])} | {seeds} | {steps} "
                f"| {wall} "
                f"| {data_text} | {paper} |" + (f" {fmt_rates(entry['success'])} |" if with_success else "")
            )
    lines.append("")
    lines.append(
        "final: score of the last evaluation; best: best evaluation of each run; mean ± sample std over seeds "
        "(a single number: one seed). Scores are D4RL-normalised (100 = the dataset's reference expert)."
        + (" Success rate: the fraction of the final evaluation's episodes that reached the goal." if with_success else "")
    )
    return "\n".join(lines) + "\n"


def plot_curves(rows: list[dict[str, Any]], out: pathlib.Path) -> list[pathlib.Path]:
    """Learning curves like the paper's Fig. 3 (rollout length) and Fig. 4 (products), a PNG per dataset and figure.

    d3rlpy baselines (``d3rlpy-*`` rows): TD3+BC is drawn dashed in both figures, and ``fig_peers_<dataset>.png``
    shows every baseline next to POLA's T0, T3 and BC (those present).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves: dict[tuple[str, str], dict[int, dict[int, float]]] = defaultdict(lambda: defaultdict(dict))
    for row in rows:
        curves[(row["dataset"], row["variant"])][row["step"]][row["seed"]] = row["score"]
    written = []
    colors = {
        "T0": "tab:blue",
        "T1": "tab:orange",
        "T3": "tab:red",
        "T5": "tab:green",
        "T3-products": "tab:cyan",
        "T0-products": "tab:olive",
        "T3-noproducts": "tab:pink",
        "T0-noproducts": "tab:brown",
        "T3-criticproducts": "tab:purple",
        "BC": "tab:gray",
    }
    for dataset in dict.fromkeys(r["dataset"] for r in rows):
        data_score = dataset_score(dataset)
        figures = {**FIGURES, "peers": ["T0", "T3", "BC", *PEER_VARIANTS]}
        for figure, members in figures.items():
            present = [v for v in members if (dataset, v) in curves]
            if figure == "peers":
                if not any(is_peer(v) for v in present):
                    continue
                present += sorted(v for (d, v) in curves if d == dataset and is_peer(v) and v not in present)
            elif len([v for v in present if v != "BC"]) < 2:
                continue  # a comparison needs two variants
            else:
                present += [v for v in PEER_VARIANTS[:1] if (dataset, v) in curves]  # TD3+BC, dashed
            fig, ax = plt.subplots(figsize=(5.5, 3.6), dpi=90)
            for variant in present:
                by_step = curves[(dataset, variant)]
                steps = sorted(by_step)
                mean = np.array([np.mean(list(by_step[s].values())) for s in steps])
                std = np.array([np.std(list(by_step[s].values())) for s in steps])
                n_seeds = max(len(by_step[s]) for s in steps)
                style = "--" if variant == "BC" else "-"
                color = colors.get(variant)
                if is_peer(variant):
                    color, style = PEER_STYLES.get(variant, ("black", "--"))
                label = VARIANTS[variant][0] if variant in VARIANTS else variant
                ax.plot(steps, mean, style, marker="o", ms=3, color=color, label=f"{label} (n={n_seeds})")
                if n_seeds > 1:
                    ax.fill_between(steps, mean - std, mean + std, color=color, alpha=0.15)
            if data_score is not None:
                ax.axhline(data_score, color="black", ls=":", lw=1, label="dataset mean")
            title = {"rollout": "rollout length T", "products": "state products"}.get(figure, "d3rlpy baselines")
            ax.set_title(f"{dataset}: {title}", fontsize=10)
            ax.set_xlabel("gradient steps")
            ax.set_ylabel("normalised score")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
            fig.tight_layout()
            path = out / f"fig_{figure}_{slug(dataset)}.png"
            fig.savefig(path)
            plt.close(fig)
            written.append(path)
    return written


def write_reports(out: pathlib.Path, variants: list[str], config: dict[str, Any] | None = None, shown: str = "") -> None:
    """``table.md`` and the figures from ``scores.csv``, with the d3rlpy baselines of ``peers.csv`` when it exists.

    :param out: output folder
    :param variants: the variants of the table, in order
    :param config: the content of ``config.json``
    :param shown: how the output is named in messages (default: the folder)
    """
    shown = (shown or str(out)).rstrip("/")
    rows = read_rows(out / "scores.csv")
    peer_rows = [r for r in read_rows(out / "peers.csv") if is_peer(r["variant"])]
    if not rows and not peer_rows:
        print(f"[score] no evaluations in {shown}/scores.csv yet")
        return
    peers_path = out / "peers_config.json"
    peers_config = json.loads(peers_path.read_text()) if peer_rows and peers_path.exists() else None
    rows = rows + peer_rows
    (out / "table.md").write_text(markdown_table(rows, variants, config, peers_config))
    paths = plot_curves(rows, out)
    print(f"[score] wrote {shown}/table.md" + "".join(f", {p.name}" for p in paths))


def publish_reports(view: Workspace, variants: list[str], config: dict[str, Any] | None = None) -> None:
    """:func:`write_reports` and ``diagnostics.md`` in a workspace: their inputs pulled, the outputs pushed.

    :param view: the workspace of the output
    :param variants: the variants of the table, in order
    :param config: the content of ``config.json``
    """
    view.pull("scores.csv", "peers.csv", "peers_config.json")
    view.pull_tree("train")
    write_reports(view.folder, variants, config, shown=view.shown())
    write_diagnostics(view.folder)
    view.push("table.md", "diagnostics.md", *sorted(view.folder.glob("fig_*.png")))
