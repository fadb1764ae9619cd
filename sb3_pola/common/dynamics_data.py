"""The data side of the dynamics model's fit (:class:`~sb3_pola.common.dynamics_trainer.DynamicsTrainer`): the
transitions as tensors, the holdout split, the normalisation statistics of the training split and the members'
bootstrap resamples."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch as th

from sb3_pola.common.dynamics import EnsembleDynamics, NormalizationStats


@dataclass(frozen=True)
class Transitions:
    """The transitions of a fit as float32 tensors on the model's device.

    :meth:`from_arrays` converts without copying what is one already; nothing here modifies the tensors.

    :param observations: ``[N, obs_dim]``
    :param actions: ``[N, action_dim]``
    :param next_observations: ``[N, obs_dim]``
    :param rewards: ``[N, 1]``
    :param dones: ``[N]`` termination flags, or None (no termination head)
    """

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    rewards: th.Tensor
    dones: th.Tensor | None

    @classmethod
    def from_arrays(
        cls,
        model: EnsembleDynamics,
        observations: th.Tensor | np.ndarray,
        actions: th.Tensor | np.ndarray,
        next_observations: th.Tensor | np.ndarray,
        rewards: th.Tensor | np.ndarray,
        dones: th.Tensor | np.ndarray | None = None,
    ) -> Transitions:
        """The caller's arrays in the model's shapes, dtype and device; ``dones`` kept only for a termination head.

        :param model: the model to fit
        :param observations: ``[N, obs_dim]``
        :param actions: ``[N, action_dim]``
        :param next_observations: ``[N, obs_dim]``
        :param rewards: ``[N]`` or ``[N, 1]``
        :param dones: ``[N]`` or ``[N, 1]``; required with ``learn_termination``
        :return: the transitions
        """
        if model.learn_termination and dones is None:
            raise ValueError("learn_termination=True needs dones")
        device = model.obs_mean.device

        def as_tensor(a: th.Tensor | np.ndarray) -> th.Tensor:
            return th.as_tensor(a, dtype=th.float32, device=device)

        obs = as_tensor(observations).reshape(-1, model.obs_dim)
        n = obs.shape[0]
        act = as_tensor(actions).reshape(n, model.action_dim)
        next_obs = as_tensor(next_observations).reshape(n, model.obs_dim)
        rew = as_tensor(rewards).reshape(n, 1)
        done = as_tensor(dones).reshape(n) if (model.learn_termination and dones is not None) else None
        return cls(obs, act, next_obs, rew, done)

    def __len__(self) -> int:
        return self.observations.shape[0]

    def standardized(self, rows: th.Tensor, stats: NormalizationStats) -> tuple[th.Tensor, th.Tensor]:
        """Standardised inputs and targets of the transitions ``rows``, gathered from the tensors (which stay as they are).

        :param rows: transition indices, any shape ``[...]``
        :param stats: the normalisation statistics
        :return: inputs ``[..., obs_dim + action_dim]`` and targets ``[..., obs_dim + 1]``
        """
        obs_rows = self.observations[rows]
        x = (th.cat((obs_rows, self.actions[rows]), dim=-1) - stats.input_mean) / stats.input_std
        y = (
            th.cat((self.next_observations[rows] - obs_rows, self.rewards[rows]), dim=-1) - stats.target_mean
        ) / stats.target_std
        return x, y

    def done_rows(self, rows: th.Tensor) -> th.Tensor | None:
        """Termination flags of the transitions ``rows`` (None without a termination head).

        :param rows: transition indices
        :return: flags of the shape of ``rows``, or None
        """
        return self.dones[rows] if self.dones is not None else None


@dataclass(frozen=True)
class HoldoutSplit:
    """Indices of the training and holdout transitions (only indices: the data are never copied).

    :param train: training rows ``[N_train]``, int32 where the row count fits (same draws as int64), a view of
        the permutation
    :param holdout: holdout rows ``[H]`` (int64)
    """

    train: th.Tensor
    holdout: th.Tensor


def holdout_split(n: int, holdout_ratio: float, max_holdout: int, device: th.device | str = "cpu") -> HoldoutSplit:
    """Hold out a random ``min(holdout_ratio * n, max_holdout)`` of ``n`` transitions (one ``randperm`` draw).

    With no room for a holdout, the first ``max_holdout`` training rows stand in for it, so that the scores
    are measured on (part of) the training data.

    :param n: number of transitions
    :param holdout_ratio: fraction held out
    :param max_holdout: maximum holdout size
    :param device: device of the indices
    :return: the split
    """
    n_holdout = min(int(n * holdout_ratio), max_holdout)
    if n - n_holdout < 1:
        raise ValueError(f"not enough transitions to fit ({n})")
    index_dtype = th.int32 if n <= th.iinfo(th.int32).max else th.long
    perm = th.randperm(n, device=device, dtype=index_dtype)
    holdout, train = perm[:n_holdout].long(), perm[n_holdout:]
    if n_holdout == 0:
        holdout = train[:max_holdout].long()
    return HoldoutSplit(train=train, holdout=holdout)


def split_statistics(
    obs: th.Tensor, act: th.Tensor, next_obs: th.Tensor, rew: th.Tensor, rows: th.Tensor, chunk_size: int = 4096
) -> NormalizationStats:
    """Column mean and std of the inputs ``[s, a]`` and the targets ``[s' - s, r]`` over the transitions ``rows``.

    The std is the unbiased one, with 1 for (near-)constant columns and for a single row. The split is gathered
    chunk by chunk (never copied whole); the chunks' float32 moments are merged in float64 with Chan et al.'s
    pairwise update, so the result equals the float32 statistics of the materialised split up to rounding.

    :param obs: ``[N, obs_dim]``
    :param act: ``[N, action_dim]``
    :param next_obs: ``[N, obs_dim]``
    :param rew: ``[N, 1]``
    :param rows: indices of the split ``[M]``
    :param chunk_size: rows gathered at a time (small: large temporaries of a loop leave glibc's heap grown)
    :return: input mean and std ``[obs_dim + action_dim]``, target mean and std ``[obs_dim + 1]`` (float32)
    """
    n_in = obs.shape[1] + act.shape[1]
    count = 0
    mean = th.zeros(n_in + obs.shape[1] + 1, dtype=th.float64, device=obs.device)
    m2 = th.zeros_like(mean)  # sum of squared deviations from the mean
    for start in range(0, rows.shape[0], chunk_size):
        idx = rows[start : start + chunk_size]
        obs_rows = obs.index_select(0, idx)
        chunk = th.cat(
            (obs_rows, act.index_select(0, idx), next_obs.index_select(0, idx) - obs_rows, rew.index_select(0, idx)), dim=-1
        )  # [c, in + D]
        c = chunk.shape[0]
        c_var, c_mean_32 = th.var_mean(chunk, dim=0, correction=0)
        c_mean, c_m2 = c_mean_32.double(), c_var.double() * c
        delta = c_mean - mean
        total = count + c
        mean = mean + delta * (c / total)
        m2 = m2 + c_m2 + delta**2 * (count * c / total)
        count = total
    if count > 1:
        std = (m2 / (count - 1)).sqrt().float()
        std = th.where(std < 1e-6, th.ones_like(std), std)
    else:
        std = th.ones_like(mean, dtype=th.float32)
    mean = mean.float()
    return NormalizationStats(mean[:n_in], std[:n_in], mean[n_in:], std[n_in:])


class BootstrapBatches:
    """Minibatches of every member's own bootstrap resample of the training split, all members at once.

    The resample (``[E, N_train]`` positions in the training split, drawn in place in the index dtype: the
    same values as ``th.randint``'s int64) is fixed for the whole fit. A *pass* walks through one random
    permutation of the resamples' columns in ``batch_size`` steps: the members' resamples are independent,
    so one permutation shuffles them all. The first permutation is drawn at the first batch.

    :param train_rows: indices of the training split ``[N_train]``
    :param n_members: ensemble size ``E``
    :param batch_size: minibatch size per member
    """

    def __init__(self, train_rows: th.Tensor, n_members: int, batch_size: int) -> None:
        self.train_rows = train_rows
        self.batch_size = batch_size
        self.n_train = train_rows.shape[0]
        self.steps_per_pass = math.ceil(self.n_train / batch_size)
        dtype, device = train_rows.dtype, train_rows.device
        self.bootstrap = th.empty((n_members, self.n_train), dtype=dtype, device=device).random_(0, self.n_train)
        self._pass_perm = th.empty(0, dtype=dtype, device=device)
        self._cursor = self.steps_per_pass  # forces a shuffle at the first batch

    def next_rows(self) -> th.Tensor:
        """The transitions of the next minibatch, a new pass when the last one is through.

        :return: transition indices ``[E, b]`` (``b = batch_size``, less at the end of a pass)
        """
        if self._cursor >= self.steps_per_pass:
            self._pass_perm = th.randperm(self.n_train, device=self.train_rows.device, dtype=self.train_rows.dtype)
            self._cursor = 0
        cols = self._pass_perm[self._cursor * self.batch_size : (self._cursor + 1) * self.batch_size]  # [b]
        self._cursor += 1
        return self.train_rows[self.bootstrap[:, cols].long()].long()  # [E, b]
