"""Where datasets are (``sb3_pola.common.dataset_paths``): the roots searched and their order, an id or a path resolved
to its ``data`` folder, the metadata helpers and the advice in a corrupt dataset's message. Loading through these
(``load_offline_dataset``) is tested in test_datasets.py."""

from __future__ import annotations

import json
import pathlib
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
from helpers import ACT_HIGH, ACT_LOW, OBS_DIM, make_episodes, write_minari_dataset

from sb3_pola.common import dataset_paths as paths
from sb3_pola.common.dataset_paths import (
    MINARI_ID,
    DatasetNotFoundError,
    corrupt_dataset_message,
    list_local_datasets,
    metadata_env_id,
    metadata_spaces,
    read_metadata,
    resolve_dataset_path,
    scan_datasets,
    search_roots,
)


def _fake_dataset(root: pathlib.Path, dataset_id: str, **metadata) -> pathlib.Path:
    """A dataset folder that only the locating code can see (a metadata file, no episodes); its ``data`` folder."""
    data_dir = root / dataset_id / "data"
    data_dir.mkdir(parents=True)
    (data_dir / paths.METADATA_FILE).write_text(json.dumps(metadata))
    return data_dir


@pytest.fixture
def minari_root(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> pathlib.Path:
    root = tmp_path / "minari"
    root.mkdir()
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    return root


def test_scan_finds_nested_ids_relative_to_the_root(tmp_path):
    root = tmp_path / "root"
    a = _fake_dataset(root, "maze/umaze-v0")
    b = _fake_dataset(root, "mujoco/hopper/medium-v0")  # Minari's ids may have two levels of namespace
    (root / "notes" / "data").mkdir(parents=True)  # a data folder without metadata is not a dataset
    assert scan_datasets(root) == {"maze/umaze-v0": a, "mujoco/hopper/medium-v0": b}
    assert scan_datasets(tmp_path / "missing") == {}


def test_minari_folder_is_searched_before_the_package(minari_root):
    """A dataset the user made or downloaded under an id the package ships is the one that loads."""
    assert search_roots() == [minari_root, paths.package_datasets_dir()]
    shipped = paths.package_datasets_dir() / "invertedpendulum" / "medium-v0" / "data"
    assert resolve_dataset_path("invertedpendulum/medium-v0") == shipped
    own = _fake_dataset(minari_root, "invertedpendulum/medium-v0")
    assert resolve_dataset_path("invertedpendulum/medium-v0") == own
    listed = list_local_datasets()
    assert listed.count("invertedpendulum/medium-v0") == 1 and listed == sorted(listed)
    assert {"invertedpendulum/medium-replay-v0", "pointmaze/umaze-v0"} <= set(listed)


def test_path_forms_resolve_to_the_data_folder(tmp_path):
    data_dir = _fake_dataset(tmp_path, "ns/set-v0")
    folder = data_dir.parent
    for form in (folder, data_dir, str(folder), str(data_dir)):
        assert resolve_dataset_path(form) == data_dir
    # a MinariDataset (or anything with its storage's data_path) is taken at its word
    assert resolve_dataset_path(SimpleNamespace(storage=SimpleNamespace(data_path=str(data_dir)))) == data_dir


@pytest.mark.parametrize(
    ("dataset", "expected"),
    [
        ("missing-folder", "no such folder, and not a Minari dataset id"),  # made an absolute path below
        ("empty-folder", "is not a Minari dataset folder"),
        ("./x-v0", "not a Minari dataset id"),
        ("outputs/my-data", "not a Minari dataset id"),
        ("test/missing-v0", "minari download test/missing-v0"),
    ],
)
def test_unknown_datasets_say_what_they_are_not(minari_root, tmp_path, dataset, expected):
    if dataset.endswith("-folder"):
        (tmp_path / "empty-folder").mkdir()
        dataset = str(tmp_path / dataset)
    _fake_dataset(minari_root, "test/present-v0")
    with pytest.raises(DatasetNotFoundError, match=expected) as info:
        resolve_dataset_path(dataset)
    message = str(info.value)
    if "-v0" in dataset and not dataset.startswith("."):
        # an id Minari could download: the message lists what is here and every way to get it
        assert "test/present-v0" in message and "download=True" in message and "sb3-pola collect" in message
        assert "(MINARI_DATASETS_PATH)" in message
    else:
        assert "minari download" not in message
    # an os.PathLike is a path, never an id
    with pytest.raises(DatasetNotFoundError, match=r"No such folder .*: a dataset path must be a Minari dataset folder"):
        resolve_dataset_path(tmp_path / "gone")


def test_not_a_location_is_a_type_error():
    with pytest.raises(TypeError, match="not int"):
        resolve_dataset_path(3)  # type: ignore[arg-type]


def test_download_is_asked_for_a_missing_id_only(minari_root, monkeypatch):
    import minari

    asked: list[str] = []

    def download(dataset_id: str) -> None:  # what minari.download_dataset does, without a server
        asked.append(dataset_id)
        _fake_dataset(minari_root, dataset_id)

    monkeypatch.setattr(minari, "download_dataset", download)
    present = _fake_dataset(minari_root, "test/present-v0")
    assert resolve_dataset_path("test/present-v0", download=True) == present
    assert asked == []
    assert resolve_dataset_path("test/remote-v0", download=True) == minari_root / "test/remote-v0" / "data"
    assert asked == ["test/remote-v0"]


def test_minari_root_label(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    assert paths.minari_root_label() == f"{tmp_path} (MINARI_DATASETS_PATH)"
    monkeypatch.delenv("MINARI_DATASETS_PATH")
    monkeypatch.setenv("HOME", str(tmp_path))
    assert paths.minari_datasets_dir() == tmp_path / ".minari" / "datasets"
    assert "not created yet" in paths.minari_root_label()
    (tmp_path / ".minari" / "datasets").mkdir(parents=True)
    label = paths.minari_root_label()
    assert "Minari's default;" in label and "not created yet" not in label


def test_minari_id_pattern():
    for dataset_id in ("halfcheetah/medium-v0", "mujoco/hopper/expert-v12", "set-v3"):
        assert MINARI_ID.search(dataset_id)
    for name in ("halfcheetah/medium", "set-v", "set-v0/extra", "set_v0"):
        assert not MINARI_ID.search(name)


@pytest.mark.parametrize(
    ("env_spec", "expected"),
    [
        (json.dumps({"id": "Hopper-v5", "max_episode_steps": 1000}), "Hopper-v5"),  # as Minari writes it
        ({"id": "PointMaze_UMaze-v3"}, "PointMaze_UMaze-v3"),
        (None, None),
        ("", None),
        ("not json", None),
        (json.dumps({"entry_point": "x"}), None),
        (json.dumps(["Hopper-v5"]), None),
    ],
)
def test_metadata_env_id(env_spec, expected):
    assert metadata_env_id({"env_spec": env_spec}) == expected
    assert metadata_env_id({}) is None


def test_metadata_spaces_from_the_stored_spaces(make_dataset):
    dataset_id = make_dataset("test/spaces-v0", make_episodes())
    data_dir = resolve_dataset_path(dataset_id)
    metadata = read_metadata(data_dir)
    observation_space, action_space = metadata_spaces(metadata, data_dir)
    assert isinstance(observation_space, gym.spaces.Box) and isinstance(action_space, gym.spaces.Box)
    assert observation_space.shape == (OBS_DIM,)
    np.testing.assert_array_equal(action_space.low, ACT_LOW)
    np.testing.assert_array_equal(action_space.high, ACT_HIGH)


@pytest.mark.parametrize("case", ["collect_command", "shipped", "minari_id", "other"])
def test_corrupt_dataset_message_names_the_file_and_one_fix(tmp_path, monkeypatch, case):
    shipped = tmp_path / "shipped"
    monkeypatch.setattr(paths, "package_datasets_dir", lambda: shipped)
    root = shipped if case == "shipped" else tmp_path / "elsewhere"
    metadata = {"collect_command": "sb3-pola collect --env Hopper-v5"} if case == "collect_command" else {}
    data_dir = _fake_dataset(root, "ns/set-v0", **metadata)
    (data_dir / "main_data.hdf5").write_bytes(b"\x89HDF")
    dataset_id = None if case == "other" else "ns/set-v0"
    error = OSError("Unable to open file\n  (truncated file: eof = 4)")
    message = corrupt_dataset_message(data_dir, dataset_id, metadata, error)
    assert "\n" not in message and message.startswith(f"{data_dir / 'main_data.hdf5'} is truncated or corrupt")
    assert "Unable to open file (truncated file: eof = 4)" in message  # the cause on one line
    fixes = {
        "collect_command": "re-collect it with the command in its metadata: `sb3-pola collect --env Hopper-v5`",
        "shipped": "reinstall the package",
        "minari_id": "minari download --force ns/set-v0",
        "other": f"copy or re-create the dataset folder {data_dir.parent}",
    }
    assert fixes[case] in message
    assert sum(fix.split(":")[0] in message for fix in fixes.values()) == 1


def test_written_dataset_is_found_by_id_and_listed(make_dataset):
    """A real Minari dataset (episodes and all) is found the same way the fake ones above are."""
    dataset_id = make_dataset("test/real-v0", make_episodes())
    data_dir = resolve_dataset_path(dataset_id)
    assert (data_dir / paths.METADATA_FILE).is_file() and any(data_dir.glob("*.hdf5"))
    assert dataset_id in list_local_datasets()


def test_helper_writer_matches_the_layout(tmp_path):
    """The tests' writer makes the layout scan_datasets expects: ``<root>/<id>/data/metadata.json``."""
    write_minari_dataset(tmp_path, "ns/written-v0", make_episodes())
    assert list(scan_datasets(tmp_path)) == ["ns/written-v0"]
