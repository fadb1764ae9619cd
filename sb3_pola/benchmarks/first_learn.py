"""A user's first and second ``learn`` (issue #25): the README's examples run twice as scripts, each in a fresh
Python process with an empty cache before the first, so the second loads the dynamics fit from the cache.

    python -m sb3_pola.benchmarks.first_learn [--steps 300] [--config light defaults]

Prints one JSON line per run: the process's wall time (Python start, imports, dataset, fit or cache hit, training),
the fit's time and the training's steps/s. One torch thread (as a user's laptop core).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

# the README's examples: the API's defaults, and the CPU example (the main job's sizes)
SCRIPT = """
import json, time
import torch as th
th.set_num_threads(1)
from sb3_pola import POLA
from sb3_pola.cli.run import LIGHT_CONFIG
config = {{"light": LIGHT_CONFIG, "defaults": {{}}}}[{config!r}]
start = time.perf_counter()
model = POLA("MlpPolicy", dataset={dataset!r}, seed=0, **config)
model.learn({steps})
learn = time.perf_counter() - start
fit = float(model.dynamics_fit_info.get("fit_time", 0.0))
print(json.dumps({{"learn_s": round(learn, 2), "fit_s": round(fit, 3), "steps_per_s": round({steps} / (learn - fit), 2)}}))
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--dataset", default="invertedpendulum/medium-v0")
    parser.add_argument("--config", nargs="+", default=["light", "defaults"], choices=["light", "defaults"])
    args = parser.parse_args(argv)
    for config in args.config:
        with tempfile.TemporaryDirectory() as cache:
            env = {**os.environ, "SB3_POLA_CACHE_DIR": cache, "OMP_NUM_THREADS": "1"}
            code = SCRIPT.format(config=config, dataset=args.dataset, steps=args.steps)
            for run in ("first", "second"):
                start = time.perf_counter()
                out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
                wall = time.perf_counter() - start
                row = {"config": config, "run": run, "steps": args.steps, "wall_s": round(wall, 1)}
                print(json.dumps({**row, **json.loads(out.stdout.strip().splitlines()[-1])}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
