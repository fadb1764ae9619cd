"""The one episode loop: a policy's undiscounted returns, and whether each episode succeeded, over seeded episodes.

:func:`episode_returns` runs any policy (observation -> action; the score grid's models, the dataset recorder's
SAC and planner policies, uniform random actions); :func:`evaluate` runs a model's ``predict`` in it. Success
follows :func:`~sb3_pola.common.metrics.update_success`, the one rule. The main job and
:class:`~sb3_pola.common.callbacks.NormalizedScoreEvalCallback` evaluate with SB3's ``evaluate_policy`` on a
vectorised env instead, as SB3's ``EvalCallback`` does.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th

from sb3_pola.common.metrics import update_success

# observation (an array, or a dict of arrays for Dict spaces) -> action
Policy = Callable[[Any], Any]


def episode_returns(env: Any, policy: Policy, n_episodes: int, seed: int, successes: list[bool | None]) -> np.ndarray:
    """Returns of ``n_episodes`` full episodes of ``policy``, episode ``i`` reset with ``seed + i``.

    :param env: a Gymnasium env (not vectorised)
    :param policy: observation -> action
    :param n_episodes: number of episodes
    :param seed: seed of the first episode's reset
    :param successes: receives one entry per episode: whether a step's ``info["success"]`` (or ``info["is_success"]``)
        was true, as goal-reaching envs such as Gymnasium-Robotics' mazes report it, or ``None`` when the env reports
        no success
    :return: ``[n_episodes]`` undiscounted returns
    """
    returns = np.zeros(n_episodes)
    for i in range(n_episodes):
        obs, _ = env.reset(seed=seed + i)
        done, success = False, None
        while not done:
            obs, reward, terminated, truncated, info = env.step(policy(obs))
            returns[i] += float(reward)
            done = terminated or truncated
            success = update_success(success, info)
        successes.append(success)
    return returns


def evaluate(
    model: Any, env: Any, n_episodes: int, seed: int, deterministic: bool = True, successes: list[bool | None] | None = None
) -> np.ndarray:
    """Returns of ``n_episodes`` episodes of the model's policy (episode ``i`` reset with ``seed + i``).

    :param model: a POLA model
    :param env: a Gymnasium env (not vectorised)
    :param n_episodes: number of episodes
    :param seed: seed of the first episode's reset; with ``deterministic=False`` it also seeds torch, so the
        sampled actions repeat (the caller's torch RNG state is restored afterwards, so an evaluation during
        training leaves the training's random stream as it was)
    :param deterministic: ``model.predict``'s flag
    :param successes: if a list, it receives one entry per episode (see :func:`episode_returns`)
    :return: ``[n_episodes]`` undiscounted returns
    """
    successes = [] if successes is None else successes

    def policy(obs: Any) -> Any:
        return model.predict(obs, deterministic=deterministic)[0]

    if deterministic:
        return episode_returns(env, policy, n_episodes, seed, successes)
    devices = list(range(th.cuda.device_count())) if th.cuda.is_initialized() else []
    with th.random.fork_rng(devices=devices):
        th.manual_seed(seed)
        return episode_returns(env, policy, n_episodes, seed, successes)
