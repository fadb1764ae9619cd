"""Training diagnostics of ``sb3-pola score`` cells: what the critic and the actor did, from ``train/<cell>/``.

Each cell's SB3 logger writes ``train/*`` statistics every ``log_interval`` gradient steps. This module
reads them back and writes ``diagnostics.md``: per cell, the statistics at the end of training (the mean
of the last ``window`` rows) and the growth of the look-ahead Q-values along the rollout
(``lookahead_q_T / lookahead_q_0``: above 1 when the actor steers the model into states the critic
values more than the current ones, which a policy that only keeps the data's speed would not do).
"""

from __future__ import annotations

import csv
import math
import pathlib

# the statistics of the table, in order (without the "train/" prefix)
KEYS = [
    "q_mean",
    "target_q",
    "q_ensemble_std",
    "policy_q_ensemble_std",
    "critic_similarity",
    "bc_loss",
    "q_loss",
    "eta",
    "action_saturation",
    "lookahead_alive",
    "actor_grad_norm",
    "critic_grad_norm",
]


def read_train_stats(folder: pathlib.Path) -> list[dict[str, float]]:
    """The ``train/*`` rows of a cell's statistics CSVs (every segment of a resumed run), in step order."""
    rows: list[dict[str, float]] = []
    for path in folder.glob("progress_from*.csv"):
        with path.open(newline="") as f:
            for row in csv.DictReader(f):
                values = {k: float(v) for k, v in row.items() if k and v not in ("", None)}
                if "train/q_mean" in values:  # the dynamics fit logs to the same file; keep the policy's rows
                    rows.append(values)
    return sorted(rows, key=lambda r: r.get("time/total_timesteps", 0.0))


def summarize_cell(rows: list[dict[str, float]], window: int = 2) -> dict[str, float]:
    """Mean of the last ``window`` rows of every statistic, plus ``lookahead_growth`` and ``step``."""
    tail = rows[-window:]
    if not tail:
        return {}
    keys = {k for r in tail for k in r}
    out = {k.removeprefix("train/"): sum(r.get(k, math.nan) for r in tail) / len(tail) for k in keys}
    horizon = max((int(k.rsplit("_", 1)[1]) for k in out if k.startswith("lookahead_q_")), default=0)
    if horizon > 0 and abs(out.get("lookahead_q_0", 0.0)) > 1e-8:
        out["lookahead_growth"] = out[f"lookahead_q_{horizon}"] / out["lookahead_q_0"]
    out["step"] = tail[-1].get("time/total_timesteps", math.nan)
    return out


def _cell_key(name: str) -> tuple[str, str, int]:
    dataset, variant, seed = name.split("__")
    return dataset, variant, int(seed.removeprefix("seed"))


def diagnostics_table(out: pathlib.Path, window: int = 2) -> str:
    """Markdown: one row per cell of ``out/train``, the end-of-training statistics."""
    header = ["cell", "step", *KEYS, "lookahead_growth"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    folders = sorted((p for p in (out / "train").glob("*") if p.is_dir()), key=lambda p: _cell_key(p.name))
    for folder in folders:
        summary = summarize_cell(read_train_stats(folder), window)
        if not summary:
            continue
        cells = [folder.name, f"{summary['step']:.0f}"]
        for key in [*KEYS, "lookahead_growth"]:
            value = summary.get(key, math.nan)
            cells.append("-" if math.isnan(value) else f"{value:.3g}")
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    lines.append(
        f"Means of the last {window} logged rows of each run's `train/*` statistics; lookahead_growth = "
        "lookahead_q_T / lookahead_q_0 (mean top-K Q at the last and the first look-ahead state)."
    )
    return "\n".join(lines) + "\n"


def write_diagnostics(out: pathlib.Path) -> pathlib.Path | None:
    """Write ``out/diagnostics.md`` (``None`` when no cell has statistics yet)."""
    if not (out / "train").is_dir():
        return None
    path = out / "diagnostics.md"
    path.write_text(diagnostics_table(out))
    return path


def plot_lookahead(out: pathlib.Path, cells: list[str] | None = None) -> pathlib.Path | None:
    """``fig_lookahead.png``: mean top-K Q at each look-ahead step over training, a panel per dataset.

    :param out: the score output folder
    :param cells: cell names to draw (default: every cell with a look-ahead)
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folders = [p for p in sorted((out / "train").glob("*")) if p.is_dir() and (cells is None or p.name in cells)]
    series: dict[str, list[tuple[str, list[dict[str, float]]]]] = {}
    for folder in folders:
        rows = read_train_stats(folder)
        if rows and "train/lookahead_q_1" in rows[-1]:
            dataset, variant, seed = _cell_key(folder.name)
            series.setdefault(dataset, []).append((f"{variant} seed {seed}", rows))
    if not series:
        return None
    fig, axes = plt.subplots(1, len(series), figsize=(5.5 * len(series), 3.6), dpi=90, squeeze=False)
    for ax, (dataset, runs) in zip(axes[0], sorted(series.items()), strict=True):
        for label, rows in runs:
            steps = [r["time/total_timesteps"] for r in rows]
            ratio = [r["train/lookahead_q_3" if "train/lookahead_q_3" in r else "train/lookahead_q_1"] for r in rows]
            base = [r["train/lookahead_q_0"] for r in rows]
            ax.plot(steps, [a / b if abs(b) > 1e-8 else math.nan for a, b in zip(ratio, base, strict=True)], label=label)
        ax.axhline(1.0, color="black", lw=0.8, ls=":")
        ax.set_title(f"{dataset}: Q at the last look-ahead state / Q at s_t", fontsize=9)
        ax.set_xlabel("gradient steps")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    path = out / "fig_lookahead.png"
    fig.savefig(path)
    plt.close(fig)
    return path
