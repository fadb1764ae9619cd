"""The on-disk cache of a dataset's arrays: one folder of ``.npy`` files per dataset, keyed by the dataset id, its
size and a fingerprint of its content (the bytes of its files and its metadata: a changed dataset never gets stale
arrays, and a reinstall or a copy, with new file times, finds its entry again), each array checked against its CRC-32
when read. :func:`cache_entries` lists the entries with what each is for, :func:`prune_cache` removes the unused ones.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pathlib
import shutil
import tempfile
import warnings
import zlib
from typing import Any

import numpy as np

# Bump when the cached arrays change meaning: old caches are then never read (and `datasets --cache --prune` removes them).
CACHE_VERSION = 3
CACHE_MANIFEST = "manifest.json"
ARRAY_FIELDS = ("observations", "actions", "rewards", "next_observations", "dones", "episode_returns")
# memo of the files' digests by (path, size, mtime): a second load does not hash the files again
DIGEST_INDEX = "file_digests.json"
_INDEX_LIMIT = 2000


def file_digest(path: pathlib.Path) -> str:
    """BLAKE2b of a file's bytes (read in 1 MiB chunks)."""
    digest = hashlib.blake2b(digest_size=20)
    with open(path, "rb") as file:
        for chunk in iter(lambda: file.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def read_digest_index(cache_dir: pathlib.Path) -> dict[str, str]:
    """The memo of file digests (empty if missing or unreadable)."""
    try:
        index = json.loads((cache_dir / DIGEST_INDEX).read_text())
    except (OSError, ValueError):
        return {}
    return index if isinstance(index, dict) else {}


def write_digest_index(cache_dir: pathlib.Path, new: dict[str, str]) -> None:
    """Add ``new`` digests to the memo (atomically; the newest :data:`_INDEX_LIMIT` kept; failures ignored)."""
    index = read_digest_index(cache_dir)
    if all(index.get(key) == value for key, value in new.items()):
        return
    index.update(new)
    index = dict(list(index.items())[-_INDEX_LIMIT:])
    try:
        cache_dir.mkdir(parents=True, exist_ok=True)
        tmp = cache_dir / f"{DIGEST_INDEX}.{os.getpid()}.tmp"
        tmp.write_text(json.dumps(index))
        os.replace(tmp, cache_dir / DIGEST_INDEX)
    except OSError:
        pass


def fingerprint(
    data_dir: pathlib.Path, metadata: dict[str, Any], index: dict[str, str] | None = None
) -> tuple[str, dict[str, str]]:
    """Hash of everything a cache entry depends on: the bytes of the dataset's files, and its metadata.

    File times play no part, so that a reinstall (new times, same bytes) finds the same entry.

    :param data_dir: the dataset's ``data`` folder
    :param metadata: its metadata
    :param index: digests already known, by ``"<path>:<size>:<mtime ns>"`` (:func:`read_digest_index`)
    :return: the fingerprint, and the digests of this dataset's files by the same keys (to remember)
    """
    digest = hashlib.sha256()
    digest.update(f"v{CACHE_VERSION}".encode())
    digests = {}
    for path in sorted(p for p in data_dir.rglob("*") if p.is_file()):
        stat = path.stat()
        key = f"{path.resolve()}:{stat.st_size}:{stat.st_mtime_ns}"
        digests[key] = (index or {}).get(key) or file_digest(path)
        digest.update(f"{path.relative_to(data_dir).as_posix()}:{stat.st_size}:{digests[key]};".encode())
    digest.update(json.dumps(metadata, sort_keys=True, default=str).encode())
    return digest.hexdigest(), digests


def cache_path(cache_dir: pathlib.Path, dataset_id: str | None, total_steps: int, fingerprint: str) -> pathlib.Path:
    safe_id = "".join(c if c.isalnum() or c in "-_." else "_" for c in (dataset_id or "dataset"))
    return cache_dir / f"{safe_id}-{total_steps}-{fingerprint[:24]}"


def _crc(array: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(array).view(np.uint8).reshape(-1).data)


def load_cache(path: pathlib.Path, n_steps: int, obs_dim: int, act_dim: int) -> dict[str, np.ndarray] | None:
    """Arrays from a cache folder (see :func:`read_cache`); a hit marks the entry as used now."""
    arrays = read_cache(path, n_steps, obs_dim, act_dim)
    if arrays is not None:
        with contextlib.suppress(OSError):
            os.utime(path / CACHE_MANIFEST)  # last use, for `sb3-pola datasets --cache`
    return arrays


def read_cache(path: pathlib.Path, n_steps: int, obs_dim: int, act_dim: int) -> dict[str, np.ndarray] | None:
    """Arrays from a cache folder, or None if missing or unusable (unreadable, shape or CRC-32 mismatch).

    One ``.npy`` per array (``np.load`` reads them with a single ``fromfile``, several times
    faster than an ``.npz``) plus ``manifest.json`` with each array's shape and CRC-32.
    """
    manifest_file = path / CACHE_MANIFEST
    if not manifest_file.is_file():
        return None
    expected_shapes = {
        "observations": (n_steps, obs_dim),
        "next_observations": (n_steps, obs_dim),
        "actions": (n_steps, act_dim),
        "rewards": (n_steps,),
        "dones": (n_steps,),
    }
    try:
        manifest = json.loads(manifest_file.read_text())
        arrays = {}
        for name in ARRAY_FIELDS:
            array = np.load(path / f"{name}.npy", allow_pickle=False)
            entry = manifest[name]
            dtype = np.float64 if name == "episode_returns" else np.float32
            shape = expected_shapes.get(name, tuple(entry["shape"]))
            if array.dtype != dtype or array.shape != shape or list(array.shape) != entry["shape"]:
                raise ValueError(f"{name} is {array.dtype} {array.shape}, expected {np.dtype(dtype)} {shape}")
            if _crc(array) != entry["crc32"]:
                raise ValueError(f"{name} fails its CRC-32 check")
            arrays[name] = array
    except (OSError, ValueError, KeyError, TypeError, EOFError) as error:
        warnings.warn(f"Corrupt dataset cache {path} ({error}): rebuilding it")
        return None
    return arrays


def save_cache(path: pathlib.Path, arrays: dict[str, np.ndarray], about: dict[str, Any] | None = None) -> None:
    """Write the cache atomically: a temporary folder renamed into place; failures only warn.

    :param path: the entry's folder
    :param arrays: the arrays
    :param about: what the manifest records besides the arrays (``dataset_id``, ``source`` folder, ``fingerprint``)
    """
    tmp_dir = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp_dir = pathlib.Path(tempfile.mkdtemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp"))
        manifest: dict[str, Any] = {"about": about or {}}
        for name, array in arrays.items():
            np.save(tmp_dir / f"{name}.npy", array, allow_pickle=False)
            manifest[name] = {"shape": list(array.shape), "dtype": str(array.dtype), "crc32": _crc(array)}
        (tmp_dir / CACHE_MANIFEST).write_text(json.dumps(manifest))
        if path.exists():  # a corrupt entry being rebuilt (a valid one is never rewritten)
            shutil.rmtree(path, ignore_errors=True)
        try:
            os.replace(tmp_dir, path)
            tmp_dir = None
        except OSError:
            if not (path / CACHE_MANIFEST).is_file():  # else another process wrote the same entry first
                raise
    except OSError as error:
        warnings.warn(f"Could not write dataset cache {path}: {error}")
    finally:
        if tmp_dir is not None:
            shutil.rmtree(tmp_dir, ignore_errors=True)


# --------------------------------------------------------------------------- listing and pruning


def folder_size(path: pathlib.Path) -> int:
    """Bytes of the files below ``path`` (or of ``path`` itself)."""
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def cache_entries(cache_dir: pathlib.Path) -> list[dict[str, Any]]:
    """The dataset-array entries of a cache folder, each with what it is for and whether it is still of use.

    :param cache_dir: the cache root
    :return: one dict per entry: ``path``, ``kind`` (``"arrays"``), ``dataset_id``, ``bytes``, ``last_used``
        (a timestamp), ``stale`` (why the entry is of no more use, or ``""``)
    """
    entries: list[dict[str, Any]] = []
    if not cache_dir.is_dir():
        return entries
    index = read_digest_index(cache_dir)
    for path in sorted(p for p in cache_dir.iterdir() if p.is_dir() and p.name != "dynamics"):
        manifest_file = path / CACHE_MANIFEST
        try:
            manifest = json.loads(manifest_file.read_text())
            about = manifest.get("about") or {}
        except (OSError, ValueError, AttributeError):
            manifest, about = {}, {}
        stale = ""
        source = pathlib.Path(about["source"]) if about.get("source") else None
        if not manifest:
            stale = "unreadable or unfinished"
        elif not about.get("fingerprint"):
            stale = "older cache format"
        elif source is None or not (source / "metadata.json").is_file():
            stale = "its dataset is gone"
        else:
            try:
                current, _ = fingerprint(source, json.loads((source / "metadata.json").read_text()), index)
            except (OSError, ValueError):
                current = ""
            if current != about["fingerprint"]:
                stale = "its dataset has changed"
        entries.append(
            {
                "path": path,
                "kind": "arrays",
                "dataset_id": about.get("dataset_id") or path.name,
                "bytes": folder_size(path),
                "last_used": (manifest_file if manifest_file.exists() else path).stat().st_mtime,
                "stale": stale,
            }
        )
    return entries


def remove_entry(path: pathlib.Path) -> None:
    """Delete a cache entry (a folder or a file, with its ``.json`` sidecar if any)."""
    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)
        path.with_suffix(".json").unlink(missing_ok=True)
