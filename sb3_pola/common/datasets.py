"""Offline datasets: Minari datasets turned into flat float32 transition arrays.

``load_offline_dataset`` accepts a Minari dataset id, a local dataset folder or a
``minari.MinariDataset`` and returns an :class:`OfflineDataset`. Transitions are built from each
episode's own observations (``next_obs[t] = obs[t + 1]`` of the same episode), ``dones`` are
terminations only (a time-limit truncation is not terminal) and actions are rescaled to [-1, 1].
Dict observations (``Dict`` of ``Box``) are flattened in the space's key order (see
:mod:`sb3_pola.common.dict_obs`); the dataset keeps the original space, and ``make_env`` flattens the
env's observations the same way.

Reading a Minari dataset goes episode by episode, so the concatenated arrays are cached on disk
(one folder of ``.npy`` files per dataset, keyed by the dataset id, its size and a fingerprint of its files and
metadata, so a changed dataset never gets stale arrays).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import pathlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeAlias

import gymnasium as gym
import numpy as np
from stable_baselines3.common.monitor import Monitor

from sb3_pola.common.dataset_cache import (
    ARRAY_FIELDS,
    cache_path,
    fingerprint,
    load_cache,
    read_digest_index,
    save_cache,
    write_digest_index,
)
from sb3_pola.common.dataset_paths import (
    DatasetCorruptError,
    DatasetError,
    DatasetLocation,
    SpaceMismatchError,
    corrupt_dataset_message,
    metadata_env_id,
    metadata_spaces,
    read_metadata,
    resolve_dataset_path,
)
from sb3_pola.common.dataset_paths import DatasetNotFoundError as DatasetNotFoundError  # the public API's errors
from sb3_pola.common.dataset_paths import list_local_datasets as list_local_datasets
from sb3_pola.common.dict_obs import check_dict_space, flat_space, flatten_env, flatten_episode_observations, key_slice
from sb3_pola.common.extras import import_gymnasium_robotics
from sb3_pola.common.metrics import normalized_score

if TYPE_CHECKING:
    pass


# D4RL's dataset kinds, as `sb3-pola collect` makes them (``<env>/<kind>-v<version>``)
D4RL_KINDS = ("random", "medium", "expert", "medium-replay", "medium-expert")
# Rows per chunk when computing statistics, so no full-size float64 temporary is made.
_STATS_CHUNK = 65536


def default_cache_dir() -> pathlib.Path:
    """Cache root: ``$SB3_POLA_CACHE_DIR``, else ``$XDG_CACHE_HOME/sb3_pola``, else ``~/.cache/sb3_pola``."""
    if os.environ.get("SB3_POLA_CACHE_DIR"):
        return pathlib.Path(os.environ["SB3_POLA_CACHE_DIR"])
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (pathlib.Path(xdg) if xdg else pathlib.Path.home() / ".cache") / "sb3_pola"


GoalRewardFn: TypeAlias = "Callable[[np.ndarray, np.ndarray], np.ndarray]"


def best_episodes(returns: np.ndarray, fraction: float) -> np.ndarray:
    """Indices of the best ``fraction`` of the episodes by return, in the file's order (at least one; ties keep the
    file's order): filtered BC's episodes (the Decision Transformer paper's %BC).

    :param returns: ``[n_episodes]`` each episode's return
    :param fraction: share of the episodes kept, in (0, 1]
    """
    if not 0 < fraction <= 1:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    n_kept = max(1, math.ceil(fraction * len(returns)))
    return np.sort(np.argsort(-np.asarray(returns), kind="stable")[:n_kept])  # best first, then the file's order


@dataclass
class OfflineDataset:
    """Flat transitions of an offline dataset.

    :param observations: ``[N, obs_dim]`` float32
    :param actions: ``[N, act_dim]`` float32, rescaled to [-1, 1] from ``action_space`` bounds
    :param rewards: ``[N]`` float32
    :param next_observations: ``[N, obs_dim]`` float32, next observation of the same episode
    :param dones: ``[N]`` float32, 1 on terminations only (truncations are not terminal)
    :param observation_space: the dataset's observation space (flattened, for Dict observations)
    :param action_space: the dataset's original (unscaled) action space
    :param dataset_id: Minari id, if known
    :param env_id: Gymnasium id of the environment, from the dataset's ``env_spec``
    :param ref_min_score: random-policy return, for normalised scores
    :param ref_max_score: expert-policy return, for normalised scores
    :param episode_returns: ``[n_episodes]`` float64, undiscounted return of each episode
    :param metadata: raw Minari metadata (``env_spec`` JSON etc.)
    :param dict_observation_space: the original ``Dict`` observation space, if the dataset's observations
        are dicts (the arrays hold them flattened in its key order)
    :param fingerprint: hash of the dataset's content (its files' bytes and metadata), if it was read from files
    """

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    next_observations: np.ndarray
    dones: np.ndarray
    observation_space: gym.spaces.Box
    action_space: gym.spaces.Box
    dataset_id: str | None = None
    env_id: str | None = None
    ref_min_score: float | None = None
    ref_max_score: float | None = None
    episode_returns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.float64))
    metadata: dict[str, Any] = field(default_factory=dict, repr=False)
    dict_observation_space: gym.spaces.Dict | None = None
    fingerprint: str | None = None

    def __len__(self) -> int:
        return int(self.observations.shape[0])

    @property
    def nbytes(self) -> int:
        """Bytes held by the transition arrays."""
        return sum(int(getattr(self, name).nbytes) for name in ARRAY_FIELDS)

    def obs_stats(self, eps: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
        """Mean and standard deviation of the observations (float64 accumulation, chunked).

        :param eps: floor of the standard deviation (constant features would divide by zero)
        :return: ``(mean, std)`` as float32 arrays of shape ``[obs_dim]``
        """
        obs = self.observations
        n = max(len(obs), 1)
        total = np.zeros(obs.shape[1:], dtype=np.float64)
        for start in range(0, len(obs), _STATS_CHUNK):
            total += obs[start : start + _STATS_CHUNK].sum(axis=0, dtype=np.float64)
        mean = total / n
        sq = np.zeros_like(mean)
        for start in range(0, len(obs), _STATS_CHUNK):
            diff = obs[start : start + _STATS_CHUNK].astype(np.float64) - mean
            sq += (diff * diff).sum(axis=0)
        std = np.maximum(np.sqrt(sq / n), eps)
        return mean.astype(np.float32), std.astype(np.float32)

    def episode_ends(self) -> np.ndarray:
        """``[N]`` bool, True at the last transition of each episode: a termination, or where the next transition
        does not start at this one's next observation (a truncation, or the end of the arrays)."""
        ends = self.dones.astype(bool).copy()
        if len(self):
            ends[:-1] |= np.any(self.next_observations[:-1] != self.observations[1:], axis=1)
            ends[-1] = True
        return ends

    def best_episode_rows(self, fraction: float) -> np.ndarray:
        """``[M]`` int64 rows of the best ``fraction`` of the episodes by undiscounted return (at least one episode;
        ties keep the file's order), in the file's order: filtered BC's data (the Decision Transformer paper's %BC).

        :param fraction: share of the episodes kept, in (0, 1]
        """
        ends = np.flatnonzero(self.episode_ends())
        starts = np.concatenate([[0], ends[:-1] + 1])
        returns = np.add.reduceat(self.rewards.astype(np.float64), starts) if len(self) else np.zeros(0)
        kept = best_episodes(returns, fraction)
        return np.concatenate([np.arange(starts[i], ends[i] + 1) for i in kept]).astype(np.int64)

    def goal_switches(self) -> np.ndarray:
        """``[N]`` bool, True where the ``desired_goal`` of a goal-conditioned dataset changes between a transition's
        observation and its next one: the collector drew a new goal once the old one was reached (Minari's and D4RL's
        mazes), a switch of task that no action caused. All False without a ``desired_goal``."""
        space = self.dict_observation_space
        if space is None or "desired_goal" not in space.spaces:
            return np.zeros(len(self), dtype=bool)
        goal = key_slice(space, "desired_goal")
        return np.any(self.observations[:, goal] != self.next_observations[:, goal], axis=1)

    def with_goal_switches(self, mode: str, reward_fn: GoalRewardFn | None = None) -> OfflineDataset:
        """A copy in which no value is bootstrapped across a :meth:`goal_switches` transition.

        :param mode: ``"terminal"``: ``dones`` 1 there, each goal an episode of its own that ends when it is reached.
            ``"relabel"`` (hindsight relabelling, as HER): the transition keeps its own goal in the next observation
            and its reward is ``reward_fn(next achieved_goal, desired_goal)``, so the step after reaching a goal
            shows what staying there is worth, the one thing the mazes' data never show
        :param reward_fn: the env's reward of goals, batched (``GoalEnv.compute_reward`` without ``info``), for
            ``"relabel"``
        """
        if mode not in ("terminal", "relabel"):
            raise ValueError(f"mode must be 'terminal' or 'relabel', got {mode!r}")
        switches = self.goal_switches()
        if not switches.any():
            return self
        tag = f"+goal-switches-{mode}"
        keep = self.fingerprint is None or self.fingerprint.endswith(tag)
        fingerprint = self.fingerprint if keep else f"{self.fingerprint}{tag}"
        if mode == "terminal":
            dones = np.maximum(self.dones, switches.astype(self.dones.dtype))
            return dataclasses.replace(self, dones=dones, fingerprint=fingerprint)
        if reward_fn is None:
            raise ValueError("relabelling goal switches needs the env's reward of goals (reward_fn)")
        assert self.dict_observation_space is not None
        goal = key_slice(self.dict_observation_space, "desired_goal")
        achieved = key_slice(self.dict_observation_space, "achieved_goal")
        next_obs, rewards = self.next_observations.copy(), self.rewards.copy()
        next_obs[switches, goal] = self.observations[switches, goal]
        relabelled = reward_fn(next_obs[switches, achieved], next_obs[switches, goal])
        rewards[switches] = np.asarray(relabelled, dtype=rewards.dtype).reshape(-1)
        return dataclasses.replace(self, next_observations=next_obs, rewards=rewards, fingerprint=fingerprint)

    def with_hindsight_goals(self, reward_fn: GoalRewardFn, seed: int = 0) -> OfflineDataset:
        """A copy with every goal segment (the transitions of an episode between two :meth:`episode_ends`) appended
        once more, its ``desired_goal`` replaced by the ``achieved_goal`` it reaches at a step drawn uniformly in it
        and its rewards ``reward_fn(next achieved_goal, that goal)`` (hindsight relabelling, HER's "episode"
        strategy). The copy passes through its goal and goes on: the critic sees what leaving a goal costs, at
        speeds and places the collectors' own goals never show. Unchanged without a ``desired_goal``.

        :param reward_fn: the env's reward of goals, batched (``GoalEnv.compute_reward`` without ``info``)
        :param seed: seed of the relabelled steps
        """
        space = self.dict_observation_space
        if space is None or "desired_goal" not in space.spaces or not len(self):
            return self
        goal, achieved = key_slice(space, "desired_goal"), key_slice(space, "achieved_goal")
        ends = np.flatnonzero(self.episode_ends())
        starts = np.concatenate([[0], ends[:-1] + 1])
        rng = np.random.default_rng(seed)
        # each segment's goal: where it is after its relabelled step  [n_segments, goal_dim]
        steps = starts + (rng.random(len(starts)) * (ends - starts + 1)).astype(np.int64)
        goals = np.repeat(self.next_observations[steps, achieved], ends - starts + 1, axis=0)  # [N, goal_dim]
        obs, next_obs = self.observations.copy(), self.next_observations.copy()
        obs[:, goal] = goals
        next_obs[:, goal] = goals
        rewards = np.asarray(reward_fn(next_obs[:, achieved], goals), dtype=self.rewards.dtype).reshape(-1)
        tag = "+hindsight-goals"
        return dataclasses.replace(
            self,
            observations=np.concatenate([self.observations, obs]),
            actions=np.concatenate([self.actions, self.actions]),
            rewards=np.concatenate([self.rewards, rewards]),
            next_observations=np.concatenate([self.next_observations, next_obs]),
            dones=np.concatenate([self.dones, self.dones]),
            fingerprint=None if self.fingerprint is None else f"{self.fingerprint}{tag}{seed}",
        )

    def returns_to_go(self, gamma: float) -> np.ndarray:
        """``[N]`` float64 discounted return from each transition to its episode's end, ``sum_k gamma^k r_{t+k}``.

        A truncated episode's last states count no reward after the cut, so they read low; for a dataset-wide
        value scale the mean over all transitions is what counts.

        :param gamma: discount factor
        """
        rewards = self.rewards.astype(np.float64)
        ends = self.episode_ends()
        out = np.empty_like(rewards)
        running = 0.0
        for i in range(len(rewards) - 1, -1, -1):
            running = rewards[i] + (0.0 if ends[i] else gamma * running)
            out[i] = running
        return out

    def normalized_score(self, returns: float | Sequence[float] | np.ndarray) -> float | None:
        """Normalised score (D4RL, x100) of the mean of ``returns`` with this dataset's reference scores.

        :param returns: episode return(s)
        :return: the score, or None (warned once) when the dataset has no reference scores
        """
        return normalized_score(returns, self.ref_min_score, self.ref_max_score, source=f"Dataset {self.dataset_id!r}")

    def unscale_action(self, scaled_action: np.ndarray) -> np.ndarray:
        """Map [-1, 1] actions back to the env's bounds."""
        low, high = self.action_space.low, self.action_space.high
        return low + 0.5 * (np.asarray(scaled_action) + 1.0) * (high - low)


# --------------------------------------------------------------------------- reading episodes


def _check_spaces(observation_space: gym.Space, action_space: gym.Space, where: str) -> None:
    if not isinstance(action_space, gym.spaces.Box):
        raise DatasetError(
            f"{where} has action space {action_space}: POLA needs continuous (Box) actions, "
            "discrete action spaces are not supported"
        )
    if isinstance(observation_space, gym.spaces.Dict):
        try:
            check_dict_space(observation_space, where)
        except ValueError as error:
            raise DatasetError(str(error)) from None
    elif not isinstance(observation_space, gym.spaces.Box) or len(observation_space.shape) != 1:
        raise DatasetError(f"{where} has observation space {observation_space}: a flat Box (or a Dict of Boxes) is needed")
    if len(action_space.shape) != 1:
        raise DatasetError(f"{where} has action space {action_space}: a flat Box is needed")
    if not (np.all(np.isfinite(action_space.low)) and np.all(np.isfinite(action_space.high))):
        raise DatasetError(f"{where} has unbounded actions {action_space}: they cannot be rescaled to [-1, 1]")


def _build_arrays(
    episodes: Iterable[dict[str, Any]],
    n_steps: int,
    n_episodes: int,
    obs_dim: int,
    act_dim: int,
    action_space: gym.spaces.Box,
    where: str,
    progress: bool,
    dict_space: gym.spaces.Dict | None = None,
) -> dict[str, np.ndarray]:
    """Concatenate episodes into preallocated arrays (no list of per-episode copies); dict observations flattened."""
    obs = np.empty((n_steps, obs_dim), dtype=np.float32)
    next_obs = np.empty((n_steps, obs_dim), dtype=np.float32)
    actions = np.empty((n_steps, act_dim), dtype=np.float32)
    rewards = np.empty(n_steps, dtype=np.float32)
    dones = np.empty(n_steps, dtype=np.float32)
    returns = np.empty(n_episodes, dtype=np.float64)
    low = action_space.low.astype(np.float64)
    span = action_space.high.astype(np.float64) - low
    bad = {"observations": 0, "actions": 0, "rewards": 0}
    pos = 0
    n_seen = 0
    if progress:
        with contextlib.suppress(ImportError):
            from tqdm.auto import tqdm

            episodes = tqdm(episodes, total=n_episodes, desc=f"reading {where}", unit="ep", leave=False)
    for episode in episodes:
        ep_act = np.asarray(episode["actions"], dtype=np.float64).reshape(-1, act_dim)
        ep_rew = np.asarray(episode["rewards"], dtype=np.float64).reshape(-1)
        length = len(ep_rew)
        if dict_space is not None:
            ep_obs = flatten_episode_observations(dict_space, episode["observations"], length + 1)
        else:
            ep_obs = np.asarray(episode["observations"]).reshape(-1, obs_dim)
        if len(ep_obs) != length + 1 or len(ep_act) != length:
            raise DatasetError(
                f"{where}: episode {n_seen} has {len(ep_obs)} observations, {len(ep_act)} actions and "
                f"{length} rewards (expected T+1, T, T)"
            )
        if pos + length > n_steps or n_seen >= n_episodes:
            raise DatasetError(f"{where}: more data than its metadata says ({n_steps} steps, {n_episodes} episodes)")
        bad["observations"] += int(ep_obs.size - np.count_nonzero(np.isfinite(ep_obs)))
        bad["actions"] += int(ep_act.size - np.count_nonzero(np.isfinite(ep_act)))
        bad["rewards"] += int(ep_rew.size - np.count_nonzero(np.isfinite(ep_rew)))
        end = pos + length
        obs[pos:end] = ep_obs[:-1]
        next_obs[pos:end] = ep_obs[1:]
        actions[pos:end] = np.clip(2.0 * (ep_act - low) / span - 1.0, -1.0, 1.0)
        rewards[pos:end] = ep_rew
        dones[pos:end] = np.asarray(episode["terminations"], dtype=bool).reshape(-1)
        returns[n_seen] = ep_rew.sum()
        pos = end
        n_seen += 1
    if pos != n_steps or n_seen != n_episodes:
        raise DatasetError(
            f"{where}: read {pos} steps in {n_seen} episodes, its metadata says {n_steps} steps in {n_episodes} episodes"
        )
    bad_fields = {name: count for name, count in bad.items() if count}
    if bad_fields:
        details = ", ".join(f"{name}: {count} values" for name, count in bad_fields.items())
        raise DatasetError(f"{where} has non-finite (NaN or inf) entries: {details}")
    return {
        "observations": obs,
        "actions": actions,
        "rewards": rewards,
        "next_observations": next_obs,
        "dones": dones,
        "episode_returns": returns,
    }


def same_spaces(dataset_space: gym.Space, env_space: gym.Space, bounds: bool) -> bool:
    """Whether two Box (or Dict of Box) spaces have the same shapes (and keys), and with ``bounds`` the same bounds."""
    if isinstance(dataset_space, gym.spaces.Dict):  # the env's own dict observations: same keys and shapes
        return (
            isinstance(env_space, gym.spaces.Dict)
            and list(env_space.spaces) == list(dataset_space.spaces)
            and all(same_spaces(sub, env_space.spaces[k], bounds) for k, sub in dataset_space.spaces.items())
        )
    if (
        not isinstance(dataset_space, gym.spaces.Box)
        or not isinstance(env_space, gym.spaces.Box)
        or env_space.shape != dataset_space.shape
    ):
        return False
    if not bounds:
        return True
    return bool(np.allclose(env_space.low, dataset_space.low) and np.allclose(env_space.high, dataset_space.high))


def load_offline_dataset(
    dataset: DatasetLocation,
    *,
    env: gym.Env | None = None,
    download: bool = False,
    use_cache: bool = True,
    cache_dir: str | os.PathLike | None = None,
    progress: bool = False,
) -> OfflineDataset:
    """Load a Minari dataset as flat float32 transitions.

    :param dataset: a Minari id (looked up in ``$MINARI_DATASETS_PATH`` or ``~/.minari/datasets``,
        then among the package's shipped datasets), a local dataset folder (containing ``data/``, or
        ``data/`` itself) or a ``minari.MinariDataset``
    :param env: if given, the dataset's spaces must match its spaces
    :param download: download a missing id with ``minari.download_dataset``
    :param use_cache: read/write the on-disk cache of the concatenated arrays
    :param cache_dir: cache folder (default ``$SB3_POLA_CACHE_DIR`` or ``~/.cache/sb3_pola``)
    :param progress: show a progress bar while reading episodes
    :return: the dataset
    """
    data_dir = resolve_dataset_path(dataset, download=download)
    try:
        metadata = read_metadata(data_dir)
    except (OSError, ValueError) as error:
        raise DatasetCorruptError(corrupt_dataset_message(data_dir, str(dataset), {}, error)) from error
    dataset_id = metadata.get("dataset_id") or (dataset if isinstance(dataset, str) else None)
    where = f"dataset {dataset_id!r} ({data_dir})"
    try:
        observation_space, action_space = metadata_spaces(metadata, data_dir)
    except (OSError, KeyError, RuntimeError) as error:
        raise DatasetCorruptError(corrupt_dataset_message(data_dir, dataset_id, metadata, error)) from error
    _check_spaces(observation_space, action_space, where)
    dict_space = observation_space if isinstance(observation_space, gym.spaces.Dict) else None
    if dict_space is not None:
        observation_space = flat_space(dict_space)
    assert isinstance(observation_space, gym.spaces.Box) and isinstance(action_space, gym.spaces.Box)
    if env is not None:
        dataset_obs_space = (
            dict_space if dict_space is not None and isinstance(env.observation_space, gym.spaces.Dict) else observation_space
        )
        obs_ok = same_spaces(dataset_obs_space, env.observation_space, bounds=False)
        act_ok = same_spaces(action_space, env.action_space, bounds=True)
        if not (obs_ok and act_ok):
            raise SpaceMismatchError(
                f"{where} does not match the env: dataset observation space {dict_space or observation_space} vs env "
                f"{env.observation_space}; dataset action space {action_space} vs env {env.action_space}"
            )
    n_steps = int(metadata.get("total_steps", 0))
    n_episodes = int(metadata.get("total_episodes", 0))
    if n_steps <= 0 or n_episodes <= 0:
        raise DatasetError(f"{where} is empty ({n_steps} steps, {n_episodes} episodes)")
    obs_dim, act_dim = int(observation_space.shape[0]), int(action_space.shape[0])

    arrays = None
    cache_file = None
    root = pathlib.Path(cache_dir) if cache_dir is not None else default_cache_dir()
    content_key, digests = fingerprint(data_dir, metadata, read_digest_index(root) if use_cache else None)
    if use_cache:
        cache_file = cache_path(root, dataset_id, n_steps, content_key)
        arrays = load_cache(cache_file, n_steps, obs_dim, act_dim)
        if arrays is not None and len(arrays["episode_returns"]) != n_episodes:
            arrays = None
    if arrays is None:
        arrays = _read_arrays(
            data_dir, dataset_id, metadata, (n_steps, n_episodes, obs_dim, act_dim), action_space, where, progress, dict_space
        )
        if cache_file is not None:  # only arrays read whole and checked are cached
            save_cache(
                cache_file, arrays, {"dataset_id": dataset_id, "source": str(data_dir.resolve()), "fingerprint": content_key}
            )
    if use_cache:
        write_digest_index(root, digests)

    ref_min, ref_max = metadata.get("ref_min_score"), metadata.get("ref_max_score")
    return OfflineDataset(
        observations=arrays["observations"],
        actions=arrays["actions"],
        rewards=arrays["rewards"],
        next_observations=arrays["next_observations"],
        dones=arrays["dones"],
        observation_space=observation_space,
        action_space=action_space,
        dataset_id=dataset_id,
        env_id=metadata_env_id(metadata),
        ref_min_score=None if ref_min is None else float(ref_min),
        ref_max_score=None if ref_max is None else float(ref_max),
        episode_returns=arrays["episode_returns"],
        metadata=metadata,
        dict_observation_space=dict_space,
        fingerprint=content_key,
    )


def _read_arrays(
    data_dir: pathlib.Path,
    dataset_id: str | None,
    metadata: dict[str, Any],
    sizes: tuple[int, int, int, int],
    action_space: gym.spaces.Box,
    where: str,
    progress: bool,
    dict_space: gym.spaces.Dict | None,
) -> dict[str, np.ndarray]:
    """Every episode of the dataset's files into flat arrays (:func:`_build_arrays`); a file that cannot be read
    raises :class:`DatasetCorruptError` naming it and the fix."""
    from minari.dataset.minari_storage import MinariStorage

    n_steps, n_episodes, obs_dim, act_dim = sizes
    try:
        storage = MinariStorage.read(data_dir)
        episodes = storage.get_episodes(range(n_episodes))
        return _build_arrays(episodes, n_steps, n_episodes, obs_dim, act_dim, action_space, where, progress, dict_space)
    except DatasetError:
        raise
    except (OSError, KeyError, ValueError, RuntimeError, TypeError, IndexError) as error:  # h5py's, on a damaged file
        raise DatasetCorruptError(corrupt_dataset_message(data_dir, dataset_id, metadata, error)) from error


def make_env(
    dataset: OfflineDataset | str | os.PathLike, eval_env: bool = True, monitor: bool = True, **env_kwargs: Any
) -> gym.Env:
    """The environment to evaluate a policy of the dataset in, from its Minari env spec (with its time limit).

    Minari datasets may record an ``eval_env_spec`` next to the ``env_spec`` they were collected in (the
    maze datasets: a fixed goal, as D4RL evaluates); it is preferred, as ``recover_environment(eval_env=True)``
    does. Dict observations come flattened, in the order of the dataset's arrays (``FlattenObservation``).

    :param dataset: a loaded dataset, or a Minari id / dataset folder
    :param eval_env: prefer the ``eval_env_spec``; ``False``: the env the data was collected in
    :param monitor: wrap it in SB3's ``Monitor`` (episode returns and lengths), so that SB3's evaluation of it warns
        of nothing
    :param env_kwargs: extra arguments for ``gym.make`` (e.g. ``render_mode``)
    :return: a new environment
    """

    def finish(env: gym.Env) -> gym.Env:
        env = flatten_env(env)
        return Monitor(env) if monitor else env

    if isinstance(dataset, OfflineDataset):
        metadata = dataset.metadata
        if not metadata.get("env_spec") and dataset.env_id is not None:
            return finish(gym.make(dataset.env_id, **env_kwargs))
    else:
        metadata = read_metadata(resolve_dataset_path(dataset))
    if eval_env and metadata.get("eval_env_spec"):
        metadata = {**metadata, "env_spec": metadata["eval_env_spec"]}
    spec_str = metadata.get("env_spec")
    if not spec_str:
        raise DatasetError(f"Dataset {metadata.get('dataset_id')!r} records no environment (env_spec)")
    from gymnasium.envs.registration import EnvSpec

    # Keys older gymnasium versions wrote that EnvSpec no longer takes (as minari does).
    spec_str = (
        spec_str.replace('"order_enforce": true,', "")
        .replace('"apply_api_compatibility": false,', "")
        .replace('"autoreset": false, ', "")
    )
    spec = EnvSpec.from_json(spec_str)
    if isinstance(spec.entry_point, str) and spec.entry_point.startswith("gymnasium_robotics"):
        import_gymnasium_robotics()  # imported here, quietly, rather than by gym.make
    return finish(gym.make(spec, **env_kwargs))


def synthetic_dataset(n: int, obs_dim: int, act_dim: int, env_id: str | None = None, seed: int = 0) -> OfflineDataset:
    """An in-memory :class:`OfflineDataset` of ``n`` random transitions (no files, no downloads): for smoke tests and
    benchmarks, where only the shapes matter.

    :param n: number of transitions
    :param obs_dim: observation size
    :param act_dim: action size
    :param env_id: environment id recorded in the dataset (selects the termination rule)
    :param seed: seed of the arrays
    :return: the dataset
    """
    rng = np.random.default_rng(seed)
    obs = rng.standard_normal((n, obs_dim), dtype=np.float32)
    return OfflineDataset(
        observations=obs,
        actions=rng.uniform(-1.0, 1.0, (n, act_dim)).astype(np.float32),
        rewards=rng.standard_normal(n, dtype=np.float32),
        next_observations=obs + 0.01 * rng.standard_normal((n, obs_dim), dtype=np.float32),
        dones=(rng.random(n) < 0.001).astype(np.float32),
        observation_space=gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32),
        action_space=gym.spaces.Box(-1.0, 1.0, (act_dim,), np.float32),
        dataset_id="synthetic",
        env_id=env_id,
    )
