"""Evaluate a saved POLA model under several rules of ``predict`` (issue #23's evaluation-rule comparison).

    python experiments/policy_quality/rules.py MODEL.zip DATASET [--rules noisefree,obsnoise,sample,best10] [--episodes 10]

Prints one line per rule: the mean and std of the returns (the score protocol's resets: episode ``i`` of seed ``S``
resets with ``10000 (S + 1) + i``).
"""

from __future__ import annotations

import argparse

import numpy as np

from sb3_pola import POLA
from sb3_pola.common.datasets import make_env
from sb3_pola.common.evaluation import evaluate

# rule -> (n_action_samples, deterministic, deterministic_rule)
RULES = {
    "noisefree": (1, True, "noise_free"),
    "obsnoise": (1, True, "observation_noise"),
    "sample": (1, False, "observation_noise"),
    # the Q-ranked choice: the noise-free chain and 9 seeded samples, the best by the pessimistic critic
    "best10": (10, True, "noise_free"),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model")
    parser.add_argument("dataset")
    parser.add_argument("--rules", default="noisefree,obsnoise,sample")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    model = POLA.load(args.model, device="cpu")
    env = make_env(args.dataset)
    for rule in args.rules.split(","):
        model.policy.n_action_samples, deterministic, model.policy.deterministic_rule = RULES[rule]
        returns = evaluate(model, env, args.episodes, 10_000 * (args.seed + 1), deterministic)
        print(f"{rule} {np.mean(returns):.1f} +/- {np.std(returns):.1f}", flush=True)


if __name__ == "__main__":
    main()
