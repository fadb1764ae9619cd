"""The mode rule's single-observation predict, before and after its fast form, in one interleaved run beside SB3 SAC.

"before": the inference plan calls the ReLU modules and the mean shift runs in action space
(``sb3_pola.pola.actor.kernel_mode``); "after": the package as it is (ReLU as an in-place function,
``sb3_pola.pola.fast_sampling.kernel_mode_fast``). Same weights, hopper sizes (11/3), the package's default actor
(3 x 256). ``python experiments/policy_quality/bench_mode_forms.py [--calls N]``
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
import torch as th
from stable_baselines3 import SAC
from torch import nn

import sb3_pola.pola.fast_sampling as fast_sampling
import sb3_pola.pola.policies as policies
from sb3_pola.benchmarks.common import TASK_SIZES, make_pola
from sb3_pola.benchmarks.predict_bench import _SpacesEnv, interleaved_latency
from sb3_pola.common.datasets import synthetic_dataset
from sb3_pola.pola.actor import kernel_mode


def before_form(model: Any, obs: np.ndarray) -> None:
    """Give ``model`` the earlier form: its cached plan built with the ReLU modules, the readable mean shift."""
    saved = dict(fast_sampling._INFERENCE_ACTIVATIONS)
    fast_sampling._INFERENCE_ACTIVATIONS.pop(nn.ReLU)
    try:
        model.predict(obs, deterministic=True)  # builds and caches the plan
    finally:
        fast_sampling._INFERENCE_ACTIVATIONS.update(saved)
    mode_action = model.policy._mode_action

    def readable(actor: Any, o: th.Tensor) -> th.Tensor:
        fast, policies.kernel_mode_fast = policies.kernel_mode_fast, kernel_mode
        try:
            return mode_action(actor, o)
        finally:
            policies.kernel_mode_fast = fast

    model.policy._mode_action = readable


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--calls", type=int, default=1000)
    args = parser.parse_args()
    th.set_num_threads(1)
    obs_dim, act_dim, env_id = TASK_SIZES["hopper"]
    data = synthetic_dataset(10_000, obs_dim, act_dim, env_id)
    after, before = make_pola(data, device="cpu"), make_pola(data, device="cpu")
    sac = SAC("MlpPolicy", _SpacesEnv(data.observation_space, data.action_space), device="cpu", seed=0)
    obs = data.observations[0]
    before_form(before, obs)
    gap = np.abs(before.predict(obs, deterministic=True)[0] - after.predict(obs, deterministic=True)[0]).max()
    # beside them, the same rule with fewer samples, on the CPU preset's actor, and one chain
    others = {f"{k} samples": make_pola(data, device="cpu", policy_kwargs={"mode_samples": k}) for k in (8, 4)}
    others["16 samples, 2 x 256 actor"] = make_pola(
        data, device="cpu", policy_kwargs={"net_arch": {"pi": [256, 256], "qf": [128, 128]}}
    )
    others["one chain (observation_noise)"] = make_pola(
        data, device="cpu", policy_kwargs={"deterministic_rule": "observation_noise"}
    )
    models = [before, after, *others.values()]
    lat = interleaved_latency(
        [*(lambda o, m=m: m.predict(o, deterministic=True) for m in models), lambda o: sac.predict(o, deterministic=True)],
        obs,
        args.calls,
    )
    b, a, *rest, s = (x["median_s"] * 1e3 for x in lat)
    print(f"largest action difference {gap:.1e}; medians of {args.calls} interleaved calls:")
    print(f"before {b:.3f} ms ({b / s:.2f}x SAC), after {a:.3f} ms ({a / s:.2f}x SAC), SAC {s:.3f} ms")
    print(f"after / before {a / b:.2f}")
    for name, t in zip(others, rest, strict=True):
        print(f"{name}: {t:.3f} ms ({t / s:.2f}x SAC)")


if __name__ == "__main__":
    main()
