"""Issue #23's maze diagnostic: does a policy stay at the goal once it reaches it?

    python experiments/policy_quality/goal_stay.py MODEL.zip [MODEL.zip ...] [--dataset pointmaze/umaze-v0] \
        [--episodes 4] [--reset-seed 100]

For each saved model, runs ``--episodes`` episodes (reset seeds 100, 101, ...; the score protocol's for seed S:
``--reset-seed 10000*(S+1)``) with ``predict(deterministic=True)``
and prints per episode the step the goal is first reached, the return (the rewarded steps: the maze pays 1 per
step at the goal) and how often the policy left the goal after being there. The mazes' datasets never show a policy
staying at a goal: their collectors draw a new goal the step the old one is reached
(``OfflineDataset.goal_switches``).
"""

from __future__ import annotations

import argparse

import torch as th

from sb3_pola import POLA
from sb3_pola.common.datasets import make_env


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+")
    parser.add_argument("--dataset", default="pointmaze/umaze-v0")
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--reset-seed", type=int, default=100)
    args = parser.parse_args()
    th.set_num_threads(1)
    for path in args.models:
        model = POLA.load(path, device="cpu")
        env = make_env(args.dataset)
        rows = []
        for episode in range(args.episodes):
            obs, _ = env.reset(seed=args.reset_seed + episode)
            first, total, leaves, previous, step = None, 0.0, 0, 0.0, 0
            while True:
                action, _ = model.predict(obs, deterministic=True)
                obs, reward, terminated, truncated, _ = env.step(action)
                step += 1
                if reward > 0 and first is None:
                    first = step
                total += float(reward)
                leaves += int(previous > 0 and reward == 0)
                previous = float(reward)
                if terminated or truncated:
                    break
            rows.append(f"reached at {first}, return {total:.0f} of {step}, left the goal {leaves}x")
        print(path, "; ".join(rows))


if __name__ == "__main__":
    main()
