"""#23: the gradient step at the CPU preset's sizes with 5 critics (the preset) and 10 (the paper, the package default).

``python experiments/critics10/timing.py [--eager]``: both configurations timed by the package's step benchmark
(:func:`sb3_pola.benchmarks.train_bench.run`: one synthetic hopper-sized dataset, the dynamics model frozen, steps
timed in turns so that the ratio is fair on a machine whose load drifts), the package defaults otherwise, the preset's
compiled update unless ``--eager``. Prints the medians and their ratio. One torch thread, as the score grid runs a cell.
"""

from __future__ import annotations

import argparse
import json

import torch as th

from sb3_pola.benchmarks.train_bench import DEFAULTS_FORM, run
from sb3_pola.grid.variants import PRESETS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--eager", action="store_true", help="the eager update instead of the preset's compiled one")
    args = parser.parse_args()
    th.set_num_threads(1)
    preset = PRESETS["cpu"]
    kwargs = {
        **DEFAULTS_FORM,  # the benchmark starts from the paper's form; the package defaults instead
        "batch_size": preset.batch_size,
        "top_k": preset.top_k,
        "dynamics_kwargs": preset.dynamics_kwargs,
        **preset.extra,
    }
    if args.eager:
        kwargs["compile_update"] = False
    configs = [
        {
            "name": f"n_critics={n}",
            "task": "hopper",
            "kwargs": {**kwargs, "n_critics": n},
            "policy_kwargs": {"net_arch": preset.net_arch},
        }
        for n in (5, 10)
    ]
    step = {r["name"]: r["step_s"] for r in run(configs=configs)["configs"]}
    print(
        json.dumps(
            {
                "compiled": not args.eager,
                "median_step_ms": {name: round(1000 * s, 2) for name, s in step.items()},
                "ratio_10_over_5": round(step["n_critics=10"] / step["n_critics=5"], 3),
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
