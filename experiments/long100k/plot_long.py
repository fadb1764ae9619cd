"""#23's long-run comparisons, one figure each (mean over seeds, a band of one standard deviation):

    python experiments/long100k/plot_long.py [--figure NAME]  (NAME: one of the figures below; default eta)

- ``eta`` (twentieth pass): hopper/medium at the two values of eta, T = 0 and T = 3, BC with the package's actor and
  d3rlpy's TD3+BC (``lrc/scores.csv`` the defaults, ``lrc/t3_eta1_scores.csv``, ``lrc/t0_scores.csv``,
  ``lrc/t0_eta1_scores.csv``, ``lrc/bc_scores.csv``, ``peers.csv``);
- ``cd5_halfcheetah`` (twenty-second pass): halfcheetah/medium-replay, the defaults against ``critic_diversity`` 5
  (``lrc/cd5_scores.csv``), with BC and TD3+BC;
- ``cd5_hopper_amd`` (twenty-second pass): hopper/medium of the AMD collection (``hopper_amd/``: another file than the
  other hopper rows, see ``experiments/hopper/collect_summary.json``), the defaults, ``critic_diversity`` 5 and BC.
- ``mode_halfcheetah``, ``mode_hopper_amd`` (thirtieth pass): the defaults of 2026-12-06 (the raw-state ReLU actor,
  the mode rule; ``amd_mode/scores.csv``) against the defaults before, BC with the package's actor before and
  d3rlpy's three (on hopper, run on the AMD collection: ``amd_mode/peers.csv``);
- ``long_halfcheetah``, ``long_hopper`` (thirty-third pass): #23's long-run figures as its done-when asks, the
  defaults, BC with the package's actor and d3rlpy's three, nothing else (the ``mode_*`` figures' curves without the
  defaults before);
- ``dip30k`` (thirty-second pass): hopper/medium's first 30,000 steps (AMD collection), the defaults against
  ``lookahead_trust_margin`` 0 (by the value rule and, thirty-third pass, the Bellman rule) and T = 0
  (``amd_mode/dip30k.csv``) and BC with the package's actor.

``--out PNG`` writes elsewhere. ``--table`` prints the figure's curves as a Markdown table instead: each seed's score
at the budget's end (or at the last step it reached) and its mean over the evaluations from ``--late`` steps on
(default 30000), and the mean ± std over the seeds that finished.
"""

from __future__ import annotations

import argparse
import pathlib
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from sb3_pola.grid.rows import read_rows

HERE = pathlib.Path(__file__).parent
# name: (dataset, title, y limits, [(label, file, variant, colour, line style)])
FIGURES = {
    "eta": (
        "hopper/medium-v0",
        "the Q term's weight over 100,000 steps",
        (10, 80),
        [
            ("POLA defaults (T = 3, eta 3.94)", "lrc/scores.csv", "T3", "tab:red", "-"),
            ("POLA T = 3, eta 1", "lrc/t3_eta1_scores.csv", "T3", "tab:purple", "-"),
            ("POLA T = 0, eta 3.94", "lrc/t0_scores.csv", "T0", "tab:blue", "-"),
            ("POLA T = 0, eta 1", "lrc/t0_eta1_scores.csv", "T0", "tab:cyan", "-"),
            ("BC, package actor", "lrc/bc_scores.csv", "BC", "tab:gray", "--"),
            ("d3rlpy TD3+BC", "peers.csv", "d3rlpy-TD3+BC", "black", "--"),
        ],
    ),
    "cd5_halfcheetah": (
        "halfcheetah/medium-replay-v0",
        "critic_diversity 5 over 100,000 steps",
        (0, 50),
        [
            ("POLA defaults (critic_diversity 1)", "lrc/scores.csv", "T3", "tab:red", "-"),
            ("POLA critic_diversity 5", "lrc/cd5_scores.csv", "T3", "tab:green", "-"),
            ("BC, package actor (tenth pass)", "lrc/scores.csv", "BC", "tab:gray", "--"),
            ("d3rlpy TD3+BC", "peers.csv", "d3rlpy-TD3+BC", "black", "--"),
        ],
    ),
    "cd5_hopper_amd": (
        "hopper/medium-v0",
        "(AMD collection) critic_diversity 5 over 100,000 steps",
        (10, 70),
        [
            ("POLA defaults (critic_diversity 1)", "hopper_amd/scores.csv", "T3", "tab:red", "-"),
            ("POLA critic_diversity 5", "hopper_amd/cd5_scores.csv", "T3", "tab:green", "-"),
            ("BC, package actor", "hopper_amd/bc_scores.csv", "BC", "tab:gray", "--"),
        ],
    ),
    "mode_halfcheetah": (
        "halfcheetah/medium-replay-v0",
        "the defaults of 2026-12-06 over 100,000 steps",
        (0, 50),
        [
            ("POLA defaults of 2026-12-06 (mode rule)", "amd_mode/scores.csv", "T3", "tab:red", "-"),
            ("POLA defaults before (lrc)", "lrc/scores.csv", "T3", "tab:orange", ":"),
            ("BC, package actor before", "lrc/scores.csv", "BC", "tab:gray", "--"),
            ("BC, package actor of 2026-12-06", "amd_mode/bc_scores.csv", "BC", "tab:brown", "--"),
            ("d3rlpy TD3+BC", "peers.csv", "d3rlpy-TD3+BC", "black", "--"),
            ("d3rlpy IQL", "peers.csv", "d3rlpy-IQL", "tab:blue", "--"),
            ("d3rlpy BC", "peers.csv", "d3rlpy-BC", "tab:green", "--"),
        ],
    ),
    "mode_hopper_amd": (
        "hopper/medium-v0",
        "(AMD collection) the defaults of 2026-12-06 over 100,000 steps",
        (10, 80),
        [
            ("POLA defaults of 2026-12-06 (mode rule)", "amd_mode/scores.csv", "T3", "tab:red", "-"),
            ("POLA defaults before", "hopper_amd/scores.csv", "T3", "tab:orange", ":"),
            ("BC, package actor before", "hopper_amd/bc_scores.csv", "BC", "tab:gray", "--"),
            ("BC, package actor of 2026-12-06", "amd_mode/bc_scores.csv", "BC", "tab:brown", "--"),
            ("d3rlpy TD3+BC", "amd_mode/peers.csv", "d3rlpy-TD3+BC", "black", "--"),
            ("d3rlpy IQL", "amd_mode/peers.csv", "d3rlpy-IQL", "tab:blue", "--"),
            ("d3rlpy BC", "amd_mode/peers.csv", "d3rlpy-BC", "tab:green", "--"),
        ],
    ),
    "long_halfcheetah": (
        "halfcheetah/medium-replay-v0",
        "the defaults over 100,000 steps against d3rlpy's baselines",
        (0, 50),
        [
            ("POLA, defaults", "amd_mode/scores.csv", "T3", "tab:red", "-"),
            ("BC, package actor", "amd_mode/bc_scores.csv", "BC", "tab:brown", "--"),
            ("d3rlpy TD3+BC (Intel VM)", "peers.csv", "d3rlpy-TD3+BC", "black", "--"),
            ("d3rlpy IQL (Intel VM)", "peers.csv", "d3rlpy-IQL", "tab:blue", "--"),
            ("d3rlpy BC (Intel VM)", "peers.csv", "d3rlpy-BC", "tab:green", "--"),
        ],
    ),
    "long_hopper": (
        "hopper/medium-v0",
        "(AMD collection) the defaults over 100,000 steps against d3rlpy's baselines",
        (10, 80),
        [
            ("POLA, defaults", "amd_mode/scores.csv", "T3", "tab:red", "-"),
            ("BC, package actor", "amd_mode/bc_scores.csv", "BC", "tab:brown", "--"),
            ("d3rlpy TD3+BC", "amd_mode/peers.csv", "d3rlpy-TD3+BC", "black", "--"),
            ("d3rlpy IQL", "amd_mode/peers.csv", "d3rlpy-IQL", "tab:blue", "--"),
            ("d3rlpy BC", "amd_mode/peers.csv", "d3rlpy-BC", "tab:green", "--"),
        ],
    ),
    "dip30k": (
        "hopper/medium-v0",
        "(AMD collection) the first 30,000 steps: the look-ahead and the 20k dip",
        (20, 50),
        [
            ("POLA defaults (T = 3)", "amd_mode/scores.csv", "T3", "tab:red", "-"),
            ("POLA T = 3, lookahead_trust_margin 0", "amd_mode/dip30k.csv", "T3-trust0", "tab:purple", "-"),
            ("POLA T = 3, margin 0, Bellman rule", "amd_mode/dip30k.csv", "T3-trustbellman0", "tab:olive", "-"),
            ("POLA T = 0", "amd_mode/dip30k.csv", "T0", "tab:blue", "-"),
            ("BC, package actor", "amd_mode/bc_scores.csv", "BC", "tab:brown", "--"),
        ],
    ),
}
XMAX = {"dip30k": 30000}  # figures of a shorter budget than their curves' files
OUT = {
    "eta": "lrc/fig_eta_hopper_medium-v0.png",
    "cd5_halfcheetah": "lrc/fig_cd5_halfcheetah_medium-replay-v0.png",
    "cd5_hopper_amd": "hopper_amd/fig_cd5_hopper_medium-v0.png",
    "mode_halfcheetah": "amd_mode/fig_halfcheetah_medium-replay-v0.png",
    "mode_hopper_amd": "amd_mode/fig_hopper_medium-v0.png",
    "dip30k": "amd_mode/fig_dip30k_hopper_medium-v0.png",
    "long_halfcheetah": "amd_mode/fig_long_halfcheetah_medium-replay-v0.png",
    "long_hopper": "amd_mode/fig_long_hopper_medium-v0.png",
}


def run_rows(path: pathlib.Path, dataset: str, variant: str, max_step: float) -> list[dict]:
    """One variant's evaluation rows on one dataset up to ``max_step``; none without the file."""
    rows = read_rows(path) if path.exists() else []
    return [r for r in rows if r["dataset"] == dataset and r["variant"] == variant and r["step"] <= max_step]


def curve(
    path: pathlib.Path, dataset: str, variant: str, max_step: float = float("inf")
) -> tuple[list[int], np.ndarray, np.ndarray, str] | None:
    """Steps, mean and std over seeds, and the number of seeds of one variant's evaluations up to ``max_step`` ("3",
    or "3 to 45000, then 1" while some seeds' runs are still short of the others'); None without a file or rows."""
    by_step: dict[int, list[float]] = defaultdict(list)
    for row in run_rows(path, dataset, variant, max_step):
        by_step[row["step"]].append(row["score"])
    if not by_step:
        return None
    steps = sorted(by_step)
    values = [by_step[s] for s in steps]
    counts = [len(v) for v in values]
    n = str(max(counts))
    if min(counts) != max(counts):
        last = max(s for s, c in zip(steps, counts, strict=True) if c == max(counts))
        n += f" to {last}, then {min(c for s, c in zip(steps, counts, strict=True) if s > last)}"
    return steps, np.array([np.mean(v) for v in values]), np.array([np.std(v) for v in values]), n


def seed_table(figure: str, late: int) -> str:
    """The figure's curves, a row each: per seed the final score and the mean from ``late`` on, then over seeds."""
    dataset, _, _, curves = FIGURES[figure]
    budget = XMAX.get(figure, 100000)
    lines = [
        f"| {dataset}: run | seeds: score at {budget // 1000}k (or at the step reached) | at {budget // 1000}k, mean ± std "
        f"| mean from {late // 1000}k on, per seed |",
        "|---|---|---|---|",
    ]
    for label, name, variant, _, _ in curves:
        by_seed: dict[int, dict[int, float]] = defaultdict(dict)
        path = HERE / name
        for row in run_rows(path, dataset, variant, budget):
            by_seed[row["seed"]][row["step"]] = row["score"]
        if not by_seed:
            continue
        finals, late_means = [], []
        for seed, scores in sorted(by_seed.items()):
            last = max(scores)
            finals.append(f"{seed}: {scores[last]:.1f}" + ("" if last == budget else f" at {last // 1000}k"))
            tail = [v for step, v in scores.items() if step >= late]
            late_means.append(f"{np.mean(tail):.1f}" if tail else "-")
        done = [scores[budget] for scores in by_seed.values() if budget in scores]
        summary = f"{np.mean(done):.1f} ± {np.std(done, ddof=1):.1f} ({len(done)})" if len(done) > 1 else "-"
        lines.append(f"| {label} | {', '.join(finals)} | {summary} | {', '.join(late_means)} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--figure", choices=sorted(FIGURES), default="eta")
    parser.add_argument("--out", help="the PNG to write (default: the figure's file beside its CSVs)")
    parser.add_argument("--table", action="store_true", help="print the seeds' table instead of drawing")
    parser.add_argument("--late", type=int, default=30000, help="--table: the late mean's first step")
    args = parser.parse_args()
    if args.table:
        print(seed_table(args.figure, args.late))
        return
    dataset, title, ylim, curves = FIGURES[args.figure]
    fig, ax = plt.subplots(figsize=(6.5, 4.0), dpi=90)
    for label, name, variant, color, style in curves:
        drawn = curve(HERE / name, dataset, variant, XMAX.get(args.figure, float("inf")))
        if drawn is None:
            print(f"no rows for {label} ({name}): not drawn")
            continue
        steps, mean, std, n = drawn
        ax.plot(steps, mean, style, marker="o", ms=3, color=color, label=f"{label} (n={n})")
        ax.fill_between(steps, mean - std, mean + std, color=color, alpha=0.12)
    ax.set_title(f"{dataset}\n{title}", fontsize=9)
    ax.set_xlabel("gradient steps")
    ax.set_ylabel("D4RL-normalised score")
    ax.set_ylim(*ylim)
    # below the axes: the labels carry the seed counts and would cover the curves
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, frameon=False)
    out = args.out or str(HERE / OUT[args.figure])
    fig.savefig(out, bbox_inches="tight")
    print(out)


if __name__ == "__main__":
    main()
