"""Termination rules against the real Gymnasium v5 MuJoCo environments."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from sb3_pola.common.termination import (
    get_termination_fn,
    hopper_termination,
    never_terminates,
    walker2d_termination,
)


def _rollout(env_id: str, n_steps: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Random-action transitions ``(obs, action, next_obs, terminated)`` of a real env, resetting at episode ends."""
    env = gym.make(env_id)
    env.action_space.seed(seed)
    obs, _ = env.reset(seed=seed)
    observations, actions, next_observations, terminals = [], [], [], []
    for _ in range(n_steps):
        action = env.action_space.sample()
        next_obs, _, terminated, truncated, _ = env.step(action)
        observations.append(obs)
        actions.append(action)
        next_observations.append(next_obs)
        terminals.append(terminated)
        obs = next_obs
        if terminated or truncated:
            obs, _ = env.reset()
    env.close()
    return np.array(observations), np.array(actions), np.array(next_observations), np.array(terminals)


@pytest.mark.parametrize(
    "env_id, n_steps, must_terminate",
    [
        ("InvertedPendulum-v5", 2000, True),
        ("InvertedDoublePendulum-v5", 2000, True),
        ("Hopper-v5", 3000, True),
        ("Walker2d-v5", 3000, True),
        ("HalfCheetah-v5", 1000, False),
        ("Ant-v5", 1000, False),
        ("Swimmer-v5", 300, False),
        ("Reacher-v5", 300, False),
    ],
)
def test_rule_matches_real_env(env_id: str, n_steps: int, must_terminate: bool) -> None:
    obs, actions, next_obs, terminated = _rollout(env_id, n_steps)
    fn = get_termination_fn(env_id)
    assert fn is not None
    pred = fn(th.as_tensor(obs), th.as_tensor(actions), th.as_tensor(next_obs))
    assert pred.dtype == th.bool and pred.shape == (n_steps,)
    np.testing.assert_array_equal(pred.numpy(), terminated)
    # float32 inputs (what the look-ahead feeds) give the same answer on real data
    pred32 = fn(th.as_tensor(obs).float(), th.as_tensor(actions).float(), th.as_tensor(next_obs).float())
    np.testing.assert_array_equal(pred32.numpy(), terminated)
    if must_terminate:
        assert terminated.any() and not terminated.all(), "the rollout should contain both terminal and non-terminal steps"


def test_humanoid_rule_matches_real_env() -> None:
    obs, actions, next_obs, terminated = _rollout("Humanoid-v5", 300)
    fn = get_termination_fn("Humanoid-v5")
    assert fn is not None
    pred = fn(th.as_tensor(obs), th.as_tensor(actions), th.as_tensor(next_obs))
    np.testing.assert_array_equal(pred.numpy(), terminated)
    assert terminated.any()


def test_hopper_state_range_is_two_sided() -> None:
    # A healthy Hopper state, then one entry pushed below -100 or above +100: both must be terminal.
    healthy = th.zeros(3, 11)
    healthy[:, 0] = 1.25  # height
    action = th.zeros(3, 3)
    healthy[1, 5] = -150.0
    healthy[2, 5] = 150.0
    done = hopper_termination(healthy, action, healthy)
    assert done.tolist() == [False, True, True]
    # the buggy one-sided form np.abs(x < 100) would call the -150 state healthy
    buggy_healthy = np.all(np.abs(healthy[:, 1:].numpy() < 100), axis=-1)
    assert bool(buggy_healthy[1]) and not bool(~done[1])


def test_hopper_and_walker_boundaries() -> None:
    def hopper(z: float, angle: float) -> bool:
        s = th.zeros(1, 11)
        s[0, 0], s[0, 1] = z, angle
        return bool(hopper_termination(s, th.zeros(1, 3), s)[0])

    assert not hopper(1.0, 0.0)
    assert hopper(0.7, 0.0) and hopper(0.69, 0.0)  # strict 0.7 < z
    assert hopper(1.0, 0.2) and hopper(1.0, -0.2) and not hopper(1.0, 0.19)
    assert hopper(float("nan"), 0.0) and hopper(float("inf"), 0.0)

    def walker(z: float, angle: float) -> bool:
        s = th.zeros(1, 17)
        s[0, 0], s[0, 1] = z, angle
        return bool(walker2d_termination(s, th.zeros(1, 6), s)[0])

    assert not walker(1.2, 0.0) and not walker(1.2, -0.99)
    assert walker(0.8, 0.0) and walker(2.0, 0.0) and walker(1.2, 1.0) and walker(1.2, -1.0)


@pytest.mark.parametrize(
    "env_id, expected",
    [
        ("Hopper-v5", hopper_termination),
        ("hopper", hopper_termination),
        ("HOPPER-v4", hopper_termination),
        ("mujoco/hopper/medium-v0", hopper_termination),
        ("hopper-medium-v2", hopper_termination),
        ("Walker2d-v5", walker2d_termination),
        ("HalfCheetah-v5", never_terminates),
        ("half_cheetah", never_terminates),
        ("halfcheetah-medium-expert-v2", never_terminates),
        ("Pusher-v5", never_terminates),
        ("Pendulum-v1", None),
        ("antmaze-umaze-v2", None),
        ("CartPole-v1", None),
        (None, None),
    ],
)
def test_get_termination_fn_matching(env_id: str | None, expected: object) -> None:
    assert get_termination_fn(env_id) is expected


def test_never_terminates_shape_and_device() -> None:
    fn = get_termination_fn("HalfCheetah-v5")
    assert fn is not None
    out = fn(th.zeros(5, 17), th.zeros(5, 6), th.randn(5, 17))
    assert out.dtype == th.bool and out.shape == (5,) and not out.any()


def test_ant_rule_matches_real_env_where_it_terminates() -> None:
    """Random actions rarely end an Ant episode: states placed above, inside and below the healthy z range do."""
    env = gym.make("Ant-v5")
    fn = get_termination_fn("Ant-v5")
    assert fn is not None
    obs_list, actions, next_list, terminated = [], [], [], []
    for i, z in enumerate([1.6, 0.75, 0.05, 1.3, 0.55, 0.1]):
        env.reset(seed=i)
        base = env.unwrapped
        qpos, qvel = base.init_qpos.copy(), base.init_qvel.copy()
        qpos[2] = z
        base.set_state(qpos, qvel)
        obs = base._get_obs()
        action = np.zeros(env.action_space.shape, dtype=np.float32)
        next_obs, _, term, _, _ = env.step(action)
        obs_list.append(obs)
        actions.append(action)
        next_list.append(next_obs)
        terminated.append(term)
    env.close()
    terminated_arr = np.array(terminated)
    assert terminated_arr.any() and not terminated_arr.all()
    pred = fn(th.as_tensor(np.array(obs_list)), th.as_tensor(np.array(actions)), th.as_tensor(np.array(next_list)))
    np.testing.assert_array_equal(pred.numpy(), terminated_arr)
