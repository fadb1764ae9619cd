"""An SB3 base class for algorithms that learn from a fixed dataset instead of from rollouts."""

from __future__ import annotations

import io
import os
import pathlib
import sys
import time
import warnings
from collections import deque
from collections.abc import Iterable
from typing import Any, TypeVar

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common import utils
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, ConvertCallback, ProgressBarCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule

from sb3_pola.common.buffers import OfflineReplayBuffer
from sb3_pola.common.datasets import DatasetLocation, OfflineDataset, load_offline_dataset, make_env, same_spaces
from sb3_pola.common.dict_obs import flatten_env, flatten_observation
from sb3_pola.common.integrity import DivergenceError, validate_model_file
from sb3_pola.common.metrics import normalized_score
from sb3_pola.common.validation import check_float, check_float_or_schedule, check_int

SelfOfflineAlgorithm = TypeVar("SelfOfflineAlgorithm", bound="OfflineAlgorithm")


class OfflineProgressBarCallback(ProgressBarCallback):
    """SB3's progress bar counting gradient steps; works without an env.

    Drawn with ``tqdm.auto`` rather than SB3's rich bar, in the style of the dynamics fit's bar that precedes it (one
    style for the package), and with ``disable=None``: no bar, nor its cursor codes, when stderr is not a terminal
    (a log file).
    """

    pbar: Any

    def _on_training_start(self) -> None:
        # the bar opens at the first step, after the work before training (the dynamics fit, its own bar and summary)
        self.pbar = None
        self._total = self.locals["total_timesteps"] - self.model.num_timesteps

    def _on_step(self) -> bool:
        if self.pbar is None:
            from tqdm.auto import tqdm

            self.pbar = tqdm(total=self._total, desc="training", unit="step", disable=None)
        self.pbar.update(1)
        return True

    def _on_training_end(self) -> None:
        if self.pbar is not None:
            self.pbar.refresh()
            self.pbar.close()


def dataset_reference(dataset: DatasetLocation | OfflineDataset | None) -> str | None:
    """What is saved with a model to find its dataset again: a Minari id or a path (never the data itself)."""
    if dataset is None or isinstance(dataset, str):
        return dataset
    if isinstance(dataset, os.PathLike):
        return os.fspath(dataset)
    if isinstance(dataset, OfflineDataset):
        return dataset.dataset_id
    spec = getattr(dataset, "spec", None)
    return getattr(spec, "dataset_id", None)


class OfflineAlgorithm(OffPolicyAlgorithm):
    """Base for offline algorithms: data from a Minari dataset, ``learn`` counts gradient steps, no env interaction.

    The env is optional: it is only used by callbacks (evaluation) and to check spaces. When
    none is given it is made from the dataset's metadata where possible. ``num_timesteps``
    counts gradient steps, so callbacks' frequencies (``eval_freq``, ``save_freq``) are in
    gradient steps too.

    :param policy: policy class or alias
    :param env: env (or its id) used for evaluation callbacks; made from the dataset if ``None``
    :param dataset: a Minari dataset id, a path to a Minari dataset folder, a ``minari.MinariDataset``
        or an in-memory :class:`~sb3_pola.common.datasets.OfflineDataset`
    :param learning_rate: learning rate or schedule
    :param batch_size: minibatch size of each gradient step
    :param tau: Polyak coefficient of the target networks
    :param gamma: discount factor
    :param download: let Minari download a dataset id that is not found locally
    :param policy_kwargs: extra arguments of the policy
    :param tensorboard_log: tensorboard log folder
    :param verbose: 0 silent, 1 info, 2 debug
    :param seed: random seed
    :param device: ``"cpu"``, ``"cuda"`` or ``"auto"``
    :param supported_action_spaces: action spaces the algorithm supports
    :param check_finite_freq: gradient steps between two NaN/inf checks of the losses and parameters (one host
        sync each; also checked at every log dump and at the end of ``learn``); ``1`` finds the exact step of a
        divergence, ``0`` checks only at dumps and at the end
    """

    # the dataset as a buffer: built with the model when a dataset is given, at the first ``learn`` after a
    # ``load`` without one
    replay_buffer: OfflineReplayBuffer | None  # type: ignore[assignment]

    def __init__(
        self,
        policy: str | type[BasePolicy],
        env: GymEnv | str | None,
        dataset: DatasetLocation | OfflineDataset | None,
        learning_rate: float | Schedule,
        batch_size: int = 256,
        tau: float = 0.005,
        gamma: float = 0.99,
        download: bool = False,
        policy_kwargs: dict[str, Any] | None = None,
        tensorboard_log: str | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: str = "auto",
        supported_action_spaces: tuple[type[spaces.Space], ...] | None = (spaces.Box,),
        check_finite_freq: int = 100,
    ) -> None:
        # checked before the dataset is loaded: a bad value fails at once, not in learn after the dynamics fit
        check_float_or_schedule("learning_rate", learning_rate, low=0.0, low_open=True)
        check_int("batch_size", batch_size, low=1)
        check_float("tau", tau, low=0.0, high=1.0, low_open=True)
        check_float("gamma", gamma, low=0.0, high=1.0, low_open=True)
        check_int("check_finite_freq", check_finite_freq, low=0)
        data: OfflineDataset | None = None
        if isinstance(env, str):  # made here rather than by SB3, so that dict observations can be flattened
            env = gym.make(env)
        env_dict_space = env.observation_space if env is not None and isinstance(env.observation_space, spaces.Dict) else None
        if isinstance(dataset, OfflineDataset):
            data = dataset
        elif dataset is not None:
            # a VecEnv has the same spaces as its envs, which is all the check reads
            data = load_offline_dataset(dataset, env=env, download=download)  # type: ignore[arg-type]
            if env is None:
                env = self._env_from_dataset(data, verbose)
        if env is not None:
            env = flatten_env(env)
        super().__init__(
            policy,
            env,  # type: ignore[arg-type]
            learning_rate,
            buffer_size=0,
            learning_starts=0,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=1,
            gradient_steps=1,
            policy_kwargs=policy_kwargs,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            support_multi_env=True,
            seed=seed,
            sde_support=False,
            supported_action_spaces=supported_action_spaces,
        )
        self.download = download
        self.dataset = dataset_reference(dataset)
        # per-step training statistics (losses, Q-values, gradient norms), summed on the device until a dump
        self._stat_sums: dict[str, th.Tensor] = {}
        self._stat_count = 0
        self._offline_data = data
        # the original Dict space of dict observations (the networks see them flattened, see common.dict_obs)
        self.dict_observation_space: spaces.Dict | None = data.dict_observation_space if data is not None else None
        if self.dict_observation_space is None and env_dict_space is not None:
            self.dict_observation_space = env_dict_space
        self.check_finite_freq = check_finite_freq
        self._last_finite_step = 0
        self.env_id: str | None = None
        self.ref_min_score: float | None = None
        self.ref_max_score: float | None = None
        if data is not None:
            if getattr(self, "observation_space", None) is None:  # SB3 leaves it unset without an env
                self.observation_space = data.observation_space
                self.action_space = data.action_space
            self.env_id = data.env_id
            self.ref_min_score, self.ref_max_score = data.ref_min_score, data.ref_max_score
        if self.env_id is None and self.env is not None:
            spec = self.env.get_attr("spec")[0]
            self.env_id = getattr(spec, "id", None)
        if data is not None:
            self._setup_offline_data()

    @property
    def offline_data(self) -> OfflineDataset | None:
        """The dataset's arrays and metadata (``None`` for a model loaded without ``dataset=`` until it learns)."""
        return self._offline_data

    @staticmethod
    def _env_from_dataset(data: OfflineDataset, verbose: int) -> GymEnv | None:
        try:
            return make_env(data)
        except Exception as error:  # an env that cannot be built only disables env-based callbacks
            if verbose:
                warnings.warn(f"Training without an env: the dataset's env could not be made ({error}).")
            return None

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_offline_data", "_stat_sums", "_stat_count"]

    def save_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase) -> None:
        """Nothing to save: the replay buffer is the dataset, found again through ``self.dataset``."""
        warnings.warn("save_replay_buffer: an offline algorithm's buffer is its dataset; nothing was saved.")

    def load_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase, truncate_last_traj: bool = True) -> None:
        """Offline algorithms read their buffer from the dataset (see ``save_replay_buffer``)."""
        raise NotImplementedError("An offline algorithm's replay buffer is its dataset: pass `dataset=` instead.")

    def _setup_offline_data(self) -> OfflineReplayBuffer:
        """The replay buffer over the dataset, loaded now if the model was built without one (e.g. after ``load``)."""
        if self.replay_buffer is None:
            if self._offline_data is None:
                if self.dataset is None:
                    raise ValueError(
                        "This model has no dataset to learn from: pass `dataset=` to the constructor "
                        "or to `load(path, dataset=...)`."
                    )
                if isinstance(self.dataset, OfflineDataset):
                    self._offline_data = self.dataset
                else:
                    self._offline_data = load_offline_dataset(self.dataset, download=self.download)
                self.dataset = dataset_reference(self.dataset)
            self._offline_data = self._prepare_offline_data(self._offline_data)
            self._check_dataset_spaces(self._offline_data)
            self.replay_buffer = OfflineReplayBuffer(self._offline_data, device=self.device)
        return self.replay_buffer

    def _prepare_offline_data(self, data: OfflineDataset) -> OfflineDataset:
        """The dataset as this algorithm learns from it (a subclass may relabel it); the loaded one by default."""
        return data

    def _check_dataset_spaces(self, data: OfflineDataset) -> None:
        assert self.observation_space is not None and self.action_space is not None
        ours, theirs = self.dict_observation_space, data.dict_observation_space
        same_dict = ours is None and theirs is None
        if ours is not None and theirs is not None:
            same_dict = same_spaces(ours, theirs, bounds=False)
        if not same_dict:
            raise ValueError(
                f"The dataset's observation space {theirs or data.observation_space} does not match the model's "
                f"{ours or self.observation_space}"
            )
        if data.observation_space.shape != self.observation_space.shape or data.action_space.shape != self.action_space.shape:
            raise ValueError(
                f"The dataset's spaces (observation {data.observation_space}, action {data.action_space}) do not match "
                f"the model's (observation {self.observation_space}, action {self.action_space})."
            )

    def _init_callback(self, callback: MaybeCallback, progress_bar: bool = False) -> BaseCallback:
        if isinstance(callback, list):
            callback = CallbackList(callback)
        if not isinstance(callback, BaseCallback):
            callback = ConvertCallback(callback)
        if progress_bar:
            callback = CallbackList([callback, OfflineProgressBarCallback()])
        callback.init_callback(self)
        return callback

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        # As BaseAlgorithm._setup_learn, without resetting the env: nothing is collected.
        self.start_time = time.time_ns()
        if self.ep_info_buffer is None or reset_num_timesteps:
            self.ep_info_buffer = deque(maxlen=self._stats_window_size)
            self.ep_success_buffer = deque(maxlen=self._stats_window_size)
        if reset_num_timesteps:
            self.num_timesteps = 0
            self._episode_num = 0
        else:
            total_timesteps += self.num_timesteps
        self._total_timesteps = total_timesteps
        self._num_timesteps_at_start = self.num_timesteps
        self._setup_offline_data()
        if not self._custom_logger:
            self._logger = utils.configure_logger(self.verbose, self.tensorboard_log, tb_log_name, reset_num_timesteps)
        callback = self._init_callback(callback, progress_bar)
        return total_timesteps, callback

    def _before_training(self, progress_bar: bool = False) -> None:
        """Work done once before the first gradient step (e.g. fitting a model of the dynamics)."""

    def learn(
        self: SelfOfflineAlgorithm,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1000,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfOfflineAlgorithm:
        """Train for ``total_timesteps`` gradient steps.

        :param total_timesteps: number of gradient steps
        :param callback: SB3 callback(s), called after every gradient step
        :param log_interval: gradient steps between two logger dumps, and one at the end for the steps since the last
            (``0``: no dumps)
        :param tb_log_name: name of the tensorboard run (default: the algorithm's class name)
        :param reset_num_timesteps: start counting from zero (``False`` continues a previous ``learn``)
        :param progress_bar: show a progress bar
        """
        tb_log_name = tb_log_name or type(self).__name__
        total_timesteps, callback = self._setup_learn(
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar
        )
        callback.on_training_start(locals(), globals())
        self._before_training(progress_bar=progress_bar)
        self._last_finite_step = self.num_timesteps
        while self.num_timesteps < total_timesteps:
            self._update_current_progress_remaining(self.num_timesteps, total_timesteps)
            self.train(gradient_steps=1, batch_size=self.batch_size)
            self.num_timesteps += 1
            dump = log_interval > 0 and self.num_timesteps % log_interval == 0
            # divergence guard: one host sync every check_finite_freq steps, and before the stats are dumped
            if dump or (self.check_finite_freq > 0 and self.num_timesteps % self.check_finite_freq == 0):
                self.check_finite()
            callback.update_locals(locals())
            if not callback.on_step():
                break
            if dump:
                self.dump_logs()
        self.check_finite()
        if log_interval > 0 and self._stat_count > 0:  # steps since the last dump (a learn shorter than log_interval)
            self.dump_logs()
        callback.on_training_end()
        return self

    def check_finite(self, parameters_only: bool = False, consequence: str = "Training stopped") -> None:
        """Raise :class:`~sb3_pola.common.integrity.DivergenceError` if a parameter or a loss is NaN or inf.

        The losses checked are the training statistics accumulated since the last log dump, so a loss
        that was non-finite at any step since then is caught. All tensors are checked with one host sync.

        :param parameters_only: check the parameters (and buffers) only, not the accumulated losses
        :param consequence: what the error stops (e.g. ``"Not saving model.zip"``), a sentence of the message
        """
        named: list[tuple[str, str, th.Tensor]] = []
        if not parameters_only:
            named += [("losses", key, value) for key, value in self._stat_sums.items()]
        policy = getattr(self, "policy", None)
        if policy is not None:
            named += [("parameters", key, value) for key, value in policy.state_dict().items() if value.is_floating_point()]
        if not named:
            return
        finite = th.stack([th.isfinite(value).all() for *_, value in named]).cpu().tolist()
        if all(finite):
            if not parameters_only:
                self._last_finite_step = self.num_timesteps
            return
        parts = []
        for kind in ("losses", "parameters"):
            bad = [name for (k, name, _), ok in zip(named, finite, strict=True) if k == kind and not ok]
            if bad:
                parts.append(f"{kind} " + ", ".join(bad[:4]) + (f" (+{len(bad) - 4} more)" if len(bad) > 4 else ""))
        raise DivergenceError(
            f"Training diverged: NaN or inf in {'; '.join(parts)} at gradient step {self.num_timesteps} (first non-finite "
            f"after step {self._last_finite_step}, when all were last found finite). {consequence}. Try a lower learning "
            "rate or max_grad_norm, and check the dataset for NaN/inf; set check_finite_freq=1 to find the exact step."
        )

    def save(
        self,
        path: str | pathlib.Path | io.BufferedIOBase,
        exclude: Iterable[str] | None = None,
        include: Iterable[str] | None = None,
        check_finite: bool = True,
    ) -> None:
        """Save the model (SB3 zip); refuses NaN/inf weights so a diverged model never replaces a good one.

        :param path: file path or file object
        :param exclude: attributes not to save
        :param include: attributes to save even if excluded by default
        :param check_finite: raise :class:`~sb3_pola.common.integrity.DivergenceError` instead of saving
            non-finite parameters (``False`` saves them anyway, e.g. for debugging)
        """
        if check_finite:
            self.check_finite(
                parameters_only=True, consequence=f"Not saving {path} (pass check_finite=False to save it anyway)"
            )
        super().save(path, exclude=exclude, include=include)

    @classmethod
    def load(  # type: ignore[override]
        cls: type[SelfOfflineAlgorithm],
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfOfflineAlgorithm:
        """Load a model (SB3's ``load``), with clear errors for missing, truncated, corrupt or foreign files.

        :param path: model file (``.zip`` may be omitted)
        :param env: env to attach; its spaces must equal the model's
        :param device: device of the loaded model
        :param custom_objects: objects replacing saved ones (SB3)
        :param print_system_info: print the saving and current system info
        :param force_reset: reset the env before training (SB3)
        :param kwargs: attributes to change, e.g. ``dataset=`` to continue training (its replay buffer is built now)
        :raises FileNotFoundError: no such file
        :raises ~sb3_pola.common.integrity.ModelFileError: truncated, corrupt, or saved by another algorithm
        :raises ValueError: ``env`` has other spaces than the model
        """
        if isinstance(path, str | os.PathLike):
            policies = tuple(dict.fromkeys(cls.policy_aliases.values()))
            data = validate_model_file(path, policies, cls.__name__)
            if env is not None:
                obs_space, act_space = env.observation_space, env.action_space
                model_obs_space = data["observation_space"]
                if isinstance(obs_space, spaces.Dict):  # the env's own dict observations: compare the original spaces
                    model_obs_space = data.get("dict_observation_space") or model_obs_space
                if obs_space != model_obs_space or act_space != data["action_space"]:
                    original = data.get("dict_observation_space")
                    flattened = f" (flattened from {original})" if original is not None and original != model_obs_space else ""
                    raise ValueError(
                        f"Cannot load {path} onto this env: the model has observation space {model_obs_space}{flattened} "
                        f"and action space {data['action_space']}, the env has observation space {obs_space} "
                        f"and action space {act_space}"
                    )
            if env is not None:
                env = flatten_env(env)
        model = super().load(
            path,
            env=env,
            device=device,
            custom_objects=custom_objects,
            print_system_info=print_system_info,
            force_reset=force_reset,
            **kwargs,
        )
        if kwargs.get("dataset") is not None:
            model._setup_offline_data()
        return model  # type: ignore[return-value]

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """SB3's ``predict``, after checking the observation's shape and that it holds no NaN or inf.

        :param observation: one observation ``obs_shape`` or a batch ``[n, *obs_shape]``; for a model of Dict
            observations also the env's own dict (each key one value or a batch), flattened as the dataset
        :param state: recurrent state (unused)
        :param episode_start: episode starts (unused)
        :param deterministic: deterministic action
        :return: the action(s) and the state
        """
        if isinstance(observation, dict):
            if self.dict_observation_space is None:
                raise ValueError(
                    f"predict got a dict observation (keys {sorted(observation)}); this model's observation space is "
                    f"{self.observation_space}: pass an array"
                )
            observation = flatten_observation(self.dict_observation_space, observation)
        self._check_observation(observation)
        return super().predict(observation, state, episode_start, deterministic)

    def _check_observation(self, observation: np.ndarray) -> None:
        space = self.observation_space
        if isinstance(observation, dict) or not isinstance(space, spaces.Box):
            return
        obs = np.asarray(observation)
        expected = space.shape
        if not (obs.shape == expected or (obs.ndim == len(expected) + 1 and obs.shape[1:] == expected)):
            raise ValueError(
                f"predict got an observation of shape {obs.shape}; this model expects {expected} (one observation) "
                f"or (n, {', '.join(map(str, expected))}) (a batch), for observation space {space}"
            )
        if not (np.issubdtype(obs.dtype, np.number) or obs.dtype == np.bool_):
            raise ValueError(f"predict got an observation of dtype {obs.dtype}; it needs numbers")
        finite = np.isfinite(obs)
        if not finite.all():
            where = [tuple(int(i) for i in index) for index in np.argwhere(~finite)[:3]]
            values = [obs[index] for index in where]
            raise ValueError(
                f"predict got an observation with NaN or inf ({int((~finite).sum())} values, e.g. at index "
                f"{', '.join(f'{w}: {v}' for w, v in zip(where, values, strict=True))}); the policy's actions would be NaN"
            )

    def normalized_score(self, returns: float | np.ndarray | list[float]) -> float | None:
        """D4RL score ``100 (R - ref_min) / (ref_max - ref_min)`` of the mean return, from the dataset's metadata."""
        return normalized_score(returns, self.ref_min_score, self.ref_max_score)

    def _accumulate_train_stats(self, stats: dict[str, th.Tensor]) -> None:
        """Add one gradient step's detached statistics; they stay on the device until the next dump."""
        for key, value in stats.items():
            # a copy, never the value itself: a CUDA-graph replay overwrites its outputs in place
            self._stat_sums[key] = self._stat_sums[key] + value if key in self._stat_sums else value.clone()
        self._stat_count += 1

    def _record_train_stats(self) -> None:
        """Write the means of the accumulated statistics as ``train/<name>`` (one host sync per dump)."""
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        if self._stat_count == 0:
            return
        values = th.stack(list(self._stat_sums.values())).cpu().numpy() / self._stat_count
        for key, value in zip(self._stat_sums, values, strict=True):
            self.logger.record(f"train/{key}", float(value))
        self._stat_sums, self._stat_count = {}, 0

    def dump_logs(self) -> None:
        time_elapsed = max((time.time_ns() - self.start_time) / 1e9, sys.float_info.epsilon)
        steps_per_s = (self.num_timesteps - self._num_timesteps_at_start) / time_elapsed
        self._record_train_stats()
        self.logger.record("time/gradient_steps_per_s", float(np.round(steps_per_s, 2)))
        self.logger.record("time/fps", int(steps_per_s))
        self.logger.record("time/time_elapsed", int(time_elapsed), exclude="tensorboard")
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(step=self.num_timesteps)
