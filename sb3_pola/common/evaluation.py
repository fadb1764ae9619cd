"""The one episode loop: a policy's returns (and success) over seeded episodes of an env."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th

from sb3_pola.common.scores import update_success


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
    :param successes: if a list, it receives one entry per episode: whether a step's ``info["success"]`` (or
        ``info["is_success"]``) was true, as goal-reaching envs such as Gymnasium-Robotics' mazes report it, or
        ``None`` when the env reports no success
    :return: ``[n_episodes]`` undiscounted returns
    """
    successes = [] if successes is None else successes
    if deterministic:
        return _episode_returns(model, env, n_episodes, seed, deterministic, successes)
    devices = list(range(th.cuda.device_count())) if th.cuda.is_initialized() else []
    with th.random.fork_rng(devices=devices):
        th.manual_seed(seed)
        return _episode_returns(model, env, n_episodes, seed, deterministic, successes)


def _episode_returns(
    model: Any, env: Any, n_episodes: int, seed: int, deterministic: bool, successes: list[bool | None]
) -> np.ndarray:
    returns = np.zeros(n_episodes)
    for i in range(n_episodes):
        obs, _ = env.reset(seed=seed + i)
        done, success = False, None
        while not done:
            action, _ = model.predict(obs, deterministic=deterministic)
            obs, reward, terminated, truncated, info = env.step(action)
            returns[i] += float(reward)
            done = terminated or truncated
            success = update_success(success, info)
        successes.append(success)
    return returns
