"""Shared fixtures: tiny Minari datasets written into temporary folders (never the user's home).

The whole run gets a temporary ``HOME`` (and cache, Minari and XDG cache folders) before any fixture runs, module- and
session-scoped ones included; the user's real ``~/.cache/sb3_pola`` and ``~/.minari`` are checked unchanged at the
end. The functions that make the datasets live in ``tests/helpers.py``."""

from __future__ import annotations

import os
import pathlib
from collections.abc import Callable, Iterator

import pytest
from helpers import SCORE_DATASETS, make_episodes, record_random_dataset, write_minari_dataset

# the user's home as the run found it: nothing may be written below these
REAL_HOME = pathlib.Path(os.path.expanduser("~"))
GUARDED = (REAL_HOME / ".cache" / "sb3_pola", REAL_HOME / ".minari")


def _snapshot(folders: tuple[pathlib.Path, ...]) -> dict[str, int]:
    """Every file below ``folders``, with its modification time."""
    return {str(p): p.stat().st_mtime_ns for folder in folders if folder.exists() for p in folder.rglob("*") if p.is_file()}


@pytest.fixture(scope="session", autouse=True)
def _home_untouched() -> Iterator[None]:
    """Fails the run (an error at the last test's teardown) if a test wrote into the user's cache or Minari folder."""
    before = _snapshot(GUARDED)
    yield
    written = sorted(path for path, mtime in _snapshot(GUARDED).items() if before.get(path) != mtime)
    assert not written, f"the tests wrote into the user's home: {written[:5]}"


@pytest.fixture(scope="session", autouse=True)
def _isolated_home(_home_untouched: None, tmp_path_factory: pytest.TempPathFactory) -> Iterator[pathlib.Path]:
    """A temporary ``HOME`` for the whole run (session scope: set up before every module fixture), the cache and
    datasets roots below it; the environment is restored afterwards."""
    home = tmp_path_factory.mktemp("home")
    patch = pytest.MonkeyPatch()
    patch.setenv("HOME", str(home))
    patch.setenv("XDG_CACHE_HOME", str(home / ".cache"))
    patch.setenv("SB3_POLA_CACHE_DIR", str(home / ".cache" / "sb3_pola"))
    patch.setenv("MINARI_DATASETS_PATH", str(home / ".minari" / "datasets"))
    yield home
    patch.undo()


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


@pytest.fixture(scope="session")
def score_data(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """The score grid's tests' datasets root (:data:`helpers.SCORE_DATASETS`; read-only, one per session)."""
    root = tmp_path_factory.mktemp("score_data")
    for seed, dataset in enumerate(SCORE_DATASETS):
        record_random_dataset(root, dataset, "Pendulum-v1", 60, seed=seed, ref_scores=(-300.0, 0.0), max_episode_steps=30)
    return root


@pytest.fixture(autouse=True)
def _score_data_path(_isolated_dirs: None, request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    """MINARI_DATASETS_PATH at ``score_data`` in the tests that use it, for what they load themselves after a run
    (``sb3-pola score --data-dir`` sets the variable for the command only)."""
    if "score_data" in request.fixturenames:
        monkeypatch.setenv("MINARI_DATASETS_PATH", str(request.getfixturevalue("score_data")))
