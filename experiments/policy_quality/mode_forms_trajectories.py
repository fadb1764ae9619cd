"""How two float forms of the mode rule part ways along episodes (thirtieth pass).

For a saved model, each of ``--episodes`` episodes (the score protocol's resets) is played twice: once with the
readable ``kernel_mode`` and once with ``kernel_mode_fast``, each driving its own episode. Printed per episode: both
returns and lengths, the largest action difference while the two are fed the same states (the readable episode's,
both forms evaluated at each of its states), and the first step at which the two closed-loop episodes' actions
differ by more than 1e-3.

``python experiments/policy_quality/mode_forms_trajectories.py --dataset D --model <run>/seed0.zip --seed 0``
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
import torch as th

import sb3_pola.pola.policies as policies
from sb3_pola import POLA
from sb3_pola.common.datasets import load_offline_dataset, make_env
from sb3_pola.pola.actor import kernel_mode
from sb3_pola.pola.fast_sampling import kernel_mode_fast


def play(model: Any, env: Any, form: Any, reset_seed: int, other: Any = None) -> tuple[float, np.ndarray, float]:
    """One episode under ``form``: its return, its actions and (with ``other``) the largest difference of ``other``'s
    action at the same states."""
    obs, _ = env.reset(seed=reset_seed)
    ret, actions, gap = 0.0, [], 0.0
    for _ in range(10_000):
        policies.kernel_mode_fast = form
        action = model.predict(obs, deterministic=True)[0]
        if other is not None:
            policies.kernel_mode_fast = other
            gap = max(gap, float(np.abs(model.predict(obs, deterministic=True)[0] - action).max()))
        actions.append(action)
        obs, reward, terminated, truncated, _ = env.step(action)
        ret += float(reward)
        if terminated or truncated:
            break
    policies.kernel_mode_fast = kernel_mode_fast
    return ret, np.array(actions), gap


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--model", required=True)
    parser.add_argument("--seed", type=int, default=0, help="the run's seed (the protocol resets at 10,000 (seed + 1) + i)")
    parser.add_argument("--episodes", type=int, default=10)
    args = parser.parse_args()
    th.set_num_threads(1)
    model = POLA.load(args.model)
    data = load_offline_dataset(args.dataset)
    env = make_env(data)
    totals = np.zeros(2)
    for episode in range(args.episodes):
        reset_seed = 10_000 * (args.seed + 1) + episode
        r1, a1, gap = play(model, env, kernel_mode, reset_seed, other=kernel_mode_fast)
        r2, a2, _ = play(model, env, kernel_mode_fast, reset_seed)
        n = min(len(a1), len(a2))
        apart = np.abs(a1[:n] - a2[:n]).max(axis=1) > 1e-3
        first = int(np.argmax(apart)) if apart.any() else -1
        print(
            f"episode {episode}: readable {r1:.1f} ({len(a1)} steps), fast {r2:.1f} ({len(a2)} steps); "
            f"same states: largest difference {gap:.1e}; closed loop: first step apart by > 1e-3: {first}"
        )
        totals += (r1, r2)
    scores = [data.normalized_score(np.array([t / args.episodes])) for t in totals]
    print(f"mean return: readable {totals[0] / args.episodes:.1f}, fast {totals[1] / args.episodes:.1f}; scores {scores}")


if __name__ == "__main__":
    main()
