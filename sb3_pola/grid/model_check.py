"""``sb3-pola model-check``: how well the dynamics model predicts what the look-ahead asks of it.

The look-ahead of eq. 3 chains the model ``T`` times from dataset states under the *policy's* actions.
The fit's holdout score measures only one step under the *dataset's* actions. This check fits the model
once per ``mean_loss`` (same seed, same budget) and measures, on held-out starts:

- ``k``-step open-loop error along the dataset's own trajectories (dataset actions), ``k = 1..T``;
- with ``--policy MODEL.zip`` on a MuJoCo env whose observation is ``(qpos, qvel)`` or ``(qpos[1:], qvel)``
  (HalfCheetah, Hopper, Walker2d, InvertedPendulum): ``k``-step error under that policy's actions against
  the real simulator, started from dataset states (the root's x position, where the observation lacks it,
  set to 0: these envs do not depend on it);
- the elites' disagreement along the same rollouts (is it a usable warning of model error?).

Errors are mean squared errors of the raw next state, next to the error of predicting "no change".
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np

if TYPE_CHECKING:
    import gymnasium as gym
    from gymnasium.envs.mujoco.mujoco_env import MujocoEnv

    from sb3_pola.common.datasets import OfflineDataset
    from sb3_pola.common.dynamics import EnsembleDynamics
    from sb3_pola.pola import POLA


def chained_starts(data: OfflineDataset, horizon: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """Indices ``i`` whose next ``horizon`` transitions follow one another in one episode.

    :param data: the dataset
    :param horizon: chain length ``T``
    :param n: number of starts wanted
    :param rng: draws the starts
    :return: up to ``n`` distinct start indices
    """
    obs, next_obs = data.observations, data.next_observations
    follows = np.all(next_obs[:-1] == obs[1:], axis=1) & (data.dones[:-1] == 0)  # i -> i + 1 is the same episode
    ok = np.ones(len(obs) - horizon, dtype=bool)
    for k in range(horizon - 1):
        ok &= follows[k : len(obs) - horizon + k]
    candidates = np.flatnonzero(ok)
    return rng.choice(candidates, size=min(n, len(candidates)), replace=False)


def open_loop_errors(
    dynamics: EnsembleDynamics, data: OfflineDataset, starts: np.ndarray, horizon: int
) -> dict[str, list[float]]:
    """``k``-step MSE of the model along the dataset's trajectories (its own actions), and of "no change".

    :param dynamics: the fitted model
    :param data: the dataset
    :param starts: start indices (:func:`chained_starts`)
    :param horizon: steps ``T``
    :return: ``mse``, ``no_change_mse`` and the elites' ``disagreement``, one value per ``k = 1..T``
    """
    import torch as th

    obs = th.as_tensor(data.observations[starts])
    state = obs
    mse, no_change, doubt = [], [], []
    with th.no_grad():
        for k in range(horizon):
            act = th.as_tensor(data.actions[starts + k])
            state, _, _, u = dynamics.step(state, act)
            target = th.as_tensor(data.next_observations[starts + k])
            mse.append(float(((state - target) ** 2).mean()))
            no_change.append(float(((obs - target) ** 2).mean()))
            doubt.append(float(u.mean()))
    return {"mse": mse, "no_change_mse": no_change, "disagreement": doubt}


def policy_rollout_errors(
    dynamics: EnsembleDynamics, policy_model: POLA, env: gym.Env, data: OfflineDataset, starts: np.ndarray, horizon: int
) -> dict[str, list[float]]:
    """``k``-step MSE of the model against the simulator under the policy's own (deterministic) actions.

    :param dynamics: the fitted model
    :param policy_model: the policy whose actions drive both rollouts
    :param env: the dataset's MuJoCo env
    :param data: the dataset
    :param starts: start indices (:func:`chained_starts`)
    :param horizon: steps ``T``
    :return: ``mse``, ``no_change_mse``, ``disagreement`` per ``k`` and ``error_disagreement_corr`` at ``k = T``
    """
    import torch as th

    sim = cast("MujocoEnv", env.unwrapped)
    nq, nv = sim.model.nq, sim.model.nv
    obs_dim = data.observations.shape[1]
    if obs_dim not in (nq + nv, nq - 1 + nv):
        raise ValueError(f"{data.env_id}: the observation is not (qpos[1:], qvel) or (qpos, qvel); cannot set the simulator")
    n_pos = obs_dim - nv  # qpos entries in the observation: nq, or nq - 1 without the root's x position
    low, high = data.action_space.low, data.action_space.high
    errors = np.zeros((horizon, len(starts)))
    no_change = np.zeros((horizon, len(starts)))
    doubt = np.zeros((horizon, len(starts)))
    env.reset(seed=0)
    for j, i in enumerate(starts):
        s0 = data.observations[i].astype(np.float64)
        qpos = s0[:n_pos] if n_pos == nq else np.concatenate(([0.0], s0[:n_pos]))
        sim.set_state(qpos, s0[n_pos:])
        real, model_state = s0, th.as_tensor(s0, dtype=th.float32)[None]
        for k in range(horizon):
            action, _ = policy_model.predict(real, deterministic=True)  # env units
            scaled = th.as_tensor(2.0 * (action - low) / (high - low) - 1.0, dtype=th.float32)[None]  # [-1, 1]
            with th.no_grad():
                model_state, _, _, u = dynamics.step(model_state, scaled)
            real, _, terminated, _, _ = env.step(action)
            errors[k, j] = float(((model_state[0].numpy() - real) ** 2).mean())
            no_change[k, j] = float(((s0 - real) ** 2).mean())
            doubt[k, j] = float(u[0])
            if terminated:  # the rest of this rollout does not exist in the simulator
                errors[k + 1 :, j] = np.nan
                no_change[k + 1 :, j] = np.nan
                doubt[k + 1 :, j] = np.nan
                break
    return {
        "mse": np.nanmean(errors, axis=1).tolist(),
        "no_change_mse": np.nanmean(no_change, axis=1).tolist(),
        "disagreement": np.nanmean(doubt, axis=1).tolist(),
        "error_disagreement_corr": float(np.corrcoef(np.nan_to_num(errors[-1]), np.nan_to_num(doubt[-1]))[0, 1]),
    }
