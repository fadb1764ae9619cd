"""Issue #23's temperature check: evaluate saved models with the observation-noise rule's chain noise scaled by tau.

    python experiments/policy_quality/temperature.py --dataset pointmaze/umaze-v0 \\
        --models OUT/pointmaze_umaze-v0/BCHGC/seed0.zip ... --taus 1 0.5 0.25 0

``predict(deterministic=True)`` draws the chain's noise as a fixed function of the observation
(``deterministic_rule="observation_noise"``); here that noise is multiplied by ``tau`` (1: the package's rule, 0: the
noise-free chain), a sampling temperature. 10 episodes per model and tau with the score protocol's resets for the seed
in the file name (``seed<S>.zip``: reset seed ``10000 (S + 1)``). One JSON line per model and tau on stdout.
"""

from __future__ import annotations

import argparse
import json
import re
from typing import Any

import numpy as np
import torch as th

import sb3_pola.pola.policies as policies
from sb3_pola import POLA
from sb3_pola.common.datasets import load_offline_dataset, make_env
from sb3_pola.common.evaluation import evaluate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--models", nargs="+", required=True)
    parser.add_argument("--taus", nargs="+", type=float, default=[1.0, 0.5, 0.25, 0.0])
    parser.add_argument("--episodes", type=int, default=10)
    args = parser.parse_args()
    th.set_num_threads(1)
    scale = [1.0]
    noise_from_projection = policies.noise_from_projection

    def scaled(*fargs: Any, **fkwargs: Any) -> th.Tensor:
        return noise_from_projection(*fargs, **fkwargs) * scale[0]

    policies.noise_from_projection = scaled  # predict's only source of chain noise under this rule
    data = load_offline_dataset(args.dataset)
    env = make_env(data)
    for path in args.models:
        match = re.search(r"seed(\d+)\.zip$", path)
        assert match, f"{path}: the seed is read from the file name seed<S>.zip"
        seed = int(match.group(1))
        model = POLA.load(path, device="cpu")
        model.policy.n_action_samples, model.policy.deterministic_rule = 1, "observation_noise"
        for tau in args.taus:
            scale[0] = tau
            successes: list[bool | None] = []
            returns = evaluate(model, env, args.episodes, 10_000 * (seed + 1), True, successes)
            score = data.normalized_score(returns)
            row: dict[str, Any] = {"dataset": args.dataset, "model": path, "seed": seed, "tau": tau}
            row["score"] = round(float(score if score is not None else returns.mean()), 1)
            if successes and successes[0] is not None:
                row["success"] = round(float(np.mean([bool(s) for s in successes])), 2)
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
