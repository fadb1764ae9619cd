"""OfflineReplayBuffer: shapes, dtypes, reproducibility, memory sharing, read-only."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from helpers import ACT_DIM, OBS_DIM

from sb3_pola.common.buffers import OfflineReplayBuffer
from sb3_pola.common.datasets import load_offline_dataset


@pytest.fixture
def data(tiny_dataset):
    return load_offline_dataset(tiny_dataset)


def test_sample_shapes_and_dtypes(data):
    buffer = OfflineReplayBuffer(data, device="cpu")
    assert buffer.size() == len(data) and buffer.full
    batch = buffer.sample(32)
    assert batch.observations.shape == batch.next_observations.shape == (32, OBS_DIM)
    assert batch.actions.shape == (32, ACT_DIM)
    assert batch.rewards.shape == batch.dones.shape == (32, 1)
    for tensor in batch[:5]:
        assert tensor.dtype == th.float32 and tensor.device.type == "cpu"
    # a sampled row is a real transition of the dataset
    obs = batch.observations[0].numpy()
    (row,) = np.flatnonzero((data.observations == obs).all(axis=1))
    np.testing.assert_array_equal(batch.next_observations[0].numpy(), data.next_observations[row])
    assert batch.rewards[0, 0].item() == data.rewards[row] and batch.dones[0, 0].item() == data.dones[row]


def test_reproducible_with_manual_seed(data):
    buffer = OfflineReplayBuffer(data, device="cpu")
    th.manual_seed(3)
    first = buffer.sample(16)
    th.manual_seed(3)
    second = buffer.sample(16)
    for a, b in zip(first[:5], second[:5], strict=False):
        assert th.equal(a, b)
    assert not th.equal(buffer.sample(16).observations, first.observations)


def test_no_duplicate_memory(data):
    buffer = OfflineReplayBuffer(data, device="cpu")
    for name in ("observations", "next_observations", "actions", "rewards", "dones"):
        assert np.shares_memory(getattr(buffer, name).numpy(), getattr(data, name)), name
    expected = sum(getattr(data, n).nbytes for n in ("observations", "next_observations", "actions", "rewards", "dones"))
    assert buffer.nbytes == expected
    assert not any(isinstance(v, np.ndarray) and v.size >= len(data) for v in vars(buffer).values())


def test_obs_stats_and_read_only(data):
    buffer = OfflineReplayBuffer(data, device="cpu")
    mean, std = data.obs_stats()
    np.testing.assert_allclose(buffer.obs_mean.numpy(), mean)
    np.testing.assert_allclose(buffer.obs_std.numpy(), std)
    with pytest.raises(TypeError, match="read-only"):
        buffer.add()
    with pytest.raises(TypeError, match="read-only"):
        buffer.extend()
    buffer.reset()
    assert buffer.size() == len(data)


def test_model_has_its_buffer_once_built(tiny_dataset: str, tmp_path) -> None:
    """As in SB3, ``model.replay_buffer`` exists once a model is built with its data, before ``learn``."""
    from helpers import light_kwargs

    from sb3_pola.pola import POLA

    model = POLA("MlpPolicy", dataset=tiny_dataset, **light_kwargs())
    assert isinstance(model.replay_buffer, OfflineReplayBuffer)
    assert model.replay_buffer.size() == len(model.offline_data)
    assert model.replay_buffer.dataset_id == "test/tiny-v0"
    in_memory = POLA("MlpPolicy", dataset=load_offline_dataset(tiny_dataset), **light_kwargs())
    assert isinstance(in_memory.replay_buffer, OfflineReplayBuffer)
    buffer = model.replay_buffer
    model.learn(2)
    assert model.replay_buffer is buffer  # learn uses the buffer built with the model
    model.save(tmp_path / "model.zip")
    # loading without a dataset stays lazy; with one, the buffer is there at once
    assert POLA.load(tmp_path / "model.zip", device="cpu").replay_buffer is None
    loaded = POLA.load(tmp_path / "model.zip", dataset=tiny_dataset, device="cpu")
    assert isinstance(loaded.replay_buffer, OfflineReplayBuffer) and loaded.replay_buffer.size() == buffer.size()
