"""Recording episodes: a policy (or uniform random actions) run in an env, as Minari episode buffers or returns."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_pola.common.evaluation import episode_returns

# observation (an array, or a dict of arrays for Dict spaces) -> action in env units
PolicyFn = Callable[[Any], np.ndarray]


def progress_bar(total: int, desc: str, enabled: bool) -> Any:
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, disable=not enabled, leave=False, file=sys.stderr)


def _stack(observations: list[Any]) -> Any:
    """Stack per-step observations; Dict ones key by key, the layout Minari's episode buffers take."""
    if isinstance(observations[0], dict):
        return {key: _stack([obs[key] for obs in observations]) for key in observations[0]}
    return np.asarray(observations)


def rollout(
    env: gym.Env, policy: PolicyFn | None, n_steps: int, seed: int, progress: bool = False, desc: str = "rollout"
) -> list[Any]:
    """Record exactly ``n_steps`` transitions as Minari episode buffers.

    Episodes end on termination or on the env's time limit (truncation); the last one, cut by the
    step budget, is marked truncated.

    :param env: environment (with its TimeLimit)
    :param policy: observation -> action in env units; None for uniform random actions
    :param n_steps: transitions to record
    :param seed: seed of the first reset and of the action space
    :return: list of ``minari.data_collector.EpisodeBuffer``
    """
    from minari.data_collector import EpisodeBuffer

    env.action_space.seed(seed)
    episodes: list[Any] = []
    obs, _ = env.reset(seed=seed)
    ep_obs, ep_act, ep_rew, ep_term, ep_trunc = [obs], [], [], [], []
    with progress_bar(n_steps, desc, progress) as bar:
        for step in range(n_steps):
            action = env.action_space.sample() if policy is None else policy(obs)
            obs, reward, terminated, truncated, _ = env.step(action)
            last = step == n_steps - 1
            ep_obs.append(obs)
            ep_act.append(np.asarray(action, dtype=np.float32))
            ep_rew.append(float(reward))
            ep_term.append(bool(terminated))
            ep_trunc.append(bool(truncated) or (last and not terminated))
            bar.update(1)
            if terminated or truncated or last:
                episodes.append(
                    EpisodeBuffer(
                        id=len(episodes),
                        observations=_stack(ep_obs),
                        actions=np.asarray(ep_act),
                        rewards=np.asarray(ep_rew),
                        terminations=np.asarray(ep_term),
                        truncations=np.asarray(ep_trunc),
                    )
                )
                if not last:
                    obs, _ = env.reset()
                    ep_obs, ep_act, ep_rew, ep_term, ep_trunc = [obs], [], [], [], []
    return episodes


def run_episodes(env: gym.Env, policy: PolicyFn | None, n_episodes: int, seed: int) -> tuple[list[float], list[bool]]:
    """Undiscounted returns of ``n_episodes`` full episodes (the action space seeded with ``seed``, episode ``i`` reset
    with ``seed + i``), and whether each succeeded (:func:`~sb3_pola.common.metrics.update_success`'s rule).

    :param policy: observation -> action in env units; None for uniform random actions
    """
    env.action_space.seed(seed)
    successes: list[bool | None] = []
    returns = episode_returns(env, policy or (lambda _obs: env.action_space.sample()), n_episodes, seed, successes)
    return [float(r) for r in returns], [bool(s) for s in successes]


def evaluate(env: gym.Env, policy: PolicyFn | None, n_episodes: int, seed: int) -> list[float]:
    """Undiscounted returns of ``n_episodes`` full episodes."""
    return run_episodes(env, policy, n_episodes, seed)[0]


def policy_fn(model: Any, deterministic: bool) -> PolicyFn:
    """Observation -> env-unit action of an SB3 model (``predict`` unscales and clips)."""

    def act(obs: np.ndarray) -> np.ndarray:
        return model.predict(obs, deterministic=deterministic)[0]

    return act
