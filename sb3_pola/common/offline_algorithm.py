"""An SB3 base class for algorithms that learn from a fixed dataset instead of from rollouts."""

from __future__ import annotations

import os
import sys
import time
import warnings
from collections import deque
from typing import Any, TypeVar

import numpy as np
from gymnasium import spaces
from stable_baselines3.common import utils
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, ConvertCallback, ProgressBarCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule

from sb3_pola.common.buffers import OfflineReplayBuffer
from sb3_pola.common.datasets import OfflineDataset, load_offline_dataset, make_env

SelfOfflineAlgorithm = TypeVar("SelfOfflineAlgorithm", bound="OfflineAlgorithm")


class OfflineProgressBarCallback(ProgressBarCallback):
    """SB3's progress bar counting gradient steps; works without an env."""

    def _on_step(self) -> bool:
        self.pbar.update(1)
        return True


def dataset_reference(dataset: Any) -> str | None:
    """What is saved with a model to find its dataset again: a Minari id or a path (never the data itself)."""
    if dataset is None or isinstance(dataset, str):
        return dataset
    if isinstance(dataset, os.PathLike):
        return os.fspath(dataset)
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
    :param dataset: a Minari dataset id, a path to a Minari dataset folder, or a ``minari.MinariDataset``
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
    """

    replay_buffer: OfflineReplayBuffer | None  # type: ignore[assignment]

    def __init__(
        self,
        policy: str | type[BasePolicy],
        env: GymEnv | str | None,
        dataset: Any,
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
    ) -> None:
        data: OfflineDataset | None = None
        if dataset is not None:
            data = load_offline_dataset(dataset, env=env if not isinstance(env, str) else None, download=download)
            if env is None:
                env = self._env_from_dataset(data, verbose)
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
        self._offline_data = data
        self.env_id: str | None = None
        self.ref_min_score: float | None = None
        self.ref_max_score: float | None = None
        if data is not None:
            if self.observation_space is None:
                self.observation_space = data.observation_space
                self.action_space = data.action_space
            self.env_id = data.env_id
            self.ref_min_score, self.ref_max_score = data.ref_min_score, data.ref_max_score
        if self.env_id is None and self.env is not None:
            spec = self.env.get_attr("spec")[0]
            self.env_id = getattr(spec, "id", None)

    @staticmethod
    def _env_from_dataset(data: OfflineDataset, verbose: int) -> GymEnv | None:
        try:
            return make_env(data)
        except Exception as error:  # an env that cannot be built only disables env-based callbacks
            if verbose:
                warnings.warn(f"Training without an env: the dataset's env could not be made ({error}).")
            return None

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_offline_data"]

    def _setup_offline_data(self) -> OfflineReplayBuffer:
        """The replay buffer over the dataset, loaded now if the model was built without one (e.g. after ``load``)."""
        if self.replay_buffer is None:
            if self._offline_data is None:
                if self.dataset is None:
                    raise ValueError(
                        "This model has no dataset to learn from: pass `dataset=` to the constructor "
                        "or to `load(path, dataset=...)`."
                    )
                self._offline_data = load_offline_dataset(self.dataset, download=self.download)
                self.dataset = dataset_reference(self.dataset)
            self._check_dataset_spaces(self._offline_data)
            self.replay_buffer = OfflineReplayBuffer(self._offline_data, device=self.device)
        return self.replay_buffer

    def _check_dataset_spaces(self, data: OfflineDataset) -> None:
        assert self.observation_space is not None and self.action_space is not None
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
        tb_log_name: str = "run",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfOfflineAlgorithm:
        """Train for ``total_timesteps`` gradient steps.

        :param total_timesteps: number of gradient steps
        :param callback: SB3 callback(s), called after every gradient step
        :param log_interval: gradient steps between two logger dumps
        :param tb_log_name: name of the tensorboard run
        :param reset_num_timesteps: start counting from zero (``False`` continues a previous ``learn``)
        :param progress_bar: show a progress bar
        """
        total_timesteps, callback = self._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        callback.on_training_start(locals(), globals())
        self._before_training(progress_bar=progress_bar)
        while self.num_timesteps < total_timesteps:
            self._update_current_progress_remaining(self.num_timesteps, total_timesteps)
            self.train(gradient_steps=1, batch_size=self.batch_size)
            self.num_timesteps += 1
            callback.update_locals(locals())
            if not callback.on_step():
                break
            if log_interval > 0 and self.num_timesteps % log_interval == 0:
                self.dump_logs()
        callback.on_training_end()
        return self

    def _record_train_stats(self) -> None:
        """Hook: write the accumulated ``train/*`` statistics to the logger."""

    def dump_logs(self) -> None:
        time_elapsed = max((time.time_ns() - self.start_time) / 1e9, sys.float_info.epsilon)
        steps_per_s = (self.num_timesteps - self._num_timesteps_at_start) / time_elapsed
        self._record_train_stats()
        self.logger.record("time/gradient_steps_per_s", float(np.round(steps_per_s, 2)))
        self.logger.record("time/fps", int(steps_per_s))
        self.logger.record("time/time_elapsed", int(time_elapsed), exclude="tensorboard")
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(step=self.num_timesteps)
