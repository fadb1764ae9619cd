"""Gradient-step benchmark of POLA: steps/s over configurations, FLOPs, roofline fraction, cost scaling.

``python -m sb3_pola.benchmarks.train_bench [--quick]``. Synthetic in-memory data (no downloads); the
dynamics model is left as initialised and frozen, since its cost per step does not depend on its weights.
"""

from __future__ import annotations

import argparse
import functools
import gc
import inspect
import json
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th

from sb3_pola.benchmarks.common import TASK_SIZES, count_flops, make_pola, matmul_replay, synchronize
from sb3_pola.common.datasets import synthetic_dataset
from sb3_pola.pola.pola import PAPER_FORM, POLA

# the paper's configuration (N=10 critics, T=3 look-ahead steps, 5 diffusion steps, state products, batch 256),
# in the paper's form (the package defaults' similarity term and detached states change the work per step)
PAPER: dict[str, Any] = {
    **PAPER_FORM,
    "n_critics": 10,
    "rollout_length": 3,
    "n_diffusion_steps": 5,
    "use_state_products": True,
    "batch_size": 256,
}


# the package defaults where they depart from the paper's form, at the paper's sizes (the speed target of #23: the
# defaults' step costs at most 1.25x the paper form's)
DEFAULTS_FORM: dict[str, Any] = {key: inspect.signature(POLA).parameters[key].default for key in PAPER_FORM}


def configurations(quick: bool, compiled: bool = False) -> list[dict[str, Any]]:
    """The benchmarked configurations: name, task size, dataset size, POLA arguments, whether to count FLOPs."""
    configs: list[dict[str, Any]] = [
        {"name": "paper hopper", "task": "hopper", "kwargs": {}, "flops": True},
        {"name": "defaults hopper", "task": "hopper", "kwargs": DEFAULTS_FORM},
        # fallback_confidence's second, imitation-only actor: one more L_d step a gradient step
        {
            "name": "defaults hopper, fallback actor",
            "task": "hopper",
            "kwargs": DEFAULTS_FORM,
            "policy_kwargs": {"fallback_confidence": 1.0},
        },
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
    if compiled:  # the paper configurations again with Mish in a kernel fused by torch.compile
        for task in ("hopper",) if quick else ("hopper", "halfcheetah"):
            configs.append(
                {
                    "name": f"paper {task}, compiled Mish",
                    "task": task,
                    "kwargs": {},
                    "flops": True,
                    "policy_kwargs": {"compile_activations": True},
                }
            )
        if not quick:  # the whole update compiled (CUDA graphs on CUDA): minutes of compilation on a small CPU
            configs.append(
                {
                    "name": "paper hopper, compiled update",
                    "task": "hopper",
                    "kwargs": {"compile_update": True},
                    "flops": True,
                    "policy_kwargs": {"compile_activations": True},
                }
            )
            # the speed target of #23, compiled: the defaults' update against the paper form's, both compiled
            configs.append(
                {
                    "name": "defaults hopper, compiled update",
                    "task": "hopper",
                    "kwargs": {**DEFAULTS_FORM, "compile_update": True},
                    "policy_kwargs": {"compile_activations": True},
                }
            )
    return configs


def build(config: dict[str, Any], device: str, datasets: dict[tuple[Any, ...], Any], policy_kwargs: dict[str, Any]) -> Any:
    """The model of ``config`` on a (shared) synthetic dataset, warmed up by two gradient steps."""
    obs_dim, act_dim, env_id = TASK_SIZES[config["task"]]
    n_data = config.get("n_data", 100_000)
    key = (n_data, obs_dim, act_dim, env_id)
    if key not in datasets:
        datasets[key] = synthetic_dataset(n_data, obs_dim, act_dim, env_id)
    kwargs = {**PAPER, **config["kwargs"]}
    model = make_pola(
        datasets[key], device=device, policy_kwargs={**policy_kwargs, **config.get("policy_kwargs", {})}, **kwargs
    )
    start = time.perf_counter()
    model.train(2, kwargs["batch_size"])  # warm-up: allocator, first-call paths, compilation
    synchronize(device)
    config["_meta"] = {
        "name": config["name"],
        "obs_dim": obs_dim,
        "act_dim": act_dim,
        "n_data": n_data,
        **kwargs,
        "policy_kwargs": {**policy_kwargs, **config.get("policy_kwargs", {})},
        "warmup_s": time.perf_counter() - start,
    }
    return model


def run(
    quick: bool = False,
    device: str = "cpu",
    policy_kwargs: dict[str, Any] | None = None,
    compiled: bool = False,
    names: list[str] | None = None,
    configs: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Time every configuration, interleaved, and count FLOPs of the paper configurations.

    All models are built first; then rounds time one step (``chunk`` steps on CUDA) of every model in turn,
    and, for the configurations with a roofline, one replay of the step's matmuls alone. Interleaving
    makes the ratios fair on a machine whose load drifts. Rounds continue until the time budget is
    spent (at least 3 rounds). Medians per configuration. ``configs`` (same form as :func:`configurations`'
    entries) times the caller's configurations instead.
    """
    datasets: dict[tuple[Any, ...], Any] = {}
    configs = [c for c in configs or configurations(quick, compiled) if names is None or c["name"] in names]
    models = [build(config, device, datasets, policy_kwargs or {}) for config in configs]
    chunk = 1 if th.device(device).type == "cpu" else 20
    tasks: list[tuple[str, Any, Callable[[], Any]]] = []
    flops: dict[str, int] = {}
    matmul_flops: dict[str, int] = {}
    for config, model in zip(configs, models, strict=True):
        batch_size = config["_meta"]["batch_size"]
        tasks.append(("step", config, functools.partial(model.train, chunk, batch_size)))
        if config.get("flops"):
            # FLOPs are counted eagerly (a dispatch mode cannot look inside a compiled graph): same math, same matmuls
            counted = model
            if config["kwargs"].get("compile_update"):
                counted = build({**config, "kwargs": {**config["kwargs"], "compile_update": False}}, device, datasets, {})
            flops[config["name"]], calls = count_flops(functools.partial(counted.train, 1, batch_size))
            del counted
            replay, matmul_flops[config["name"]] = matmul_replay(calls, device)
            tasks.append(("matmuls", config, replay))
    times: dict[tuple[str, str], list[float]] = {(kind, c["name"]): [] for kind, c, _ in tasks}
    budget, max_rounds = (35.0, 10) if quick else (180.0, 60)
    start = time.perf_counter()
    for round_ in range(max_rounds):
        if round_ >= 3 and time.perf_counter() - start > budget:
            break
        for kind, config, fn in tasks:
            t0 = time.perf_counter()
            fn()
            synchronize(device)
            times[(kind, config["name"])].append((time.perf_counter() - t0) / (chunk if kind == "step" else 1))
    results = []
    for config in configs:
        result = dict(config["_meta"])
        step = float(np.median(times[("step", config["name"])]))
        result.update(step_s=step, steps_per_s=1.0 / step, reps=len(times[("step", config["name"])]) * chunk)
        if config["name"] in flops:
            matmul_s = float(np.median(times[("matmuls", config["name"])]))
            n_flops = flops[config["name"]]
            result.update(
                flops=n_flops,
                achieved_flops_per_s=n_flops / step,
                matmul_flops_per_s=matmul_flops[config["name"]] / matmul_s,
                matmul_seconds=matmul_s,
                roofline_fraction=(n_flops / step) / (matmul_flops[config["name"]] / matmul_s),
            )
        results.append(result)
    del models
    gc.collect()
    scaling = scaling_checks(results)
    if th.device(device).type == "cuda":
        scaling["gpu_paper_steps_per_s"] = gpu_check(results)
    return {"configs": results, "scaling": scaling, "rounds": len(times[("step", configs[0]["name"])])}


def gpu_check(results: list[dict[str, Any]]) -> dict[str, Any]:
    """The GPU target: the paper configuration (Hopper size) at >= 500 gradient steps/s, eager or compiled."""
    paper = {r["name"]: r["steps_per_s"] for r in results if r["name"].startswith("paper hopper") and "1M" not in r["name"]}
    best = max(paper, key=paper.__getitem__)
    return {"best": best, "steps_per_s": paper[best], "all": paper, "target": ">= 500 steps/s", "met": paper[best] >= 500}


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
    for suffix, key in (("", "defaults_over_paper_form"), (", compiled update", "defaults_over_paper_form_compiled")):
        if f"defaults hopper{suffix}" in by_name and f"paper hopper{suffix}" in by_name:
            ratio = by_name[f"defaults hopper{suffix}"]["step_s"] / by_name[f"paper hopper{suffix}"]["step_s"]
            checks[key] = {"ratio": ratio, "target": "<= 1.25", "met": ratio <= 1.25}
    return checks


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--only", nargs="+", help="the configurations to time (names as printed)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument(
        "--compiled", action="store_true", help="also the compiled configurations (minutes of compilation on a CPU)"
    )
    args = parser.parse_args(argv)
    print(json.dumps(run(args.quick, args.device, compiled=args.compiled, names=args.only), indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
