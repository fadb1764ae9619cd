"""#23: the gradient step at the CPU preset's sizes with 5 critics (the preset) and 10 (the paper, the package default).

``python experiments/critics10/timing.py [--rounds 200] [--eager]``: both models built on one synthetic
hopper-sized dataset (11 state, 3 action dimensions), the package defaults otherwise, the preset's compiled update
unless ``--eager``; their steps are timed in turns (interleaved, so that the ratio is fair on a machine whose load
drifts) and the medians printed with their ratio. One torch thread, as the score grid runs a cell.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch as th

from sb3_pola.benchmarks.common import TASK_SIZES, make_pola
from sb3_pola.common.datasets import synthetic_dataset
from sb3_pola.grid.variants import PRESETS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rounds", type=int, default=200, help="timed steps per model")
    parser.add_argument("--eager", action="store_true", help="the eager update instead of the preset's compiled one")
    args = parser.parse_args()
    th.set_num_threads(1)
    preset = PRESETS["cpu"]
    obs_dim, act_dim, env_id = TASK_SIZES["hopper"]
    data = synthetic_dataset(100_000, obs_dim, act_dim, env_id)
    kwargs = {
        "batch_size": preset.batch_size,
        "top_k": preset.top_k,
        "policy_kwargs": {"net_arch": preset.net_arch},
        "dynamics_kwargs": preset.dynamics_kwargs,
        **preset.extra,
    }
    if args.eager:
        kwargs["compile_update"] = False
    models = {n: make_pola(data, n_critics=n, **kwargs) for n in (5, 10)}
    for model in models.values():  # warm-up: compilation, allocator, first-call paths
        model.train(20, preset.batch_size)
    times: dict[int, list[float]] = {n: [] for n in models}
    for _ in range(args.rounds):
        for n, model in models.items():
            start = time.perf_counter()
            model.train(1, preset.batch_size)
            times[n].append(time.perf_counter() - start)
    medians = {n: float(np.median(t)) for n, t in times.items()}
    print(
        json.dumps(
            {
                "compiled": not args.eager,
                "rounds": args.rounds,
                "median_step_ms": {f"n_critics={n}": round(1000 * s, 2) for n, s in medians.items()},
                "ratio_10_over_5": round(medians[10] / medians[5], 3),
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
