"""Shared fixtures: tiny Minari datasets written into temporary folders (never the user's home)."""

from __future__ import annotations

import json
import os
import pathlib
import warnings
from collections.abc import Callable

import gymnasium as gym
import numpy as np
import pytest

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


@pytest.fixture(autouse=True)
def _isolated_dirs(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every test gets its own cache and datasets root, so nothing touches the user's home."""
    base = tmp_path_factory.mktemp("isolated")
    monkeypatch.setenv("SB3_POLA_CACHE_DIR", str(base / "cache"))
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(base / "minari"))


@pytest.fixture(scope="session")
def tiny_datasets_root(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """A session-wide datasets root holding ``test/tiny-v0`` (read-only: copy it to modify it)."""
    root = tmp_path_factory.mktemp("minari")
    write_minari_dataset(root, "test/tiny-v0", make_episodes())
    return root


@pytest.fixture
def tiny_dataset(tiny_datasets_root: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """Id of the tiny dataset, with MINARI_DATASETS_PATH pointing at its root."""
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tiny_datasets_root))
    return "test/tiny-v0"


@pytest.fixture
def make_dataset(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> Callable[..., str]:
    """Factory writing a fresh dataset into this test's own root (and pointing MINARI_DATASETS_PATH there)."""
    root = tmp_path / "datasets"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))

    def make(dataset_id: str = "test/custom-v0", buffers: list | None = None, **kwargs) -> str:
        write_minari_dataset(root, dataset_id, make_episodes() if buffers is None else buffers, **kwargs)
        return dataset_id

    return make
