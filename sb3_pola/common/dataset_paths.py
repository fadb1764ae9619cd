"""Where datasets are: the folders searched for Minari datasets, an id or a path resolved to its ``data`` folder,
its metadata, and the errors (and the one-line advice) for a dataset that is missing or cannot be read."""

from __future__ import annotations

import json
import os
import pathlib
import re
from typing import TYPE_CHECKING, Any, TypeAlias

import gymnasium as gym

from sb3_pola.common.errors import UserError

if TYPE_CHECKING:
    from minari import MinariDataset

# a dataset on disk: a Minari id, a dataset folder (``os.PathLike`` or a path string) or a ``minari.MinariDataset``
DatasetLocation: TypeAlias = "str | os.PathLike[str] | MinariDataset"

METADATA_FILE = "metadata.json"


class DatasetError(UserError, ValueError):
    """A dataset that cannot be used (unknown id, wrong spaces, bad values...)."""


class DatasetNotFoundError(DatasetError, FileNotFoundError):
    """No local dataset with the given id or path."""


class SpaceMismatchError(DatasetError):
    """The dataset's spaces do not match the environment's."""


class DatasetCorruptError(DatasetError):
    """A dataset file that cannot be read (truncated, damaged); the message names the file and how to get it back."""


def package_datasets_dir() -> pathlib.Path:
    """Folder of the datasets shipped with the package (``sb3_pola/data/datasets``)."""
    return pathlib.Path(__file__).resolve().parent.parent / "data" / "datasets"


def minari_datasets_dir() -> pathlib.Path:
    """Minari's local datasets root, computed without creating it (minari's own helper does)."""
    path = os.environ.get("MINARI_DATASETS_PATH")
    return pathlib.Path(path) if path else pathlib.Path.home() / ".minari" / "datasets"


def minari_root_label() -> str:
    """Minari's folder as messages name it: ``(MINARI_DATASETS_PATH)`` only when that variable chose it."""
    root = minari_datasets_dir()
    if os.environ.get("MINARI_DATASETS_PATH"):
        return f"{root} (MINARI_DATASETS_PATH)"
    missing = "" if root.is_dir() else ", not created yet"
    return f"{root} (Minari's default{missing}; set MINARI_DATASETS_PATH for another)"


# a Minari dataset id ends in its version: ``halfcheetah/medium-v0``
MINARI_ID = re.compile(r"-v\d+$")


# --------------------------------------------------------------------------- locating datasets


def _data_dir(path: pathlib.Path) -> pathlib.Path | None:
    """The Minari ``data`` folder for ``path`` (the dataset folder or ``data`` itself), or None."""
    if (path / "data" / METADATA_FILE).is_file():
        return path / "data"
    if (path / METADATA_FILE).is_file():
        return path
    return None


def scan_datasets(root: pathlib.Path) -> dict[str, pathlib.Path]:
    """Dataset ids -> data folders under a datasets root (ids are paths relative to the root)."""
    found: dict[str, pathlib.Path] = {}
    if not root.is_dir():
        return found
    for metadata_file in sorted(root.rglob(f"data/{METADATA_FILE}")):
        data_dir = metadata_file.parent
        found.setdefault(data_dir.parent.relative_to(root).as_posix(), data_dir)
    return found


def search_roots() -> list[pathlib.Path]:
    return [minari_datasets_dir(), package_datasets_dir()]


def list_local_datasets() -> list[str]:
    """Ids of the datasets in the Minari folder and those shipped with the package (sorted, unique)."""
    ids: set[str] = set()
    for root in search_roots():
        ids.update(scan_datasets(root))
    return sorted(ids)


def _find_dataset_id(dataset_id: str) -> pathlib.Path | None:
    for root in search_roots():
        data_dir = _data_dir(root / dataset_id)
        if data_dir is not None:
            return data_dir
    return None


def resolve_dataset_path(dataset: DatasetLocation, download: bool = False) -> pathlib.Path:
    """The ``data`` folder of a dataset given by id, path or ``MinariDataset``.

    :param dataset: Minari id, local folder, or ``minari.MinariDataset``
    :param download: download a missing id from the Minari server
    :return: path of the folder that holds ``metadata.json``
    """
    storage = getattr(dataset, "storage", None)
    if storage is not None and hasattr(storage, "data_path"):
        return pathlib.Path(storage.data_path)
    if isinstance(dataset, os.PathLike) or (isinstance(dataset, str) and os.path.isdir(dataset)):
        path = pathlib.Path(dataset)
        data_dir = _data_dir(path) if path.is_dir() else None
        if data_dir is not None:
            return data_dir
        if isinstance(dataset, os.PathLike) or os.path.isabs(dataset):
            if not path.exists():
                raise DatasetNotFoundError(f"No such folder {path}: a dataset path must be a Minari dataset folder")
            raise DatasetNotFoundError(f"{path} is not a Minari dataset folder (no data/{METADATA_FILE} in it)")
    if not isinstance(dataset, str):
        raise TypeError(f"dataset must be a Minari id, a path or a MinariDataset, not {type(dataset).__name__}")
    data_dir = _find_dataset_id(dataset)
    if data_dir is None and download:
        import minari

        minari.download_dataset(dataset)
        data_dir = _find_dataset_id(dataset)
    if data_dir is None:
        local = list_local_datasets()
        listing = f"Local datasets: {', '.join(local) if local else 'none'}."
        if os.path.isabs(dataset) or dataset.startswith((".", "~")) or not MINARI_ID.search(dataset):
            # a path, or at least not an id that Minari could download
            raise DatasetNotFoundError(
                f"Unknown dataset {dataset!r}: no such folder, and not a Minari dataset id (ids end in -v<N>, e.g. "
                f"invertedpendulum/medium-v0). {listing}"
            )
        raise DatasetNotFoundError(
            f"Unknown dataset {dataset!r}: not in {minari_root_label()} nor in the package's {package_datasets_dir()}. "
            f"{listing} Download it with `minari download {dataset}` or load_offline_dataset(..., download=True), "
            "or make one with `sb3-pola collect`."
        )
    return data_dir


def read_metadata(data_dir: pathlib.Path) -> dict[str, Any]:
    with open(data_dir / METADATA_FILE) as file:
        return json.load(file)


def metadata_env_id(metadata: dict[str, Any]) -> str | None:
    spec = metadata.get("env_spec")
    if not spec:
        return None
    try:
        return json.loads(spec)["id"] if isinstance(spec, str) else spec.get("id")
    except (ValueError, KeyError, TypeError):
        return None


def metadata_spaces(metadata: dict[str, Any], data_dir: pathlib.Path) -> tuple[gym.Space, gym.Space]:
    from minari.dataset.minari_storage import MinariStorage
    from minari.serialization import deserialize_space

    if "observation_space" in metadata and "action_space" in metadata:
        return deserialize_space(metadata["observation_space"]), deserialize_space(metadata["action_space"])
    storage = MinariStorage.read(data_dir)  # recovers spaces from the env spec
    return storage.observation_space, storage.action_space


def corrupt_dataset_message(data_dir: pathlib.Path, dataset_id: str | None, metadata: dict[str, Any], error: Exception) -> str:
    """One line naming a dataset file that cannot be read, and how to get a good copy back.

    :param data_dir: the dataset's ``data`` folder
    :param dataset_id: its id, if known
    :param metadata: its metadata (``collect_command``: the command that recorded it)
    :param error: what reading it raised
    :return: the message
    """
    files = sorted(data_dir.glob("*.hdf5")) or sorted(p for p in data_dir.iterdir() if p.name != METADATA_FILE)
    file = files[0] if files else data_dir
    cause = " ".join(str(error).split())[:200] or type(error).__name__
    if metadata.get("collect_command"):
        fix = f"re-collect it with the command in its metadata: `{metadata['collect_command']}` (with --overwrite)"
    elif data_dir.resolve().is_relative_to(package_datasets_dir()):
        fix = (
            "it ships with sb3_pola: reinstall the package (`pip install --force-reinstall sb3_pola`; in a clone, "
            "`git checkout -- sb3_pola/data`)"
        )
    elif dataset_id and MINARI_ID.search(dataset_id):
        fix = f"re-download it with `minari download --force {dataset_id}` if it is one of Minari's, else re-create it"
    else:
        fix = f"copy or re-create the dataset folder {data_dir.parent} again"
    return f"{file} is truncated or corrupt, dataset {dataset_id!r} cannot be read ({cause}): {fix}"
