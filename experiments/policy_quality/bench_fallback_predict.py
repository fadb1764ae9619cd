"""#23: what ``fallback_confidence`` costs a single-observation ``predict`` (two actors' chains and a critic call):
the defaults' deterministic predict, the same with the fallback actor, and SAC's, interleaved in one run.

    python experiments/policy_quality/bench_fallback_predict.py [--calls 1000] [--task hopper]

Prints one JSON object: each predict's median and 99th percentile in seconds, and the ratios to SAC and to the
defaults. Untrained weights (the cost does not depend on them); one torch thread.
"""

from __future__ import annotations

import argparse
import json

import torch as th
from stable_baselines3 import SAC

from sb3_pola.benchmarks.common import TASK_SIZES, make_pola
from sb3_pola.benchmarks.predict_bench import _SpacesEnv, interleaved_latency
from sb3_pola.common.datasets import synthetic_dataset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=1000)
    parser.add_argument("--task", default="hopper", choices=sorted(TASK_SIZES))
    args = parser.parse_args()
    th.set_num_threads(1)
    obs_dim, act_dim, env_id = TASK_SIZES[args.task]
    data = synthetic_dataset(10_000, obs_dim, act_dim, env_id)
    defaults = make_pola(data, device="cpu", policy_kwargs={})
    fallback = make_pola(data, device="cpu", policy_kwargs={"fallback_confidence": 1.0})
    sac = SAC("MlpPolicy", _SpacesEnv(data.observation_space, data.action_space), device="cpu", seed=0)
    obs = data.observations[0]
    names = ("defaults", "fallback", "sac")
    results = interleaved_latency(
        [lambda o, m=m: m.predict(o, deterministic=True) for m in (defaults, fallback, sac)], obs, args.calls
    )
    row = {name: {"median_s": r["median_s"], "p99_s": r["p99_s"]} for name, r in zip(names, results, strict=True)}
    row["fallback_over_defaults"] = results[1]["median_s"] / results[0]["median_s"]
    row["defaults_over_sac"] = results[0]["median_s"] / results[2]["median_s"]
    row["fallback_over_sac"] = results[1]["median_s"] / results[2]["median_s"]
    print(json.dumps({"task": args.task, "calls": args.calls, **row}, indent=2))


if __name__ == "__main__":
    main()
