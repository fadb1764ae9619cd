"""#23: can a test on the critic's values tell the look-ahead's extrapolation from a better future?

For a saved POLA model and its dataset, the look-ahead of eq. 3 is rolled from 4,096 data states with the model's own
pieces (actor, dynamics model, critic ensemble) and two per-sample tests of a predicted state ``s_i`` are compared:

- value: the critic's pessimistic ``Q(s_i, a_i) <= Q(s_t, a_t)`` (``lookahead_trust_margin=0``);
- Bellman: the value the rollout implies for ``s_t``, ``sum_{j<i} gamma^j r_j + gamma^i Q(s_i, a_i)`` (the model's
  rewards, counted while the rollout is alive), ``<= Q(s_t, a_t)``: a better future the critic already counts at
  ``s_t`` passes, a value that appears only at the predicted state does not (``lookahead_trust_rule="bellman"``,
  which this measurement preceded).

One line per model: the spread of ``Q(s_i) - Q(s_t)`` in units of the batch's mean ``|Q(s_t)|`` (5th, 50th, 95th
percentiles over samples and steps), each test's share kept, the share of samples on which they agree and the share
on which the value test agrees with itself on a second draw of the actor's chain noise (how much of it is noise).
``python experiments/long100k/trust_gap.py MODEL.zip DATASET_ID [MODEL.zip DATASET_ID ...]`` (the dataset found as
``sb3-pola`` finds it: ``MINARI_DATASETS_PATH``, then the shipped ones).
"""

from __future__ import annotations

import argparse

import numpy as np
import torch as th

from sb3_pola import POLA
from sb3_pola.common.datasets import load_offline_dataset
from sb3_pola.common.dict_obs import key_slice
from sb3_pola.pola.losses import pessimistic_q


@th.no_grad()
def rollout_values(model: POLA, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """Pessimistic Q ``[T+1, B]``, the model's rewards ``[T, B]`` (critic units) and alive ``[T+1, B]``."""
    state, action = obs, model._sample_actor(model.policy.actor_features(obs))
    states, actions, rewards, alive = [state], [action], [], [th.ones(len(obs))]
    for _ in range(model.rollout_length):
        state, reward, terminal, _ = model._model_step(state, action)
        action = model._sample_lookahead(model.policy.actor_features(state))
        rewards.append(reward)
        alive.append(alive[-1] * (1.0 - terminal))
        states.append(state)
        actions.append(action)
    q = model.critic(th.cat(states), th.cat(actions)).view(-1, model.rollout_length + 1, len(obs))  # [N, T+1, B]
    return pessimistic_q(q, model.top_k, model.lcb_coef), th.stack(rewards), th.stack(alive)


def share(kept: th.Tensor, live: th.Tensor) -> float:
    """The share of the alive predicted terms ``[T, B]`` where ``kept``."""
    return float(kept[live].float().mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pairs", nargs="+", help="MODEL.zip DATASET_ID, repeated")
    parser.add_argument("--states", type=int, default=4096)
    args = parser.parse_args()
    if len(args.pairs) % 2:
        parser.error("give MODEL.zip DATASET_ID pairs")
    for path, dataset in zip(args.pairs[::2], args.pairs[1::2], strict=True):
        model = POLA.load(path, device="cpu")
        if model.rollout_length == 0:
            print(f"{dataset} {path}: T = 0, no look-ahead")
            continue
        data = load_offline_dataset(dataset)  # observations flat, as the policy reads them
        space = data.dict_observation_space
        if model.lookahead_fixed_goal and space is not None and "desired_goal" in space.spaces:
            model._goal_mask = th.zeros(data.observations.shape[1], dtype=th.bool)  # the goal kept in imagination
            model._goal_mask[key_slice(space, "desired_goal")] = True
        index = np.random.default_rng(0).choice(len(data.rewards), args.states, replace=False)
        obs = th.as_tensor(data.observations[index], dtype=th.float32)
        th.manual_seed(1)  # a second draw of the actor's chain noise: how far the value test repeats itself
        q_again = rollout_values(model, obs)[0]
        th.manual_seed(0)
        q, rewards, alive = rollout_values(model, obs)
        scale = q[0].abs().mean()
        powers = th.tensor([model.gamma**i for i in range(model.rollout_length + 1)])[:, None]  # [T+1, 1]
        implied = th.cumsum(powers[:-1] * alive[:-1] * rewards, dim=0) + powers[1:] * q[1:]  # [T, B]
        by_value, by_bellman = q[1:] <= q[0], implied <= q[0]
        live = alive[1:] > 0
        gap = ((q[1:] - q[0]) / scale)[live].numpy()
        p5, p50, p95 = np.percentile(gap, [5, 50, 95])
        print(
            f"{dataset} {path}: Q(s_t) {float(q[0].mean()):.1f}; (Q(s_i) - Q(s_t)) / |Q(s_t)| p5 {p5:+.4f} "
            f"p50 {p50:+.4f} p95 {p95:+.4f}; kept: value {share(by_value, live):.2f}, Bellman {share(by_bellman, live):.2f}; "
            f"agree {share(by_value == by_bellman, live):.2f}; the value test on a second draw of the actor's noise agrees "
            f"{share(by_value == (q_again[1:] <= q_again[0]), live):.2f}; alive at T {float(alive[-1].mean()):.2f}"
        )


if __name__ == "__main__":
    main()
