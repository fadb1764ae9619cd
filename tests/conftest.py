"""Shared fixtures: tiny Minari datasets written into temporary folders (never the user's home).

The functions that make the datasets live in ``tests/helpers.py``."""

from __future__ import annotations

import pathlib
from collections.abc import Callable

import pytest
from helpers import make_episodes, record_random_dataset, write_minari_dataset


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


@pytest.fixture(scope="session")
def pendulum_path(tmp_path_factory: pytest.TempPathFactory) -> str:
    """Path of ``pendulum/random-v0``: 600 steps of uniform random actions in Pendulum-v1 (read-only, one per session)."""
    return str(record_random_dataset(tmp_path_factory.mktemp("pendulum"), "pendulum/random-v0", "Pendulum-v1", 600))
