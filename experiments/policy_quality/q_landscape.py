"""Issue #23's pendulum diagnostic: run a saved POLA model for one episode and, at the states it visits, compare the
actor's action with the critic's greedy action (the top-K pessimistic Q of eq. 4 over a grid of actions).

    python experiments/policy_quality/q_landscape.py --model outputs/main/model.zip \\
        [--dataset invertedpendulum/medium-v0] [--seed 3] [--every 14]

Prints every ``--every``-th state with the actor's action, Q there, the greedy action and Q's range over the actions
(a 61-point grid for a one-dimensional action, else 256 uniform draws), then the episode's length. It tells a critic
that does not know better (the actor at its argmax, the episode still failing) from an actor that does not follow it.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch as th

from sb3_pola import POLA
from sb3_pola.common.datasets import make_env


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True)
    parser.add_argument("--dataset", default="invertedpendulum/medium-v0")
    parser.add_argument("--seed", type=int, default=3, help="the episode's reset seed")
    parser.add_argument("--every", type=int, default=14, help="print every n-th state")
    parser.add_argument("--max-steps", type=int, default=1000)
    args = parser.parse_args()
    th.set_num_threads(1)
    model = POLA.load(args.model, device="cpu")
    env = make_env(args.dataset)
    low, high = (th.as_tensor(b, dtype=th.float32) for b in (env.action_space.low, env.action_space.high))
    gen = th.Generator().manual_seed(0)
    if low.numel() == 1:
        candidates = th.linspace(float(low[0]), float(high[0]), 61).unsqueeze(1)  # [C, 1]
    else:
        candidates = low + (high - low) * th.rand(256, low.numel(), generator=gen)  # [C, A]

    def pessimistic_q(states: th.Tensor, actions: th.Tensor) -> th.Tensor:
        return model.critic(states, actions).topk(model.top_k, dim=0, largest=False).values.mean(dim=0)  # [B]

    obs, _ = env.reset(seed=args.seed)
    length = 0
    for t in range(args.max_steps):
        action, _ = model.predict(obs, deterministic=True)
        if t % args.every == 0:
            with th.no_grad():
                state = th.as_tensor(obs, dtype=th.float32).unsqueeze(0)
                q_actor = float(pessimistic_q(state, th.as_tensor(action, dtype=th.float32).unsqueeze(0))[0])
                q_grid = pessimistic_q(state.expand(len(candidates), -1), candidates)  # [C]
            greedy = candidates[int(q_grid.argmax())].numpy()
            print(
                f"t={t:4d} obs={np.round(obs, 3)} a={np.round(action, 3)} Q(a)={q_actor:.2f} "
                f"greedy={np.round(greedy, 2)} Q range over actions {float(q_grid.min()):.2f}..{float(q_grid.max()):.2f}"
            )
        obs, _, terminated, truncated, _ = env.step(action)
        length = t + 1
        if terminated or truncated:
            break
    print(f"episode length {length}")


if __name__ == "__main__":
    main()
