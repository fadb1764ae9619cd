"""Dynamics-ensemble benchmark: fit time and accuracy on synthetic HalfCheetah-sized data, and step() cost.

``python -m sb3_pola.benchmarks.dynamics_bench [--quick]`` prints the figures. The data come from a fixed
random nonlinear system (obs 17, action 6), so the numbers measure the training machinery, not a task.
Full mode fits the default configuration (7 members, 5 elites, 4 x 200 SiLU, batch 256) on 100k and 1M
transitions for a capped number of epochs (an epoch is at most 1000 gradient steps) and reports the time
per gradient step, so that a fit to convergence can be extrapolated.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from typing import Any

import torch as th

from sb3_pola.common.dynamics import EnsembleDynamics
from sb3_pola.common.dynamics_trainer import DynamicsTrainer

OBS_DIM, ACT_DIM = 17, 6


def synthetic_transitions(n: int, seed: int = 0) -> dict[str, th.Tensor]:
    """``n`` transitions of a fixed random nonlinear system with HalfCheetah's sizes.

    :param n: number of transitions
    :param seed: seed of the samples (the system itself is fixed)
    :return: ``obs [n, 17]``, ``act [n, 6]``, ``next_obs [n, 17]``, ``rew [n]``
    """
    system = th.Generator().manual_seed(0)
    a_mat = th.randn(OBS_DIM, OBS_DIM, generator=system) * 0.3
    b_mat = th.randn(ACT_DIM, OBS_DIM, generator=system) * 0.5
    gen = th.Generator().manual_seed(seed)
    obs = th.randn(n, OBS_DIM, generator=gen)
    act = th.rand(n, ACT_DIM, generator=gen) * 2 - 1
    delta = 0.5 * th.tanh(obs @ a_mat + act @ b_mat) + 0.1 * th.sin(3 * obs)  # [n, 17]
    next_obs = obs + delta + 0.01 * th.randn(n, OBS_DIM, generator=gen)
    rew = obs[:, 8] - 0.1 * (act**2).sum(-1) + 0.01 * th.randn(n, generator=gen)
    return {"obs": obs, "act": act, "next_obs": next_obs, "rew": rew}


def bench_fit(n: int, max_epochs: int, seed: int = 0) -> dict[str, float]:
    """Fit the default ensemble on ``n`` synthetic transitions for at most ``max_epochs`` epochs.

    :param n: number of transitions
    :param max_epochs: epoch cap (an epoch is at most 1000 gradient steps)
    :param seed: torch seed
    :return: the fit's metrics plus ``ms_per_step`` and ``n``
    """
    data = synthetic_transitions(n, seed)
    th.manual_seed(seed)
    model = EnsembleDynamics(OBS_DIM, ACT_DIM)
    metrics = DynamicsTrainer(model, max_epochs=max_epochs).fit(data["obs"], data["act"], data["next_obs"], data["rew"])
    metrics["ms_per_step"] = 1000 * metrics["fit_time"] / max(metrics["steps"], 1)
    metrics["n"] = float(n)
    return metrics


def bench_step(batch_size: int = 256, repeats: int = 50) -> dict[str, float]:
    """Cost of one differentiable :meth:`EnsembleDynamics.step` (forward + backward to the inputs), frozen model.

    :param batch_size: batch size
    :param repeats: timed repetitions
    :return: ``step_ms`` for each of ``deterministic`` / ``stochastic``
    """
    th.manual_seed(0)
    model = EnsembleDynamics(OBS_DIM, ACT_DIM).freeze()
    obs = th.randn(batch_size, OBS_DIM, requires_grad=True)
    act = th.randn(batch_size, ACT_DIM, requires_grad=True)
    out: dict[str, float] = {}
    for deterministic in (True, False):
        for i in range(repeats + 5):
            if i == 5:
                start = time.perf_counter()
            next_obs, reward, _, _ = model.step(obs, act, deterministic=deterministic)
            (next_obs.sum() + reward.sum()).backward()
        key = "deterministic" if deterministic else "stochastic"
        out[f"step_{key}_ms"] = 1000 * (time.perf_counter() - start) / repeats
    return out


def run(quick: bool = False, max_epochs: int | None = None) -> dict[str, Any]:
    """Run the benchmark.

    :param quick: 10k transitions, 2 epochs, instead of 100k (5 epochs) and 1M (3 epochs)
    :param max_epochs: override the epoch cap of every size
    :return: ``{"fit": [per-size metrics], "step": step costs, "threads": torch threads,
        "load_before" / "load_after": 1-minute load average (other processes distort the timings)}``
    """
    sizes = [(10_000, 2)] if quick else [(100_000, 5), (1_000_000, 3)]
    if max_epochs is not None:
        sizes = [(n, max_epochs) for n, _ in sizes]
    result: dict[str, Any] = {"threads": th.get_num_threads(), "load_before": os.getloadavg()[0]}
    result["fit"] = [bench_fit(n, max_epochs) for n, max_epochs in sizes]
    result["step"] = bench_step(repeats=10 if quick else 50)
    result["load_after"] = os.getloadavg()[0]
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes")
    parser.add_argument("--max-epochs", type=int, default=None, help="epoch cap for every size")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--json", type=str, default=None, help="also write the figures to this file")
    args = parser.parse_args()
    if args.threads is not None:
        th.set_num_threads(args.threads)
    result = run(quick=args.quick, max_epochs=args.max_epochs)
    print(f"torch threads {result['threads']}, load {result['load_before']:.1f} -> {result['load_after']:.1f}")
    for m in result["fit"]:
        print(
            f"fit n={int(m['n']):>9,}: {int(m['epochs'])} epochs, {int(m['steps'])} steps, {m['fit_time']:.1f} s "
            f"({m['ms_per_step']:.1f} ms/step); holdout next-state mse {m['holdout_mse']:.5f} "
            f"vs no-change {m['no_change_mse']:.5f} (ratio {m['holdout_mse'] / m['no_change_mse']:.4f}), "
            f"reward mse {m['holdout_reward_mse']:.5f}"
        )
    step = result["step"]
    print(
        f"step (B=256, fwd+bwd to inputs): deterministic {step['step_deterministic_ms']:.2f} ms, "
        f"stochastic {step['step_stochastic_ms']:.2f} ms"
    )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)


if __name__ == "__main__":
    main()
