"""The on-disk cache of a dataset's arrays: one folder of ``.npy`` files per dataset, keyed by the dataset id, its
size and a fingerprint of its files and metadata (so a changed dataset never gets stale arrays), each array checked
against its CRC-32 when read.
"""

from __future__ import annotations

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

# Bump when the cached arrays change meaning: old caches are then never read.
CACHE_VERSION = 2
CACHE_MANIFEST = "manifest.json"
ARRAY_FIELDS = ("observations", "actions", "rewards", "next_observations", "dones", "episode_returns")


def fingerprint(data_dir: pathlib.Path, metadata: dict[str, Any]) -> str:
    """Hash of everything a cache entry depends on: file sizes and mtimes (ns), and the metadata."""
    digest = hashlib.sha256()
    digest.update(f"v{CACHE_VERSION}".encode())
    for path in sorted(p for p in data_dir.rglob("*") if p.is_file()):
        stat = path.stat()
        digest.update(f"{path.relative_to(data_dir).as_posix()}:{stat.st_size}:{stat.st_mtime_ns};".encode())
    digest.update(json.dumps(metadata, sort_keys=True, default=str).encode())
    return digest.hexdigest()


def cache_path(cache_dir: pathlib.Path, dataset_id: str | None, total_steps: int, fingerprint: str) -> pathlib.Path:
    safe_id = "".join(c if c.isalnum() or c in "-_." else "_" for c in (dataset_id or "dataset"))
    return cache_dir / f"{safe_id}-{total_steps}-{fingerprint[:24]}"


def _crc(array: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(array).view(np.uint8).reshape(-1).data)


def load_cache(path: pathlib.Path, n_steps: int, obs_dim: int, act_dim: int) -> dict[str, np.ndarray] | None:
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


def save_cache(path: pathlib.Path, arrays: dict[str, np.ndarray]) -> None:
    """Write the cache atomically: a temporary folder renamed into place; failures only warn."""
    tmp_dir = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp_dir = pathlib.Path(tempfile.mkdtemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp"))
        manifest = {}
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
