"""Known termination rules of the Gymnasium MuJoCo tasks, as torch functions for the look-ahead.

Every rule takes ``(obs, action, next_obs)``, each ``[B, ...]``, and returns a bool tensor ``[B]``
(``True`` = the transition ends the episode). The rules are pure tensor ops: no host-device sync, no
data-dependent Python branching, differentiable inputs are fine (the output is boolean).

The rules are those of the Gymnasium ``v5`` environments with their default constructor arguments
(``exclude_current_positions_from_observation=True``), written on the *observation*:

- Hopper: healthy iff every ``|next_obs[1:]| < 100`` (both sides), height ``next_obs[0] > 0.7``
  and ``|angle| = |next_obs[1]| < 0.2``. Gymnasium checks the unclipped joint velocities while the
  observation clips them to ``[-10, 10]``, so a velocity above 100 is invisible in the observation:
  the only case where this rule and the env can differ.
- Walker2d: healthy iff ``0.8 < next_obs[0] < 2`` and ``-1 < next_obs[1] < 1``.
- Ant: healthy iff the observation is finite and ``0.2 <= next_obs[0] <= 1`` (closed interval).
- Humanoid: healthy iff ``1 < next_obs[0] < 2``.
- InvertedPendulum: terminal iff an observation entry is not finite or ``|next_obs[1]| > 0.2``.
- InvertedDoublePendulum: terminal iff the tip height ``0.6 (cos q1 + cos(q1 + q2)) <= 1``,
  computed from the sines and cosines in the observation.
- HalfCheetah, Swimmer, Reacher, Pusher, HumanoidStandup: never terminate.

Terminal = not healthy. Unknown environments give ``None``: the caller then uses a learned termination head.
"""

from __future__ import annotations

import re
from collections.abc import Callable

import torch as th

TerminationFn = Callable[[th.Tensor, th.Tensor, th.Tensor], th.Tensor]


def never_terminates(obs: th.Tensor, action: th.Tensor, next_obs: th.Tensor) -> th.Tensor:
    """All-``False`` termination (HalfCheetah, Swimmer, Reacher, Pusher, HumanoidStandup).

    :param obs: current observations ``[B, obs_dim]``
    :param action: actions ``[B, act_dim]``
    :param next_obs: next observations ``[B, obs_dim]``
    :return: ``[B]`` bool, all ``False``
    """
    return th.zeros(next_obs.shape[0], dtype=th.bool, device=next_obs.device)


def hopper_termination(obs: th.Tensor, action: th.Tensor, next_obs: th.Tensor) -> th.Tensor:
    """Hopper-v5: terminal iff not (all ``|s[1:]| < 100`` and ``0.7 < z < inf`` and ``|angle| < 0.2``).

    Both sides of the state range are checked (the common ``np.abs(x < 100)`` form checks one side only).

    :param obs: current observations ``[B, 11]``
    :param action: actions ``[B, 3]``
    :param next_obs: next observations ``[B, 11]``
    :return: ``[B]`` bool
    """
    height, angle = next_obs[:, 0], next_obs[:, 1]
    healthy_state = (next_obs[:, 1:].abs() < 100.0).all(dim=-1)
    healthy_z = (height > 0.7) & (height < float("inf"))
    healthy_angle = angle.abs() < 0.2
    return ~(healthy_state & healthy_z & healthy_angle)


def walker2d_termination(obs: th.Tensor, action: th.Tensor, next_obs: th.Tensor) -> th.Tensor:
    """Walker2d-v5: terminal iff not (``0.8 < z < 2`` and ``-1 < angle < 1``).

    :param obs: current observations ``[B, 17]``
    :param action: actions ``[B, 6]``
    :param next_obs: next observations ``[B, 17]``
    :return: ``[B]`` bool
    """
    height, angle = next_obs[:, 0], next_obs[:, 1]
    healthy = (height > 0.8) & (height < 2.0) & (angle > -1.0) & (angle < 1.0)
    return ~healthy


def ant_termination(obs: th.Tensor, action: th.Tensor, next_obs: th.Tensor) -> th.Tensor:
    """Ant-v5: terminal iff not (finite observation and ``0.2 <= z <= 1``).

    :param obs: current observations ``[B, obs_dim]``
    :param action: actions ``[B, 8]``
    :param next_obs: next observations ``[B, obs_dim]``
    :return: ``[B]`` bool
    """
    height = next_obs[:, 0]
    healthy = th.isfinite(next_obs).all(dim=-1) & (height >= 0.2) & (height <= 1.0)
    return ~healthy


def humanoid_termination(obs: th.Tensor, action: th.Tensor, next_obs: th.Tensor) -> th.Tensor:
    """Humanoid-v5: terminal iff not ``1 < z < 2``.

    :param obs: current observations ``[B, obs_dim]``
    :param action: actions ``[B, 17]``
    :param next_obs: next observations ``[B, obs_dim]``
    :return: ``[B]`` bool
    """
    height = next_obs[:, 0]
    return ~((height > 1.0) & (height < 2.0))


def inverted_pendulum_termination(obs: th.Tensor, action: th.Tensor, next_obs: th.Tensor) -> th.Tensor:
    """InvertedPendulum-v5: terminal iff a non-finite entry or ``|pole angle| > 0.2``.

    :param obs: current observations ``[B, 4]``
    :param action: actions ``[B, 1]``
    :param next_obs: next observations ``[B, 4]``
    :return: ``[B]`` bool
    """
    return ~th.isfinite(next_obs).all(dim=-1) | (next_obs[:, 1].abs() > 0.2)


def inverted_double_pendulum_termination(obs: th.Tensor, action: th.Tensor, next_obs: th.Tensor) -> th.Tensor:
    """InvertedDoublePendulum-v5: terminal iff the tip height ``y <= 1``.

    Observation ``[x, sin q1, sin q2, cos q1, cos q2, ...]``; both links are 0.6 long and the cart is at
    height 0, so ``y = 0.6 (cos q1 + cos(q1 + q2)) = 0.6 (c1 + c1 c2 - s1 s2)``.

    :param obs: current observations ``[B, 9]``
    :param action: actions ``[B, 1]``
    :param next_obs: next observations ``[B, 9]``
    :return: ``[B]`` bool
    """
    s1, s2, c1, c2 = next_obs[:, 1], next_obs[:, 2], next_obs[:, 3], next_obs[:, 4]
    y = 0.6 * (c1 + c1 * c2 - s1 * s2)
    return y <= 1.0


# Family name (lower case, letters and digits only) -> rule.
TERMINATION_FNS: dict[str, TerminationFn] = {
    "hopper": hopper_termination,
    "walker2d": walker2d_termination,
    "ant": ant_termination,
    "humanoid": humanoid_termination,
    "invertedpendulum": inverted_pendulum_termination,
    "inverteddoublependulum": inverted_double_pendulum_termination,
    "halfcheetah": never_terminates,
    "swimmer": never_terminates,
    "reacher": never_terminates,
    "pusher": never_terminates,
    "humanoidstandup": never_terminates,
}


def _candidates(env_id: str) -> list[str]:
    """Family-name candidates of an id: ``"Hopper-v5"``, ``"hopper"``, ``"mujoco/hopper/medium-v0"``,
    ``"hopper-medium-v2"``, ``"half_cheetah"`` all give ``"hopper"`` / ``"halfcheetah"`` among them."""
    out: list[str] = []
    for part in env_id.lower().split("/"):
        part = re.sub(r"-v\d+$", "", part.strip())
        for name in (part, part.split("-")[0]):
            out.append(re.sub(r"[^a-z0-9]", "", name))
    return out


def get_termination_fn(env_id: str | None) -> TerminationFn | None:
    """The known termination rule of an environment, or ``None`` if there is none.

    Matching is on the environment family, case-insensitive and version-agnostic: ``"Hopper-v5"``,
    ``"hopper"``, ``"Hopper-v4"``, a Minari id like ``"mujoco/hopper/medium-v0"`` or a D4RL-style
    ``"hopper-medium-v2"`` all give the Hopper rule. The rules are those of Gymnasium ``v5`` (the same
    as ``v4`` for these tasks, with default arguments).

    :param env_id: environment (or dataset) id; ``None`` gives ``None``
    :return: a function ``(obs, action, next_obs) -> bool [B]``, or ``None`` for an unknown environment
    """
    if env_id is None:
        return None
    for name in _candidates(env_id):
        if name in TERMINATION_FNS:
            return TERMINATION_FNS[name]
    return None
