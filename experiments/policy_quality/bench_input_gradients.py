"""#23: the defaults' training step with EDAC's input gradients written out against autograd's double backward, next to
the paper form's step (paper sizes, Hopper-sized synthetic data, eager, one thread, interleaved rounds, medians).

    python experiments/policy_quality/bench_input_gradients.py [--rounds 12]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch as th

from sb3_pola.benchmarks.common import make_pola
from sb3_pola.benchmarks.train_bench import DEFAULTS_FORM, PAPER
from sb3_pola.common.datasets import synthetic_dataset
from sb3_pola.common.input_gradients import autograd_input_gradients


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=12)
    args = parser.parse_args()
    th.set_num_threads(1)
    data = synthetic_dataset(100_000, 11, 3, "Hopper-v5")
    models = {
        "paper": make_pola(data, **PAPER),
        "defaults (written-out input gradients)": make_pola(data, **{**PAPER, **DEFAULTS_FORM}),
        "defaults (autograd double backward)": make_pola(data, **{**PAPER, **DEFAULTS_FORM}),
    }
    models["defaults (autograd double backward)"]._input_gradients = autograd_input_gradients
    for model in models.values():
        model.train(2, 256)  # warm-up
    times: dict[str, list[float]] = {name: [] for name in models}
    for _ in range(args.rounds):
        for name, model in models.items():
            start = time.perf_counter()
            model.train(1, 256)
            times[name].append(time.perf_counter() - start)
    paper = statistics.median(times["paper"])
    for name in models:
        step = statistics.median(times[name])
        print(f"{name}: {1000 * step:.1f} ms, {step / paper:.3f} x paper")


if __name__ == "__main__":
    main()
