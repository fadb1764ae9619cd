"""Dict observations: a goal-style Minari dataset through the loader, the env, the policy, predict and save/load."""

from __future__ import annotations

import pathlib

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from helpers import light_kwargs, record_random_dataset
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_pola import POLA
from sb3_pola.common.dataset_paths import DatasetError, package_datasets_dir
from sb3_pola.common.datasets import OfflineDataset, load_offline_dataset, make_env, synthetic_dataset
from sb3_pola.common.dict_obs import check_dict_space, flatten_observation

KEYS = ["achieved_goal", "desired_goal", "observation"]  # Gymnasium's (sorted) order, the flattening order


@pytest.fixture(scope="module")
def goal_dataset(tmp_path_factory: pytest.TempPathFactory) -> str:
    return str(record_random_dataset(tmp_path_factory.mktemp("goal"), "goalpendulum/random-v0", "GoalPendulum-v0", 400))


@pytest.fixture(scope="module")
def goal_model(goal_dataset: str) -> POLA:
    return POLA("MlpPolicy", dataset=goal_dataset, **light_kwargs()).learn(4)


def test_dense_reward_options_stay_off_with_a_desired_goal(goal_model: POLA) -> None:
    """``"auto"`` (the default) of ``q_term_confidence`` and ``bc_top_fraction`` is off on goal-conditioned data."""
    assert (goal_model.q_term_confidence, goal_model.bc_top_fraction) == ("auto", "auto")
    assert goal_model._dense_option("q_term_confidence") is None and goal_model._dense_option("bc_top_fraction") is None
    assert goal_model._imitation_rows is None and "train/q_term_share" not in goal_model.logger.name_to_value


def test_dataset_is_flattened_in_the_spaces_key_order(goal_dataset: str) -> None:
    data = load_offline_dataset(goal_dataset, use_cache=False)
    assert isinstance(data.dict_observation_space, gym.spaces.Dict)
    assert list(data.dict_observation_space.spaces) == KEYS
    assert data.observation_space.shape == (5,) and data.observations.shape == (400, 5)
    # the first reset of the recording (seed 0), flattened by Gymnasium, is the first row
    env = gym.make("GoalPendulum-v0")
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(data.observations[0], gym.spaces.flatten(env.observation_space, obs), rtol=1e-6)
    np.testing.assert_allclose(data.observations[0], np.concatenate([obs[k] for k in KEYS]), rtol=1e-6)
    np.testing.assert_array_equal(data.next_observations[:-1][data.dones[:-1] == 0][:5], data.observations[1:6])
    # cached arrays read back equal
    load_offline_dataset(goal_dataset)
    again = load_offline_dataset(goal_dataset)
    np.testing.assert_array_equal(again.observations, data.observations)
    assert again.dict_observation_space == data.dict_observation_space


def test_dataset_env_check(goal_dataset: str) -> None:
    load_offline_dataset(goal_dataset, env=gym.make("GoalPendulum-v0"), use_cache=False)  # the env's own dict space
    with pytest.raises(DatasetError, match=r"does not match the env.*Dict"):
        load_offline_dataset(goal_dataset, env=gym.make("Pendulum-v1"), use_cache=False)


def test_make_env_flattens_as_the_dataset(goal_dataset: str) -> None:
    data = load_offline_dataset(goal_dataset)
    env = make_env(data)
    assert env.observation_space == data.observation_space
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(obs, data.observations[0], rtol=1e-6)
    assert make_env(goal_dataset).observation_space == data.observation_space


def test_only_dicts_of_boxes() -> None:
    box = gym.spaces.Box(-1, 1, (2,))
    check_dict_space(gym.spaces.Dict({"a": box}), "x")
    for space in (
        gym.spaces.Dict({"a": box, "b": gym.spaces.Discrete(3)}),
        gym.spaces.Dict({"a": gym.spaces.Dict({"b": box})}),
    ):
        with pytest.raises(ValueError, match="Box spaces only"):
            check_dict_space(space, "x")


def test_flatten_observation_single_and_batch() -> None:
    space = gym.spaces.Dict({"b": gym.spaces.Box(-1, 1, (2,)), "a": gym.spaces.Box(-1, 1, (1,))})
    assert list(space.spaces) == ["a", "b"]
    np.testing.assert_array_equal(flatten_observation(space, {"b": [1, 2], "a": [3]}), [3, 1, 2])
    batch = flatten_observation(space, {"b": np.zeros((4, 2)), "a": np.ones((4, 1))})
    assert batch.shape == (4, 3) and (batch[:, 0] == 1).all()
    with pytest.raises(ValueError, match="keys"):
        flatten_observation(space, {"a": [3]})
    with pytest.raises(ValueError, match="shape"):
        flatten_observation(space, {"b": [1, 2, 3], "a": [3]})
    with pytest.raises(ValueError, match="batch sizes"):
        flatten_observation(space, {"b": np.zeros((4, 2)), "a": np.ones((3, 1))})


def test_trains_and_predicts_from_dict_observations(goal_model: POLA) -> None:
    model = goal_model
    assert model.num_timesteps == 4 and model.observation_space.shape == (5,)
    assert model.dict_observation_space is not None and list(model.dict_observation_space.spaces) == KEYS
    assert model.policy.features_extractor.features_dim == 5  # the flat vector (the products are off by default)
    env = gym.make("GoalPendulum-v0")
    obs, _ = env.reset(seed=3)
    action, _ = model.predict(obs, deterministic=True)
    flat, _ = model.predict(gym.spaces.flatten(env.observation_space, obs), deterministic=True)
    assert action.shape == (1,)
    np.testing.assert_array_equal(action, flat)
    batch = {k: np.stack([obs[k]] * 3) for k in obs}
    actions, _ = model.predict(batch, deterministic=True)
    assert actions.shape == (3, 1)
    np.testing.assert_allclose(actions, np.stack([action] * 3), atol=1e-6)
    with pytest.raises(ValueError, match="keys"):
        model.predict({"observation": obs["observation"]})
    with pytest.raises(ValueError, match="NaN"):
        model.predict({**obs, "desired_goal": np.array([np.nan], dtype=np.float32)})


def test_env_with_dict_observations(goal_dataset: str) -> None:
    model = POLA("MlpPolicy", env=gym.make("GoalPendulum-v0"), dataset=goal_dataset, **light_kwargs(rollout_length=0))
    assert model.observation_space.shape == (5,) and model.dict_observation_space is not None
    model.learn(2)
    model = POLA("MlpPolicy", env="GoalPendulum-v0", dataset=goal_dataset, **light_kwargs(rollout_length=0))
    assert model.observation_space.shape == (5,)
    venv = DummyVecEnv([lambda: gym.make("GoalPendulum-v0")] * 2)
    model = POLA("MlpPolicy", env=venv, dataset=goal_dataset, **light_kwargs(rollout_length=0))
    assert model.observation_space.shape == (5,) and model.dict_observation_space == venv.observation_space
    assert model.env is not None
    model.env.seed(1)
    first = model.env.reset()
    assert first.shape == (2, 5)
    raw = gym.make("GoalPendulum-v0").reset(seed=1)[0]
    np.testing.assert_allclose(first[0], gym.spaces.flatten(venv.observation_space, raw), rtol=1e-6)
    obs, _, dones, _ = model.env.step(np.zeros((2, 1), dtype=np.float32))
    assert obs.shape == (2, 5) and not dones.any()
    model.learn(2)


def test_save_load_keeps_the_dict_space(goal_model: POLA, goal_dataset: str, tmp_path: pathlib.Path) -> None:
    path = tmp_path / "goal.zip"
    goal_model.save(path)
    env = gym.make("GoalPendulum-v0")
    obs, _ = env.reset(seed=5)
    expected, _ = goal_model.predict(obs, deterministic=True)
    for loaded in (POLA.load(path, device="cpu"), POLA.load(path, env=env, device="cpu")):
        assert loaded.dict_observation_space == goal_model.dict_observation_space
        np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], expected)
    POLA.load(path, env=make_env(goal_dataset), device="cpu")  # the flattened env
    with pytest.raises(
        ValueError, match=r"model has observation space Box.*flattened from Dict\(.*the env has observation space Box"
    ):
        POLA.load(path, env=gym.make("Pendulum-v1"), device="cpu")
    # continuing on another dataset of other spaces: a clear error naming both
    other = record_random_dataset(tmp_path, "pendulum/random-v0", "Pendulum-v1", 50)
    with pytest.raises(ValueError, match=r"observation space Box.*does not match the model's Dict"):
        POLA.load(path, dataset=str(other), device="cpu").learn(1)


def test_flat_model_refuses_dict_observations(goal_model: POLA, tmp_path: pathlib.Path) -> None:
    data = record_random_dataset(tmp_path, "pendulum/random-v0", "Pendulum-v1", 50)
    model = POLA("MlpPolicy", dataset=str(data), **light_kwargs())
    with pytest.raises(ValueError, match=r"dict observation.*pass an array"):
        model.predict({"observation": np.zeros(3)})
    assert isinstance(load_offline_dataset(str(data)), OfflineDataset)


def test_make_env_prefers_the_eval_env_spec(tmp_path: pathlib.Path) -> None:
    """Minari's ``eval_env_spec`` (the mazes: a fixed goal) is the env to evaluate in; ``env_spec`` the one collected in."""
    import json

    path = record_random_dataset(tmp_path, "pendulum/random-v0", "Pendulum-v1", 20)
    metadata_file = path / "data" / "metadata.json"
    metadata = json.loads(metadata_file.read_text())
    spec = json.loads(metadata["env_spec"])
    metadata["eval_env_spec"] = json.dumps({**spec, "max_episode_steps": 77})
    metadata_file.write_text(json.dumps(metadata))
    assert make_env(str(path)).spec.max_episode_steps == 77
    assert make_env(str(path), eval_env=False).spec.max_episode_steps == spec["max_episode_steps"]


def test_export_takes_the_flattened_vector(goal_model: POLA, tmp_path: pathlib.Path) -> None:
    import torch as th

    path = goal_model.export_policy(tmp_path / "goal.pt", format="torchscript")
    graph = th.jit.load(str(path))
    obs, _ = gym.make("GoalPendulum-v0").reset(seed=7)
    flat = gym.spaces.flatten(goal_model.dict_observation_space, obs).astype(np.float32)
    with th.no_grad():
        exported = graph(th.as_tensor(flat)[None])[0].numpy()
    np.testing.assert_allclose(exported, goal_model.predict(obs, deterministic=True)[0], atol=1e-5)


def test_goal_switches_of_the_shipped_umaze(monkeypatch: pytest.MonkeyPatch, tmp_path: pathlib.Path) -> None:
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(package_datasets_dir()))
    data = load_offline_dataset("pointmaze/umaze-v0", cache_dir=tmp_path)
    goal = slice(2, 4)  # desired_goal, after achieved_goal (2 columns) in the flattening order
    switches = data.goal_switches()
    changed = np.any(data.observations[:, goal] != data.next_observations[:, goal], axis=1)
    np.testing.assert_array_equal(switches, changed)
    assert switches.sum() > 100 and data.dones.sum() == 0
    # the collector draws a new goal the step after the old one is reached
    assert (data.rewards[np.flatnonzero(switches) - 1] > 0).mean() > 0.95
    terminal = data.with_goal_switches("terminal")
    np.testing.assert_array_equal(terminal.dones.astype(bool), switches)
    assert terminal.fingerprint != data.fingerprint
    assert terminal.with_goal_switches("terminal").fingerprint == terminal.fingerprint
    assert data.dones.sum() == 0  # the original is left alone
    model = POLA("MlpPolicy", dataset=data, goal_switches="terminal", hindsight_goals=False, **light_kwargs())
    np.testing.assert_array_equal(model.offline_data.dones.astype(bool), switches)
    as_recorded = POLA("MlpPolicy", dataset=data, goal_switches=None, hindsight_goals=False, **light_kwargs()).offline_data
    assert as_recorded.goal_switches().sum() == switches.sum() and not as_recorded.dones.any()
    # relabelled (the default): the switch keeps its goal, and the env's reward of it says the policy is still there
    model = POLA("MlpPolicy", dataset=data, hindsight_goals=False, **light_kwargs())
    assert POLA("MlpPolicy", dataset=data, **light_kwargs()).goal_switches == "relabel"
    relabelled = model.offline_data
    assert not relabelled.goal_switches().any() and not relabelled.dones.any()
    np.testing.assert_array_equal(relabelled.next_observations[switches, goal], data.observations[switches, goal])
    np.testing.assert_array_equal(relabelled.rewards[~switches], data.rewards[~switches])
    assert relabelled.rewards[switches].mean() > 0.9 > data.rewards[switches].mean()
    with pytest.raises(ValueError, match="goal_switches"):
        POLA("MlpPolicy", dataset=data, goal_switches="hindsight", **light_kwargs())


def test_hindsight_goals_of_the_shipped_umaze(monkeypatch: pytest.MonkeyPatch, tmp_path: pathlib.Path) -> None:
    """``hindsight_goals``: every goal segment once more, its goal a point it reaches, rewarded by the env's rule."""
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(package_datasets_dir()))
    data = load_offline_dataset("pointmaze/umaze-v0", cache_dir=tmp_path)
    achieved, goal = slice(0, 2), slice(2, 4)  # the flattening order: achieved_goal, desired_goal, observation
    # goal switches relabelled only
    relabelled = POLA("MlpPolicy", dataset=data, hindsight_goals=False, **light_kwargs()).offline_data
    model = POLA("MlpPolicy", dataset=data, **{**light_kwargs(), "seed": 3})
    assert model.hindsight_goals  # the default
    both, n = model.offline_data, len(relabelled)
    assert len(both) == 2 * n and both.fingerprint != relabelled.fingerprint
    for name in ("observations", "actions", "rewards", "next_observations", "dones"):  # the first half as it was
        np.testing.assert_array_equal(getattr(both, name)[:n], getattr(relabelled, name)[:n])
    copy_obs, copy_next = both.observations[n:], both.next_observations[n:]
    np.testing.assert_array_equal(copy_obs[:, achieved], relabelled.observations[:, achieved])  # only goals change
    np.testing.assert_array_equal(copy_obs[:, 4:], relabelled.observations[:, 4:])
    np.testing.assert_array_equal(both.actions[n:], relabelled.actions)
    np.testing.assert_array_equal(copy_obs[:, goal], copy_next[:, goal])  # one goal a segment, never switched
    ends = np.flatnonzero(relabelled.episode_ends())
    np.testing.assert_array_equal(np.flatnonzero(both.episode_ends()[n:]), ends)  # the same segments
    starts = np.concatenate([[0], ends[:-1] + 1])
    for start, end in zip(starts[:20], ends[:20], strict=True):
        segment_goal = copy_obs[start, goal]
        assert (copy_obs[start : end + 1, goal] == segment_goal).all()
        # the goal is where the segment is after one of its steps, so that step is rewarded
        hits = np.all(copy_next[start : end + 1, achieved] == segment_goal, axis=1)
        assert hits.any() and both.rewards[n + start + np.flatnonzero(hits)].min() == 1.0
    # the env's rule: 1 within 0.45 of the goal, else 0
    distance = np.linalg.norm(copy_next[:, achieved] - copy_next[:, goal], axis=1)
    np.testing.assert_array_equal(both.rewards[n:], (distance <= 0.45).astype(np.float32))
    assert both.rewards[n:].sum() > 5 * relabelled.rewards.sum()  # a copy lingers near its goal, the data's never
    # the critic trains on both halves, the actor on the data's rows only
    critic_rows: list[np.ndarray] = []
    actor_rows: list[np.ndarray] = []
    critic_loss, actor_loss = model._critic_loss_fn, model._bc_loss_fn
    model._critic_loss_fn = lambda obs, *a: critic_rows.append(obs.numpy().copy()) or critic_loss(obs, *a)  # type: ignore[method-assign]
    model._bc_loss_fn = lambda obs, *a: actor_rows.append(obs.numpy().copy()) or actor_loss(obs, *a)  # type: ignore[method-assign]
    model.learn(20)
    data_rows = {row.tobytes() for row in both.observations[:n]}
    copy_rows = {row.tobytes() for row in both.observations[n:]} - data_rows
    seen_by_actor = [row.tobytes() for batch in actor_rows for row in batch]
    seen_by_critic = [row.tobytes() for batch in critic_rows for row in batch]
    assert len(seen_by_actor) == 20 * model.batch_size and all(row in data_rows for row in seen_by_actor)
    assert sum(row in copy_rows for row in seen_by_critic) > 0.3 * len(seen_by_critic)
    # the dynamics model fits the data's rows: the copies show the same motion under other goals
    assert len(model._dynamics_arrays()[0]) == n
    other = POLA("MlpPolicy", dataset=data, hindsight_goals=True, **{**light_kwargs(), "seed": 4}).offline_data
    assert not np.array_equal(other.observations[n:, goal], copy_obs[:, goal])  # the seed draws the steps
    # no desired_goal, no copy
    flat = synthetic_dataset(50, 3, 2, seed=0)
    assert flat.with_hindsight_goals(lambda a, g: np.zeros(len(a))) is flat


def test_hindsight_goals_need_the_envs_reward_of_goals(goal_dataset: str) -> None:
    """A goal env without ``compute_reward`` cannot relabel: the default says so and trains on the data alone."""
    with pytest.warns(UserWarning, match="compute_reward"):
        data = POLA("MlpPolicy", dataset=goal_dataset, **light_kwargs()).offline_data
    assert len(data) == len(load_offline_dataset(goal_dataset))


def test_no_goal_switches_without_a_desired_goal() -> None:
    data = synthetic_dataset(50, 3, 2, seed=0)
    assert not data.goal_switches().any()
    np.testing.assert_array_equal(data.with_goal_switches("terminal").dones, data.dones)


@pytest.mark.parametrize("fixed", [True, False])
def test_lookahead_keeps_the_desired_goal(goal_dataset: str, fixed: bool) -> None:
    """``lookahead_fixed_goal`` (default): the states the actor sees in the look-ahead keep the batch's desired_goal,
    whatever the dynamics model predicts for it; ``False``: the model's prediction, as for every other column."""
    model = POLA("MlpPolicy", dataset=goal_dataset, lookahead_fixed_goal=fixed, **light_kwargs())
    assert POLA("MlpPolicy", dataset=goal_dataset, **light_kwargs()).lookahead_fixed_goal  # the default
    model.learn(1)
    goal = slice(1, 2)  # achieved_goal (1 column), desired_goal (1), observation (3): the flattening order
    assert (model._goal_mask is not None) == fixed
    assert not fixed or model._goal_mask.nonzero().flatten().tolist() == [1]  # type: ignore[union-attr]
    assert model.policy.dynamics is not None
    model.policy.dynamics.step = lambda s, a: (s + 1.0, s[:, 0], th.zeros(len(s)), th.zeros(len(s)))  # type: ignore[method-assign]
    seen: list[th.Tensor] = []
    features = model.policy.actor_features

    def record(state: th.Tensor) -> th.Tensor:
        seen.append(state.detach().clone())
        return features(state)

    model.policy.actor_features = record  # type: ignore[method-assign]
    obs = th.as_tensor(model.offline_data.observations[:8], dtype=th.float32)
    model._lookahead_q_loss(obs, features(obs))
    assert len(seen) == model.rollout_length  # the look-ahead's states s_{t+1}, ..., s_{t+T}
    for i, state in enumerate(seen, start=1):
        np.testing.assert_allclose(state[:, goal], obs[:, goal] + (0.0 if fixed else i))
        others = [0, 2, 3, 4]
        np.testing.assert_allclose(state[:, others], obs[:, others] + i)
