"""What POLA derives from its dataset before the first gradient step: the goals relabelled, the returns-to-go
behind the critics' floor, start and gate, the look-ahead's fixed goal, and the dynamics model's fit (or its cache)."""

from __future__ import annotations

import functools
import os
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th

from sb3_pola.common.buffers import OfflineReplayBuffer
from sb3_pola.common.dataset_paths import DatasetError, resolve_dataset_path
from sb3_pola.common.datasets import OfflineDataset, make_env
from sb3_pola.common.dict_obs import key_slice
from sb3_pola.common.dynamics_cache import cache_key, data_fingerprint, fit_or_load
from sb3_pola.common.dynamics_trainer import DynamicsTrainer, auto_max_steps
from sb3_pola.common.offline_algorithm import OfflineAlgorithm
from sb3_pola.pola.arguments import DENSE_REWARD_OPTIONS
from sb3_pola.pola.losses import value_lower_bound
from sb3_pola.pola.policies import POLAPolicy


def _goal_reward(compute_reward: Callable[..., Any], achieved: np.ndarray, desired: np.ndarray) -> np.ndarray:
    """A GoalEnv's ``compute_reward`` over a batch of goals (its ``info`` unused by the mazes' sparse reward)."""
    return np.asarray(compute_reward(achieved, desired, {}), dtype=np.float32)


def _dataset_source(dataset: Any) -> str | None:
    """The folder of a dataset given by id or path, for the dynamics cache's listing (``None`` if unknown)."""
    if not isinstance(dataset, str | os.PathLike):
        return None
    try:
        return str(resolve_dataset_path(dataset))
    except (DatasetError, TypeError):
        return None


class POLAData(OfflineAlgorithm):
    """:class:`~sb3_pola.pola.pola.POLA`'s preparation of its data (a base of POLA; its arguments are POLA's)."""

    policy: POLAPolicy
    gamma: float
    reward_scale: float
    q_scale_floor_value: float | None
    target_q_floor: float | str | None
    target_q_floor_value: float | None
    critic_init_value: float | str | None
    eta_gate: str | None
    critic_bc_coef: float
    lookahead_fixed_goal: bool
    goal_switches: str | None
    hindsight_goals: bool
    bc_top_fraction: float | str | None
    q_term_confidence: float | str | None
    n_critics: int
    dynamics_fit_kwargs: dict[str, Any]
    dynamics_cache: bool

    def _init_data_state(self) -> None:
        """What the preparation derives from the data, before it is loaded (by ``POLA.__init__``)."""
        self._n_imitation_rows: int | None = None  # hindsight_goals: the actor's batches come from the first rows
        self._imitation_rows: th.Tensor | None = None  # bc_top_fraction: [M] the rows the actor's batches come from
        # "returns": the dataset's discounted return-to-go of every transition, [N], set once the data are loaded
        self._data_returns: th.Tensor | None = None
        self._critic_init_done = False  # critic_init_value applied (once, before the first update)
        # critic_bc_coef: 1 where a row's episode goes on (its next action is the next row's), [N]
        self._next_data_mask: th.Tensor | None = None
        # "critic_maturity": the dataset's mean and lowest discounted return-to-go, set once the data are loaded
        self.data_value: float | None = None
        self.data_value_floor = 0.0
        # [obs_dim] bool, the desired_goal's columns of goal-conditioned data (lookahead_fixed_goal), set by learn
        self._goal_mask: th.Tensor | None = None
        self.dynamics_fit_info: dict[str, float] = {}

    def _prepare_offline_data(self, data: OfflineDataset) -> OfflineDataset:
        space = data.dict_observation_space
        hindsight = self.hindsight_goals and space is not None and "desired_goal" in space.spaces
        switches = self.goal_switches is not None and data.goal_switches().any()
        if not switches and not hindsight:
            self._note_imitation_rows(data)
            return data
        reward_fn = None
        if hindsight or self.goal_switches == "relabel":
            env = make_env(data)
            compute_reward = getattr(env.unwrapped, "compute_reward", None)
            env.close()
            if compute_reward is not None:
                reward_fn = functools.partial(_goal_reward, compute_reward)
        if switches:
            if self.goal_switches == "relabel" and reward_fn is None:
                raise ValueError(f"goal_switches='relabel' needs an env with compute_reward (GoalEnv); {data.env_id} has none")
            data = data.with_goal_switches(self.goal_switches, reward_fn)  # type: ignore[arg-type]
        self._note_imitation_rows(data)  # before the copies: the actor's rows are the data's
        if hindsight:
            if reward_fn is None:
                warnings.warn(f"hindsight_goals needs an env with compute_reward (GoalEnv); {data.env_id} has none: no copies")
                return data
            self._n_imitation_rows = len(data)  # the copies come after: the critic's rows, not the actor's
            data = data.with_hindsight_goals(reward_fn, seed=0 if self.seed is None else self.seed)
        return data

    def _dense_option(self, name: str) -> float | None:
        """An option for dense rewards (``DENSE_REWARD_OPTIONS``) as it applies: its value, or under ``"auto"`` its
        dense-reward value where the data have no ``desired_goal`` (a maze's sparse reward: off; fortieth pass) and,
        for ``q_term_confidence``, the critic has members to agree."""
        value = getattr(self, name)
        if value != "auto":
            return value
        space = self.dict_observation_space
        if space is not None and "desired_goal" in space.spaces:
            return None
        if name == "q_term_confidence" and self.n_critics < 2:
            return None
        return DENSE_REWARD_OPTIONS[name]

    def _note_imitation_rows(self, data: OfflineDataset) -> None:
        """Note the rows of the data's best episodes, the actor's (``bc_top_fraction``)."""
        fraction = self._dense_option("bc_top_fraction")
        if fraction is not None:
            self._imitation_rows = th.as_tensor(data.best_episode_rows(fraction))

    def _actor_indices(self, buffer: OfflineReplayBuffer, batch_size: int) -> th.Tensor | None:
        """``[B]`` rows of the actor's batch where they are not the critics' (``bc_top_fraction``: the best episodes';
        ``hindsight_goals``: the data's, not the copies'); ``None``: the critics' batch."""
        if self._imitation_rows is not None:
            if self._imitation_rows.device != buffer.device:
                self._imitation_rows = self._imitation_rows.to(buffer.device)
            return self._imitation_rows[buffer.sample_indices(batch_size, len(self._imitation_rows))]
        if self._n_imitation_rows is not None:
            return buffer.sample_indices(batch_size, self._n_imitation_rows)
        return None

    # ------------------------------------------------------------------ dynamics model
    def _before_training(self, progress_bar: bool = False) -> None:
        rewards = self._setup_offline_data().rewards * self.reward_scale  # in the critic's units
        if self.q_scale_floor_value is None:  # "auto": the value scale of the dataset's rewards
            self.q_scale_floor_value = float(rewards.abs().mean()) / (1.0 - self.gamma)
        if self.target_q_floor == "auto" and self.target_q_floor_value is None:
            self.target_q_floor_value = value_lower_bound(rewards, self.gamma)
        floor_needs = self.target_q_floor == "returns" and self._data_returns is None
        gate_needs = self.eta_gate == "critic_maturity" and self.data_value is None
        init_needs = self.critic_init_value == "returns" and self._n_updates == 0 and not self._critic_init_done
        if floor_needs or gate_needs or init_needs:  # the data's returns-to-go, computed once for all
            self._setup_offline_data()
            assert self._offline_data is not None
            returns = self._offline_data.returns_to_go(self.gamma) * self.reward_scale  # in the critic's units
            if floor_needs:
                self._data_returns = th.as_tensor(returns, dtype=th.float32, device=self.device)  # [N]
            if gate_needs:
                self.data_value, self.data_value_floor = float(returns.mean()), float(returns.min())
            if init_needs:
                self._shift_critic_output(float(returns.mean()))
        if self.critic_bc_coef > 0 and self._next_data_mask is None:
            self._next_data_mask = self._episode_goes_on()
        if isinstance(self.critic_init_value, float | int) and self._n_updates == 0:
            self._shift_critic_output(float(self.critic_init_value))
        if self.lookahead_fixed_goal and self._goal_mask is None:
            self._goal_mask = self._desired_goal_mask()
        dynamics = self.policy.dynamics
        if dynamics is None:
            return
        if bool(self.policy.dynamics_fitted):
            dynamics.freeze()  # a loaded model (resume) rebuilt the model with trainable parameters
            return
        arrays = self._dynamics_arrays()
        fit_kwargs = {"progress_bar": progress_bar, "logger": self.logger, "verbose": self.verbose, **self.dynamics_fit_kwargs}
        fit_kwargs = self._sized_fit_kwargs(fit_kwargs, len(arrays[0]))

        def fit() -> dict[str, float]:
            return DynamicsTrainer(dynamics, **fit_kwargs).fit(*arrays)

        self.dynamics_fit_info = self._fit_or_load_dynamics(fit, fit_kwargs, arrays)
        dynamics.freeze()
        self.policy.dynamics_fitted.fill_(True)

    def _episode_goes_on(self) -> th.Tensor:
        """``[N]`` 1 where a row's episode goes on, so its next action is the next row's; 0 at an episode's last row
        (a terminal's target has no ``Q'``; a truncation's next action is not in the data). The hindsight copies are
        episodes of their own (``episode_ends``)."""
        self._setup_offline_data()
        assert self._offline_data is not None
        return th.as_tensor(~self._offline_data.episode_ends(), dtype=th.float32, device=self.device)

    def _next_data(self, indices: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """``critic_bc_coef``'s batch: the data's next action of each row, ``[B, A]`` (the next row's; any action at an
        episode's last row), and ``[B]`` 1 where it is one (:meth:`_episode_goes_on`)."""
        assert self._next_data_mask is not None
        actions = self._setup_offline_data().actions
        return actions[(indices + 1).clamp_max(len(actions) - 1)], self._next_data_mask[indices]

    def _dynamics_arrays(self) -> list[th.Tensor]:
        """The transitions the dynamics model fits: ``s, a, s', r, done`` of the data's rows (the hindsight copies of
        ``hindsight_goals`` show the same motion under other goals)."""
        buffer = self._setup_offline_data()
        n = self._n_imitation_rows or len(buffer.observations)
        return [x[:n] for x in (buffer.observations, buffer.actions, buffer.next_observations, buffer.rewards, buffer.dones)]

    def _desired_goal_mask(self) -> th.Tensor | None:
        """``[obs_dim]`` bool, True at the ``desired_goal`` columns of a goal-conditioned dataset's flattened
        observations; ``None`` without a ``desired_goal``."""
        self._setup_offline_data()
        space = None if self._offline_data is None else self._offline_data.dict_observation_space
        if space is None or "desired_goal" not in space.spaces:
            return None
        mask = th.zeros(self.observation_space.shape[0], dtype=th.bool, device=self.device)  # type: ignore[index]
        mask[key_slice(space, "desired_goal")] = True
        return mask

    def _shift_critic_output(self, value: float) -> None:
        """Shift the output bias of every critic member and target member by ``value`` (``critic_init_value``), once:
        a second ``learn`` or a resumed model (``_n_updates > 0``) keeps its trained critics."""
        if self._critic_init_done:
            return
        with th.no_grad():
            for critic in (self.policy.critic, self.policy.critic_target):
                critic.output_layer.bias.add_(value)  # [N, 1, 1]
        self._critic_init_done = True

    # ------------------------------------------------------------------ the dynamics fit: its size, its cache (issue #25)
    def _sized_fit_kwargs(self, fit_kwargs: dict[str, Any], n_transitions: int) -> dict[str, Any]:
        """The fit's arguments: a bar at ``verbose >= 1`` too, and, when no budget is given, one sized to the data
        (:func:`~sb3_pola.common.dynamics_trainer.auto_max_steps`)."""
        fit_kwargs = {**fit_kwargs, "progress_bar": fit_kwargs["progress_bar"] or self.verbose >= 1}
        if "max_epochs" not in fit_kwargs and "max_steps" not in fit_kwargs:
            sizes = {k: fit_kwargs[k] for k in ("batch_size", "holdout_ratio", "max_holdout") if k in fit_kwargs}
            fit_kwargs["max_steps"] = auto_max_steps(n_transitions, **sizes)
        return fit_kwargs

    def _fit_or_load_dynamics(
        self, fit: Callable[[], dict[str, float]], fit_kwargs: dict[str, Any], arrays: list[th.Tensor]
    ) -> dict[str, float]:
        """``fit()`` on ``arrays`` (:meth:`_dynamics_arrays`), or its result from the cache of fitted dynamics models
        (``dynamics_cache``)."""
        dynamics, data = self.policy.dynamics, self._offline_data
        assert dynamics is not None
        if not self.dynamics_cache:
            return fit()
        data_key = data_fingerprint(data.fingerprint if data is not None else None, arrays)
        result_kwargs = {k: v for k, v in fit_kwargs.items() if k not in ("progress_bar", "logger", "verbose")}
        exact = self.seed is not None  # seed=None: any fit of this data and configuration will do
        key = cache_key(dynamics, data_key, result_kwargs, self.device, exact=exact)
        source = data.metadata.get("source") if data is not None else None
        about = {
            "dataset_id": data.dataset_id if data is not None else None,
            "source": source or _dataset_source(self.dataset),
        }
        return fit_or_load(dynamics, fit, key, about, verbose=self.verbose, restore_rng=exact)
