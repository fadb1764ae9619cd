"""Read-only replay buffer over an :class:`~sb3_pola.common.datasets.OfflineDataset`."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.buffers import BaseBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from sb3_pola.common.datasets import OfflineDataset


class OfflineReplayBuffer(BaseBuffer):
    """SB3 replay buffer holding a whole offline dataset as torch tensors on ``device``.

    On CPU the tensors share memory with the dataset's numpy arrays (``th.from_numpy``), so the
    data exists once; on an accelerator they are copied there once and the buffer keeps no
    numpy arrays. Sampling draws indices with ``th.randint`` on the device from torch's global
    RNG, so ``th.manual_seed`` makes batches reproducible and no host round-trip is needed.

    :param data: the dataset (actions already scaled to [-1, 1])
    :param device: where the tensors live and batches are returned
    """

    observations: th.Tensor  # type: ignore[assignment]
    actions: th.Tensor  # type: ignore[assignment]

    def __init__(self, data: OfflineDataset, device: th.device | str = "auto") -> None:
        super().__init__(len(data), data.observation_space, data.action_space, device=device, n_envs=1)
        self.dataset_id = data.dataset_id

        def to_tensor(array: np.ndarray) -> th.Tensor:
            return th.from_numpy(np.ascontiguousarray(array, dtype=np.float32)).to(self.device)

        self.observations = to_tensor(data.observations)
        self.next_observations = to_tensor(data.next_observations)
        self.actions = to_tensor(data.actions)
        # [N, 1] views, as SB3 returns rewards and dones
        self.rewards = to_tensor(data.rewards).reshape(-1, 1)
        self.dones = to_tensor(data.dones).reshape(-1, 1)
        mean, std = data.obs_stats()
        self._obs_mean = th.as_tensor(mean, device=self.device)
        self._obs_std = th.as_tensor(std, device=self.device)
        self.pos = self.buffer_size
        self.full = True

    @property
    def obs_mean(self) -> th.Tensor:
        """Per-feature observation mean, float32 ``[obs_dim]``."""
        return self._obs_mean

    @property
    def obs_std(self) -> th.Tensor:
        """Per-feature observation std (floored), float32 ``[obs_dim]``."""
        return self._obs_std

    @property
    def nbytes(self) -> int:
        """Bytes of the transition tensors."""
        tensors = (self.observations, self.next_observations, self.actions, self.rewards, self.dones)
        return sum(t.element_size() * t.nelement() for t in tensors)

    def reset(self) -> None:
        """Nothing to reset: the buffer always holds the whole dataset."""
        self.pos = self.buffer_size
        self.full = True

    def add(self, *args: Any, **kwargs: Any) -> None:
        raise TypeError("OfflineReplayBuffer is read-only: an offline dataset cannot be added to")

    def extend(self, *args: Any, **kwargs: Any) -> None:
        raise TypeError("OfflineReplayBuffer is read-only: an offline dataset cannot be extended")

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> ReplayBufferSamples:
        """Uniformly sample transitions (with replacement).

        :param batch_size: number of transitions
        :param env: ignored (an offline dataset is not normalised by a VecNormalize)
        :return: tensors on ``device``: observations ``[B, obs_dim]``, actions ``[B, act_dim]``,
            next_observations, dones ``[B, 1]``, rewards ``[B, 1]``
        """
        return self._get_samples(self.sample_indices(batch_size))

    def sample_indices(self, batch_size: int, n_rows: int | None = None) -> th.Tensor:
        """``[B]`` uniform transition indices (with replacement), the draw :meth:`sample` makes; ``n_rows``: from the
        first ``n_rows`` transitions only."""
        return th.randint(0, self.buffer_size if n_rows is None else n_rows, (batch_size,), device=self.device)

    def _get_samples(  # type: ignore[override]
        self, batch_inds: np.ndarray | th.Tensor, env: VecNormalize | None = None
    ) -> ReplayBufferSamples:
        indices = th.as_tensor(batch_inds, device=self.device, dtype=th.long)
        return ReplayBufferSamples(
            observations=self.observations[indices],
            actions=self.actions[indices],
            next_observations=self.next_observations[indices],
            dones=self.dones[indices],
            rewards=self.rewards[indices],
        )
