"""Predict benchmark: single-observation latency of POLA next to SB3 SAC, batched throughput and its roofline.

``python -m sb3_pola.benchmarks.predict_bench [--quick]``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th

from sb3_pola.benchmarks.common import TASK_SIZES, count_flops, make_pola, matmul_replay, synchronize
from sb3_pola.common.datasets import synthetic_dataset


class _SpacesEnv(gym.Env):
    """An env that only carries spaces (SAC needs one to be built)."""

    def __init__(self, observation_space: gym.spaces.Box, action_space: gym.spaces.Box) -> None:
        self.observation_space = observation_space
        self.action_space = action_space

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        return self.observation_space.sample(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        return self.observation_space.sample(), 0.0, False, False, {}


def latency(predict: Any, obs: np.ndarray, n_calls: int) -> dict[str, float]:
    """Median and p99 latency of ``predict(obs)`` over ``n_calls`` calls (after 20 warm-up calls), in seconds."""
    for _ in range(20):
        predict(obs)
    times = np.empty(n_calls)
    for i in range(n_calls):
        start = time.perf_counter()
        predict(obs)
        times[i] = time.perf_counter() - start
    return {"median_s": float(np.median(times)), "p99_s": float(np.quantile(times, 0.99))}


def interleaved_latency(predicts: list[Any], obs: np.ndarray, n_calls: int) -> list[dict[str, float]]:
    """:func:`latency` of several predict functions, their calls alternating (fair under a drifting load)."""
    for _ in range(20):
        for predict in predicts:
            predict(obs)
    times = np.empty((len(predicts), n_calls))
    for i in range(n_calls):
        for j, predict in enumerate(predicts):
            start = time.perf_counter()
            predict(obs)
            times[j, i] = time.perf_counter() - start
    return [{"median_s": float(np.median(t)), "p99_s": float(np.quantile(t, 0.99))} for t in times]


def run(
    quick: bool = False,
    device: str = "cpu",
    task: str = "hopper",
    batch: int = 1024,
    policy_kwargs: dict[str, Any] | None = None,
    compiled: bool = False,
) -> dict[str, Any]:
    """Single-observation latency (POLA vs SAC, same observation space, same run) and batched predict throughput."""
    from stable_baselines3 import SAC

    obs_dim, act_dim, env_id = TASK_SIZES[task]
    data = synthetic_dataset(10_000, obs_dim, act_dim, env_id)
    model = make_pola(data, device=device, policy_kwargs=policy_kwargs or {})
    sac = SAC("MlpPolicy", _SpacesEnv(data.observation_space, data.action_space), device=device, seed=0)
    obs = data.observations[0]
    n_calls = 300 if quick else 1000
    # the policy's own deterministic rule (the mode of 16 chains by default) and, beside it, one chain with the
    # observation's noise (the rule before #23's twenty-ninth pass), in the same interleaved run
    one_sample_kwargs = {**(policy_kwargs or {}), "deterministic_rule": "observation_noise"}
    one_sample = make_pola(data, device=device, policy_kwargs=one_sample_kwargs)
    pola_lat, one_lat, sac_lat = interleaved_latency(
        [
            lambda o: model.predict(o, deterministic=True),
            lambda o: one_sample.predict(o, deterministic=True),
            lambda o: sac.predict(o, deterministic=True),
        ],
        obs,
        n_calls,
    )
    ratio = pola_lat["median_s"] / sac_lat["median_s"]

    # batched: the policy's forward on a device tensor (no numpy round trip), as an evaluation over many envs would;
    # timed interleaved with a replay of its matmuls alone (the roofline's denominator), eager and compiled Mish
    obs_batch = th.as_tensor(data.observations[:batch], device=device)
    variants = {"eager": model}
    if compiled:
        variants["compiled Mish"] = make_pola(
            data, device=device, policy_kwargs={**(policy_kwargs or {}), "compile_activations": True}
        )
    fns: dict[str, Callable[[], Any]] = {}
    for name, variant in variants.items():

        def batched(policy: Any = variant.policy) -> th.Tensor:
            with th.no_grad():
                return policy._predict(obs_batch, deterministic=True)

        batched()
        fns[name] = batched
    flops, calls = count_flops(fns["eager"])
    replay, matmul_flops = matmul_replay(calls, device)
    fns["matmuls"] = replay
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(5 if quick else 20):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn()
            synchronize(device)
            times[name].append(time.perf_counter() - start)
    matmul_fps = matmul_flops / float(np.median(times["matmuls"]))
    batched_results = {}
    for name in variants:
        seconds = float(np.median(times[name]))
        batched_results[name] = {
            "batch": batch,
            "seconds": seconds,
            "obs_per_s": batch / seconds,
            "flops": flops,
            "achieved_flops_per_s": flops / seconds,
            "matmul_flops_per_s": matmul_fps,
            "roofline_fraction": flops / seconds / matmul_fps,
        }
    return {
        "task": task,
        "obs_dim": obs_dim,
        "single": {
            "pola_median_s": pola_lat["median_s"],
            "pola_p99_s": pola_lat["p99_s"],
            "rule": model.policy.deterministic_rule,
            "one_sample_median_s": one_lat["median_s"],
            "one_sample_p99_s": one_lat["p99_s"],
            "sac_median_s": sac_lat["median_s"],
            "sac_p99_s": sac_lat["p99_s"],
            "n_calls": n_calls,
            "ratio": ratio,
            "target": "<= 2x SAC",
            "met": ratio <= 2.0,
        },
        "batched": batched_results,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)
    print(json.dumps(run(args.quick, args.device), indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
