"""Writing recorded episodes as a Minari dataset with reference scores (D4RL's normalisation), and its summary."""

from __future__ import annotations

import contextlib
import json
import os
import pathlib
import shlex
import shutil
import sys
import tempfile
from collections.abc import Iterator
from typing import Any

import numpy as np
from gymnasium.envs.registration import EnvSpec

MIN_REF_EPISODES = 10


@contextlib.contextmanager
def _env_var(name: str, value: str) -> Iterator[None]:
    old = os.environ.get(name)
    os.environ[name] = value
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = old


def default_name(env_id: str) -> str:
    """``InvertedPendulum-v5`` -> ``invertedpendulum``."""
    return env_id.split("/")[-1].rsplit("-v", 1)[0].lower()


def _repack(data_dir: pathlib.Path, extra_metadata: dict[str, Any] | None = None) -> None:
    """Rewrite minari's HDF5 file with contiguous datasets (and add ``extra_metadata`` to its metadata).

    Minari writes every episode's arrays as resizable chunked datasets, ~14 kB of overhead per
    episode; contiguous ones need ~2 kB, which keeps short-episode datasets (random,
    medium-replay) several times smaller. The layout is the same, so minari reads it as before.
    """
    import h5py

    src = data_dir / "main_data.hdf5"
    tmp = data_dir / "main_data.hdf5.tmp"

    def copy_group(group_in: Any, group_out: Any) -> None:
        group_out.attrs.update(group_in.attrs)
        for key, value in group_in.items():
            if isinstance(value, h5py.Group):
                copy_group(value, group_out.create_group(key, track_order=True))
            else:
                group_out.create_dataset(key, data=value[()])

    with h5py.File(src, "r") as file_in, h5py.File(tmp, "w", track_order=True) as file_out:
        copy_group(file_in, file_out)
    os.replace(tmp, src)
    metadata_file = data_dir / "metadata.json"
    metadata = json.loads(metadata_file.read_text())
    metadata.update(extra_metadata or {})
    metadata["dataset_size"] = round(src.stat().st_size / 1e6, 1)  # MB, as minari computes it
    metadata_file.write_text(json.dumps(metadata))


def write_dataset(
    out_root: pathlib.Path,
    dataset_id: str,
    episodes: list[Any],
    env_id: str | EnvSpec,
    ref_min: float,
    ref_max: float,
    ref_episodes: int,
    algorithm_name: str,
    description: str,
    overwrite: bool,
    eval_env: str | EnvSpec | None = None,
    extra_metadata: dict[str, Any] | None = None,
    code_permalink: str = "sb3_pola/collect/mujoco.py",
) -> pathlib.Path:
    """Create the Minari dataset in a temporary root, then move it in place (no half-written dataset).

    :param env_id: the env the data was recorded in (id or spec: its ``env_spec``)
    :param eval_env: the env to evaluate in (its ``eval_env_spec``); default ``env_id``
    :param extra_metadata: more keys for ``metadata.json``
    :param code_permalink: the code that made the data
    """
    import minari

    target = out_root / dataset_id
    if target.exists():
        if not overwrite:
            raise FileExistsError(f"{target} exists: pass --overwrite to replace it")
        shutil.rmtree(target)
    out_root.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out_root, prefix=".collect-") as tmp, _env_var("MINARI_DATASETS_PATH", tmp):
        minari.create_dataset_from_buffers(
            dataset_id=dataset_id,
            buffer=episodes,
            env=env_id,
            eval_env=env_id if eval_env is None else eval_env,
            algorithm_name=algorithm_name,
            author="sb3-pola collect",
            author_email="none@example.org",
            code_permalink=code_permalink,
            ref_min_score=ref_min,
            ref_max_score=ref_max,
            num_episodes_average_score=ref_episodes,
            description=description,
            data_format="hdf5",
        )
        _repack(pathlib.Path(tmp) / dataset_id / "data", {**collect_command(), **(extra_metadata or {})})
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(pathlib.Path(tmp) / dataset_id, target)
        if "/" in dataset_id:  # minari's namespace file, which `minari list local` expects
            namespace = dataset_id.split("/")[0]
            ns_file = pathlib.Path(tmp) / namespace / "namespace_metadata.json"
            if ns_file.exists() and not (out_root / namespace / ns_file.name).exists():
                shutil.copy(ns_file, out_root / namespace / ns_file.name)
    return target


def collect_command() -> dict[str, str]:
    """``{"collect_command": "sb3-pola collect ..."}``, the command that is recording the dataset, for its metadata
    (a corrupt copy is then re-collected with it, see :func:`~sb3_pola.common.dataset_paths.corrupt_dataset_message`);
    empty when not run as ``sb3-pola collect``."""
    argv = sys.argv[1:]
    if not argv or argv[0] != "collect":
        return {}
    return {"collect_command": shlex.join(["sb3-pola", *argv])}


def dataset_summary(path: pathlib.Path, episodes: list[Any]) -> dict[str, Any]:
    """Path, steps, episodes, mean return and size on disk of a written dataset, for the printed summary."""
    returns = [float(np.sum(e.rewards)) for e in episodes]
    return {
        "path": str(path),
        "steps": int(sum(len(e.rewards) for e in episodes)),
        "episodes": len(episodes),
        "mean_return": float(np.mean(returns)),
        "bytes": sum(p.stat().st_size for p in path.rglob("*") if p.is_file()),
    }


def datasets_root(out: str | None) -> pathlib.Path:
    """``--out``, else ``$MINARI_DATASETS_PATH``, else ``~/.minari/datasets``, as an absolute path."""
    root = pathlib.Path(out or os.environ.get("MINARI_DATASETS_PATH") or pathlib.Path.home() / ".minari" / "datasets")
    return root.expanduser().resolve()  # minari mangles relative dataset paths (get_size joins them twice)
