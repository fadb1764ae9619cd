"""Test helpers: small Minari datasets (hand-made episodes, or recorded from real Gymnasium envs) and light models."""

from __future__ import annotations

import json
import os
import pathlib
import warnings

import gymnasium as gym
import numpy as np

OBS_DIM = 3
ACT_DIM = 2
ACT_LOW = np.array([-2.0, 0.0], dtype=np.float32)
ACT_HIGH = np.array([2.0, 4.0], dtype=np.float32)
# (length, terminated): the last episode is cut by truncation
EPISODES = [(5, True), (7, False), (4, True), (6, False)]


def make_episodes(episodes: list[tuple[int, bool]] = EPISODES, seed: int = 0, discrete: bool = False) -> list:
    """Episode buffers whose observations encode (episode, step) so boundaries can be checked."""
    from minari.data_collector import EpisodeBuffer

    rng = np.random.default_rng(seed)
    buffers = []
    for ep, (length, terminated) in enumerate(episodes):
        obs = np.zeros((length + 1, OBS_DIM))
        obs[:, 0] = ep
        obs[:, 1] = np.arange(length + 1)
        obs[:, 2] = rng.normal(size=length + 1)
        if discrete:
            actions = rng.integers(0, 3, size=length)
        else:
            actions = rng.uniform(ACT_LOW, ACT_HIGH, size=(length, ACT_DIM)).astype(np.float32)
        terminations = np.zeros(length, dtype=bool)
        truncations = np.zeros(length, dtype=bool)
        (terminations if terminated else truncations)[-1] = True
        buffers.append(
            EpisodeBuffer(
                id=ep,
                observations=obs,
                actions=actions,
                rewards=rng.normal(size=length),
                terminations=terminations,
                truncations=truncations,
            )
        )
    return buffers


def write_minari_dataset(
    root: pathlib.Path,
    dataset_id: str,
    buffers: list,
    ref_scores: bool = True,
    discrete: bool = False,
) -> pathlib.Path:
    """Write a Minari dataset under ``root`` with create_dataset_from_buffers; returns its folder."""
    import minari

    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # minari's advice about missing author, env spec...
            minari.create_dataset_from_buffers(
                dataset_id=dataset_id,
                buffer=buffers,
                observation_space=gym.spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float64),
                action_space=gym.spaces.Discrete(3) if discrete else gym.spaces.Box(ACT_LOW, ACT_HIGH, dtype=np.float32),
                algorithm_name="test",
                data_format="hdf5",
            )
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old
    if ref_scores:
        # minari stores reference scores only when it knows the env; write them as it would
        metadata_file = root / dataset_id / "data" / "metadata.json"
        metadata = json.loads(metadata_file.read_text())
        metadata.update(ref_min_score=-10.0, ref_max_score=10.0)
        metadata_file.write_text(json.dumps(metadata))
    return root / dataset_id


class GoalPendulum(gym.Env):
    """Pendulum-v1 with goal-style Dict observations (``observation``, ``achieved_goal``, ``desired_goal``), as
    Minari's maze datasets have, for the Dict-observation tests (registered below as ``GoalPendulum-v0``)."""

    def __init__(self) -> None:
        self.pendulum = gym.make("Pendulum-v1").unwrapped
        box = gym.spaces.Box(-np.inf, np.inf, shape=(1,), dtype=np.float32)
        self.observation_space = gym.spaces.Dict(
            {"observation": self.pendulum.observation_space, "achieved_goal": box, "desired_goal": box}
        )
        self.action_space = self.pendulum.action_space

    def _dict(self, obs: np.ndarray) -> dict:
        return {"observation": obs, "achieved_goal": obs[:1].copy(), "desired_goal": np.ones(1, dtype=np.float32)}

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        obs, info = self.pendulum.reset(seed=seed)
        return self._dict(obs), info

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.pendulum.step(action)
        return self._dict(obs), float(reward), terminated, truncated, info


if "GoalPendulum-v0" not in gym.registry:
    gym.register("GoalPendulum-v0", entry_point="helpers:GoalPendulum", max_episode_steps=200)


def _stack(observations: list) -> np.ndarray | dict:
    if isinstance(observations[0], dict):
        return {key: np.array([o[key] for o in observations]) for key in observations[0]}
    return np.array(observations)


def record_random_dataset(
    root: pathlib.Path,
    dataset_id: str,
    env_id: str,
    n_steps: int,
    seed: int = 0,
    ref_scores: tuple[float, float] | None = None,
    max_episode_steps: int | None = None,
) -> pathlib.Path:
    """Roll out uniform random actions in ``env_id`` for ``n_steps`` and write a Minari dataset (with its env spec).

    ``ref_scores`` (min, max) are written into the metadata as Minari would for a known env.
    """
    import minari
    from minari.data_collector import EpisodeBuffer

    env = gym.make(env_id, max_episode_steps=max_episode_steps)
    env.action_space.seed(seed)
    buffers, steps, episode = [], 0, 0
    while steps < n_steps:
        obs, _ = env.reset(seed=seed + episode)
        observations, actions, rewards, terms, truncs = [obs], [], [], [], []
        done = False
        while not done:
            action = env.action_space.sample()
            obs, reward, terminated, truncated, _ = env.step(action)
            observations.append(obs)
            actions.append(action)
            rewards.append(reward)
            terms.append(terminated)
            truncs.append(truncated)
            steps += 1
            done = terminated or truncated or steps >= n_steps
        truncs[-1] = truncs[-1] or not terms[-1]
        buffers.append(
            EpisodeBuffer(
                id=episode,
                observations=_stack(observations),
                actions=np.array(actions),
                rewards=np.array(rewards),
                terminations=np.array(terms),
                truncations=np.array(truncs),
            )
        )
        episode += 1
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            minari.create_dataset_from_buffers(
                dataset_id=dataset_id, buffer=buffers, env=env, algorithm_name="random", data_format="hdf5"
            )
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old
    env.close()
    if ref_scores is not None:
        metadata_file = root / dataset_id / "data" / "metadata.json"
        metadata = json.loads(metadata_file.read_text())
        metadata.update(ref_min_score=ref_scores[0], ref_max_score=ref_scores[1])
        metadata_file.write_text(json.dumps(metadata))
    return root / dataset_id


def light_kwargs(**overrides) -> dict:
    """The tests' one light configuration: small enough for unit tests on a CPU, with every part of POLA (dynamics
    model, look-ahead, EMA). tests/soak.py builds on it; the main job's ``LIGHT_CONFIG`` (sb3_pola/cli/run.py) is a
    run's configuration (its numbers are quoted in docs/results.md), not a test's."""
    kwargs: dict = dict(
        n_critics=3,
        top_k=2,
        rollout_length=2,
        batch_size=32,
        ema_start=10,
        policy_kwargs=dict(net_arch=[32, 32]),
        dynamics_kwargs=dict(n_members=2, n_elites=1, hidden_dim=32, n_layers=2),
        dynamics_fit_kwargs=dict(max_epochs=1),
        seed=0,
        device="cpu",
    )
    kwargs.update(overrides)
    return kwargs


def model_on_dataset(data, seed: int = 0, **kwargs):
    """A POLA model on an in-memory dataset, ready for ``_update``: buffer set up, dynamics frozen as initialised."""
    from stable_baselines3.common.logger import configure

    from sb3_pola.pola import POLA

    model = POLA("MlpPolicy", dataset=data, seed=seed, device="cpu", **kwargs)
    model.set_logger(configure(None, [""]))
    if model.policy.dynamics is not None:
        model.policy.dynamics.freeze()
        model.policy.dynamics_fitted.fill_(True)
    return model


# ----------------------------------------------------------------------------- the score grid's tests

# the score grid's datasets (conftest's ``score_data``): 2 random episodes of Pendulum-v1 each, truncated at 30 steps
SCORE_DATASETS = ("test/pendulum-v0", "test/pendulum2-v0")
# ``sb3-pola score`` options of a tiny, fast grid (the budget, datasets, variants and seeds left to each test)
TINY_GRID = ["--batch-size", "8", "--net-arch", "8", "--n-critics", "2", "--dynamics-steps", "4"]
TINY_GRID += ["--dynamics-kwargs", '{"hidden_dim": 8, "n_layers": 1, "n_members": 2, "n_elites": 1}']
TINY_GRID += ["--preset", "cpu", "--no-compile", "--device", "cpu", "-v", "0"]


def comparable(rows: list) -> list[tuple]:
    """Score rows without their wall-clock time (str: a NaN success equals NaN)."""
    from sb3_pola.grid.rows import CSV_FIELDS

    return [tuple(str(r[k]) for k in CSV_FIELDS if k != "wall_s") for r in rows]


def same_models(expected: pathlib.Path, models: pathlib.Path) -> None:
    """The final models of ``models`` are those of ``expected``, bit for bit."""
    import torch as th

    from sb3_pola.pola import POLA

    names = sorted(p.name for p in expected.iterdir())
    assert sorted(p.name for p in models.iterdir()) == names
    for name in names:
        expected_state = POLA.load(expected / name, device="cpu").policy.state_dict()
        state = POLA.load(models / name, device="cpu").policy.state_dict()
        assert all(th.equal(state[key], value) for key, value in expected_state.items()), name
