"""Gradient-step benchmark of POLA: steps/s over configurations, FLOPs, roofline fraction, cost scaling.

``python -m sb3_pola.benchmarks.train_bench [--quick]``. Synthetic in-memory data (no downloads); the
dynamics model is left as initialised and frozen, since its cost per step does not depend on its weights.
"""

from __future__ import annotations

import argparse
import gc
import json
import time
from typing import Any

import numpy as np
import torch as th

from sb3_pola.benchmarks.common import TASK_SIZES, count_flops, make_pola, matmul_roofline, synchronize, synthetic_dataset

# the paper's configuration (N=10 critics, T=3 look-ahead steps, 5 diffusion steps, state products, batch 256)
PAPER: dict[str, Any] = {
    "n_critics": 10,
    "rollout_length": 3,
    "n_diffusion_steps": 5,
    "use_state_products": True,
    "batch_size": 256,
}


def configurations(quick: bool) -> list[dict[str, Any]]:
    """The benchmarked configurations: name, task size, dataset size, POLA arguments, whether to count FLOPs."""
    configs: list[dict[str, Any]] = [
        {"name": "paper hopper", "task": "hopper", "kwargs": {}, "flops": True},
        {"name": "paper halfcheetah", "task": "halfcheetah", "kwargs": {}, "flops": not quick},
        {"name": "T=0", "task": "hopper", "kwargs": {"rollout_length": 0}},
        {"name": "T=1", "task": "hopper", "kwargs": {"rollout_length": 1}},
        {"name": "T=5", "task": "hopper", "kwargs": {"rollout_length": 5}},
        {"name": "N=2", "task": "hopper", "kwargs": {"n_critics": 2}},
        {"name": "N=50", "task": "hopper", "kwargs": {"n_critics": 50}},
        {"name": "batch 1024", "task": "hopper", "kwargs": {"batch_size": 1024}},
        {
            "name": "diffusion-ql size",
            "task": "hopper",
            "kwargs": {"n_critics": 2, "rollout_length": 0, "use_state_products": False},
        },
        {"name": "paper hopper, 1M data", "task": "hopper", "kwargs": {}, "n_data": 1_000_000},
    ]
    if quick:
        configs = [c for c in configs if c["name"] not in ("paper halfcheetah", "N=50", "batch 1024")]
    return configs


def time_steps(model: Any, batch_size: int, device: str, budget_s: float, max_reps: int, chunk: int) -> dict[str, float]:
    """Median time of one gradient step (``model.train``), in chunks of ``chunk`` steps, within a time budget."""
    model.train(2, batch_size)  # warm-up (allocator, first-call paths)
    synchronize(device)
    times: list[float] = []
    start = time.perf_counter()
    while len(times) < max_reps and (len(times) < 3 or time.perf_counter() - start < budget_s):
        t0 = time.perf_counter()
        model.train(chunk, batch_size)
        synchronize(device)
        times.append((time.perf_counter() - t0) / chunk)
    step = float(np.median(times))
    return {"step_s": step, "steps_per_s": 1.0 / step, "reps": len(times) * chunk}


def bench_config(
    config: dict[str, Any],
    device: str,
    quick: bool,
    datasets: dict[tuple[Any, ...], Any],
    policy_kwargs: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Build the model of ``config`` and time its gradient step (and count its FLOPs when asked)."""
    obs_dim, act_dim, env_id = TASK_SIZES[config["task"]]
    n_data = config.get("n_data", 100_000)
    key = (n_data, obs_dim, act_dim, env_id)
    if key not in datasets:
        datasets[key] = synthetic_dataset(n_data, obs_dim, act_dim, env_id)
    kwargs = {**PAPER, **config["kwargs"]}
    model = make_pola(datasets[key], device=device, policy_kwargs=policy_kwargs or {}, **kwargs)
    batch_size = kwargs["batch_size"]
    chunk = 1 if th.device(device).type == "cpu" else 20
    result: dict[str, Any] = {
        "name": config["name"],
        "obs_dim": obs_dim,
        "act_dim": act_dim,
        "n_data": n_data,
        **{k: v for k, v in kwargs.items()},
        **time_steps(model, batch_size, device, budget_s=4.0 if quick else 12.0, max_reps=8 if quick else 30, chunk=chunk),
    }
    if config.get("flops"):
        flops, calls = count_flops(lambda: model.train(1, batch_size))
        roof = matmul_roofline(calls, device, reps=3 if quick else 5)
        achieved = flops / result["step_s"]
        result.update(
            flops=flops,
            achieved_flops_per_s=achieved,
            matmul_flops_per_s=roof["flops_per_s"],
            matmul_seconds=roof["seconds"],
            roofline_fraction=achieved / roof["flops_per_s"],
        )
    gc.collect()
    return result


def scaling_checks(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Cost growth: step time linear in T, N=10 vs N=2, independence of the dataset size."""
    by_name = {r["name"]: r for r in results}
    checks: dict[str, Any] = {}
    t_points = [
        (r["rollout_length"], r["step_s"]) for name in ("T=0", "T=1", "paper hopper", "T=5") if (r := by_name.get(name))
    ]
    if len(t_points) >= 3:
        t, s = np.array(t_points, dtype=float).T
        slope, intercept = np.polyfit(t, s, 1)
        residual = float(np.max(np.abs(s - (slope * t + intercept)) / s))
        checks["linear_in_T"] = {
            "points": t_points,
            "slope_s_per_T": float(slope),
            "intercept_s": float(intercept),
            "max_rel_residual": residual,
            "target": "max relative residual of a linear fit <= 0.1",
            "met": residual <= 0.1,
        }
    if "N=2" in by_name and "paper hopper" in by_name:
        ratio = by_name["paper hopper"]["step_s"] / by_name["N=2"]["step_s"]
        checks["n10_over_n2"] = {"ratio": ratio, "target": "< 3", "met": ratio < 3.0}
    if "paper hopper, 1M data" in by_name and "paper hopper" in by_name:
        ratio = by_name["paper hopper, 1M data"]["step_s"] / by_name["paper hopper"]["step_s"]
        checks["dataset_1m_over_100k"] = {"ratio": ratio, "target": "0.85 .. 1.15", "met": 0.85 <= ratio <= 1.15}
    return checks


def run(quick: bool = False, device: str = "cpu", policy_kwargs: dict[str, Any] | None = None) -> dict[str, Any]:
    """Time every configuration; returns ``configs`` (one dict each) and ``scaling`` (the growth checks)."""
    datasets: dict[tuple[Any, ...], Any] = {}
    results = [bench_config(config, device, quick, datasets, policy_kwargs) for config in configurations(quick)]
    return {"configs": results, "scaling": scaling_checks(results)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)
    print(json.dumps(run(args.quick, args.device), indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
