"""Dict observations (Minari's goal-conditioned datasets: ``observation``, ``achieved_goal``, ``desired_goal``).

POLA's networks take one flat vector, so a ``Dict`` of ``Box`` spaces is flattened in one fixed order
everywhere: the dataset's arrays, the env an evaluation runs in (Gymnasium's ``FlattenObservation``)
and ``predict`` given the env's own dict observations. The order is the ``Dict`` space's key order,
which Gymnasium sorts alphabetically (``achieved_goal``, ``desired_goal``, ``observation`` for the
mazes); each key's value is flattened C-order, exactly as :func:`gymnasium.spaces.flatten` does. The
state products of the actor then apply to the flattened vector.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn


def check_dict_space(space: spaces.Dict, where: str) -> None:
    """Raise ``ValueError`` unless ``space`` is a non-empty ``Dict`` of ``Box`` spaces (nothing nested)."""
    bad = {key: sub for key, sub in space.spaces.items() if not isinstance(sub, spaces.Box)}
    if not space.spaces or bad:
        raise ValueError(
            f"{where} has observation space {space}: a Dict observation space must hold Box spaces only "
            f"(not {', '.join(f'{k}: {v}' for k, v in bad.items()) or 'nothing'})"
        )


def flat_space(space: spaces.Dict) -> spaces.Box:
    """The flat ``Box`` of a ``Dict`` of ``Box`` spaces (Gymnasium's ``flatten_space``, the wrapper's space)."""
    flat = spaces.flatten_space(space)
    assert isinstance(flat, spaces.Box)
    return flat


def key_slice(space: spaces.Dict, key: str) -> slice:
    """The columns of ``key`` in the flattened vector (the space's key order, each key C-order)."""
    start = 0
    for name, sub in space.spaces.items():
        size = int(np.prod(sub.shape or ()))
        if name == key:
            return slice(start, start + size)
        start += size
    raise KeyError(f"{key!r} is not a key of {space}")


def flatten_episode_observations(space: spaces.Dict, observations: dict[str, Any], n: int) -> np.ndarray:
    """``[n, D]`` rows of one episode's dict observations (each key ``[n, *shape]``), in the space's key order."""
    missing = set(space.spaces) - set(observations)
    if missing:
        raise ValueError(f"dict observations lack the keys {sorted(missing)} of the space {space}")
    return np.concatenate([np.asarray(observations[key]).reshape(n, -1) for key in space.spaces], axis=1)


def flatten_observation(space: spaces.Dict, observation: dict[str, Any]) -> np.ndarray:
    """One dict observation -> ``[D]``, or a batch (each key ``[n, *shape]``) -> ``[n, D]``.

    :raises ValueError: other keys than the space's, or a value of the wrong shape
    """
    keys, given = list(space.spaces), set(observation)
    if given != set(keys):
        raise ValueError(
            f"predict got a dict observation with keys {sorted(given)}; this model's observation space has the keys "
            f"{keys} ({space})"
        )
    batch: int | None = None
    parts: list[np.ndarray] = []
    for key in keys:
        value = np.asarray(observation[key])
        shape = space.spaces[key].shape
        assert shape is not None  # a Box's
        if value.shape == shape:
            n = None
        elif value.ndim == len(shape) + 1 and value.shape[1:] == shape:
            n = value.shape[0]
        else:
            raise ValueError(
                f"predict got {key!r} of shape {value.shape}; the observation space {space} expects {shape} "
                f"(one observation) or (n, {', '.join(map(str, shape))}) (a batch)"
            )
        if parts and n != batch:
            raise ValueError(f"predict got dict values with different batch sizes ({batch} and {n}) for {keys}")
        batch = n
        parts.append(value.reshape(-1) if n is None else value.reshape(n, -1))
    return np.concatenate(parts, axis=-1)


class VecFlattenObservation(VecEnvWrapper):
    """A VecEnv's dict observations flattened as :func:`flatten_observation` does (``FlattenObservation`` for VecEnvs).

    :param venv: a VecEnv with a ``Dict`` of ``Box`` observation space
    """

    def __init__(self, venv: VecEnv) -> None:
        assert isinstance(venv.observation_space, spaces.Dict)
        check_dict_space(venv.observation_space, f"VecEnv {venv}")
        self.dict_space = venv.observation_space
        super().__init__(venv, observation_space=flat_space(self.dict_space))

    def _flatten(self, obs: Any) -> np.ndarray:
        return flatten_observation(self.dict_space, obs).astype(self.observation_space.dtype)

    def reset(self) -> VecEnvObs:
        return self._flatten(self.venv.reset())

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        for info in infos:  # SB3 keeps the last observation of an episode here, as the env returned it
            if isinstance(info.get("terminal_observation"), dict):
                info["terminal_observation"] = self._flatten(info["terminal_observation"])
        return self._flatten(obs), rewards, dones, infos


def flatten_env(env: gym.Env | VecEnv) -> Any:
    """``env`` with its dict observations flattened (as the dataset's), or ``env`` itself if they are flat already."""
    if not isinstance(env.observation_space, spaces.Dict):
        return env
    if isinstance(env, VecEnv):
        return VecFlattenObservation(env)
    check_dict_space(env.observation_space, f"env {env}")
    return gym.wrappers.FlattenObservation(env)
