"""``sb3-pola peers``: d3rlpy baselines (TD3+BC, IQL, BC) on the same Minari datasets and evaluation protocol as ``score``.

d3rlpy 2.8.1 pins ``gymnasium==1.0.0``, which this package's environment does not have, so the
baselines run in a virtual environment of their own (``--venv``, default ``.venv-peers``, created
and filled on first use with :data:`PEER_REQUIREMENTS`). This command, in the package's
environment:

1. exports each dataset from :func:`~sb3_pola.common.datasets.load_offline_dataset` (the arrays
   POLA trains on: actions in [-1, 1], next observations of the same episode, terminations only)
   to ``<out>/peers_data/<dataset>.npz``, with the episode ends split into ``terminals`` and
   ``timeouts``, the action bounds, the env id and time limit and the reference scores
   (d3rlpy's own Minari loader is not used: it misaligns observations);
2. runs ``peers_worker.py`` with the peers venv's Python once per (dataset, algorithm, seed) cell:
   it builds a d3rlpy ``MDPDataset`` of exactly the exported transitions (checked, see the worker),
   trains with d3rlpy's hyperparameters and evaluates every ``--eval-freq`` steps with ``score``'s
   protocol, appending rows to ``<out>/peers.csv`` (``scores.csv``'s columns, variants
   ``d3rlpy-TD3+BC``, ``d3rlpy-IQL``, ``d3rlpy-BC``);
3. rewrites ``<out>/table.md`` and the figures (``score``'s reports, which add the baselines when
   ``peers.csv`` is there; ``--out`` defaults to ``score``'s folder for that reason).

Finished cells are skipped (``<out>/peers_cells/<cell>.json``); an interrupted cell continues from
its last evaluation (``<out>/peers_ckpt/<cell>.pkl``: model, optimisers, gradient step and random
states; the continued run matches an uninterrupted one), its later rows dropped.
``<out>/peers_config.json`` records the budget, the library versions of the peers venv and the
machine; ``<out>/peers_logs/`` the workers' output.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import time
from typing import Any

import numpy as np

from sb3_pola.grid.peers_worker import VARIANT_NAMES
from sb3_pola.grid.rows import slug

ALGOS = list(VARIANT_NAMES)
PEER_REQUIREMENTS = ["d3rlpy==2.8.1", "gymnasium[mujoco]==1.0.*", "torch==2.13.0"]
# Installed after PEER_REQUIREMENTS without their dependencies, for the point mazes of the Dict-observation
# datasets: Gymnasium-Robotics 1.3.1 (the last whose pins allow gymnasium 1.0) caps mujoco below 3.2, which
# would change the MuJoCo version the locomotion baselines are evaluated with; 1.4.2 declares gymnasium>=1.2
# but its point mazes run on gymnasium 1.0 (tests/test_peers.py builds one through the worker's make_env).
PEER_NO_DEPS_REQUIREMENTS = ["gymnasium-robotics==1.4.2", "pettingzoo==1.24.3"]
WORKER = pathlib.Path(__file__).resolve().parent / "peers_worker.py"
DEFAULT_VENV = ".venv-peers"


# ----------------------------------------------------------------------------------------- export


def episode_lengths(dataset_id: str) -> np.ndarray:
    """Length of each episode of a Minari dataset, in order (from the episodes' metadata, else their rewards)."""
    from minari.dataset.minari_storage import MinariStorage

    from sb3_pola.common.dataset_paths import resolve_dataset_path

    storage = MinariStorage.read(resolve_dataset_path(dataset_id))
    n_episodes = int(storage.metadata.get("total_episodes", storage.total_episodes))
    lengths = [meta.get("total_steps") for meta in storage.get_episode_metadata(range(n_episodes))]
    if any(length is None for length in lengths):
        lengths = [len(np.asarray(episode["rewards"]).reshape(-1)) for episode in storage.get_episodes(range(n_episodes))]
    return np.asarray(lengths, dtype=np.int64)


def export_arrays(data: Any, lengths: np.ndarray) -> dict[str, np.ndarray]:
    """The npz content of an :class:`~sb3_pola.common.datasets.OfflineDataset` with the given episode lengths.

    ``terminals`` are the dataset's ``dones`` (terminations); ``timeouts`` flag the last step of every
    episode that did not terminate (truncated, or cut by the end of the data), so each episode ends
    with exactly one of the two.

    :raises ValueError: lengths that do not cover the data, a termination inside an episode, or an
        episode whose next observations are not its own following observations
    """
    n = len(data)
    lengths = np.asarray(lengths, dtype=np.int64)
    if int(lengths.sum()) != n or np.any(lengths < 1):
        raise ValueError(f"episode lengths sum to {int(lengths.sum())}, the dataset has {n} transitions")
    ends = np.cumsum(lengths) - 1
    terminals = (np.asarray(data.dones) > 0).astype(np.float32)
    inside = np.ones(n, dtype=bool)
    inside[ends] = False
    if np.any(terminals[inside] > 0):
        raise ValueError(f"terminations inside episodes at steps {np.flatnonzero(terminals * inside)[:5].tolist()}")
    # within an episode, next_obs[t] is obs[t + 1]: the episode boundaries are right
    within = np.flatnonzero(inside)
    if not np.array_equal(data.next_observations[within], data.observations[within + 1]):
        bad = within[np.any(data.next_observations[within] != data.observations[within + 1], axis=1)]
        raise ValueError(f"next observations are not the following observations inside episodes (steps {bad[:5].tolist()})")
    timeouts = np.zeros(n, dtype=np.float32)
    timeouts[ends] = 1.0 - terminals[ends]
    # the env score evaluates in: the eval_env_spec where the dataset has one (the mazes' fixed goal)
    spec_json = data.metadata.get("eval_env_spec") or data.metadata.get("env_spec")
    spec = json.loads(spec_json) if spec_json else {}
    dict_keys = list(data.dict_observation_space.spaces) if data.dict_observation_space is not None else []
    env_id = spec.get("id") or data.env_id or ""
    return {
        "observations": np.ascontiguousarray(data.observations, dtype=np.float32),
        "actions": np.ascontiguousarray(data.actions, dtype=np.float32),
        "rewards": np.ascontiguousarray(data.rewards, dtype=np.float32),
        "next_observations": np.ascontiguousarray(data.next_observations, dtype=np.float32),
        "terminals": terminals,
        "timeouts": timeouts,
        "episode_lengths": lengths,
        "episode_returns": np.asarray(data.episode_returns, dtype=np.float64),
        "action_low": np.asarray(data.action_space.low, dtype=np.float64),
        "action_high": np.asarray(data.action_space.high, dtype=np.float64),
        "dataset_id": np.array(data.dataset_id or ""),
        "env_id": np.array(env_id),
        "env_kwargs": np.array(json.dumps(spec.get("kwargs") or {})),
        "max_episode_steps": np.array(int(spec.get("max_episode_steps") or 0)),
        # Dict observations: flattened in this key order (the order of the arrays above)
        "dict_keys": np.array(json.dumps(dict_keys)),
        "ref_min_score": np.array(np.nan if data.ref_min_score is None else data.ref_min_score),
        "ref_max_score": np.array(np.nan if data.ref_max_score is None else data.ref_max_score),
    }


def export_dataset(dataset_id: str, path: pathlib.Path) -> pathlib.Path:
    """Write ``dataset_id``'s arrays (:func:`export_arrays`) to ``path`` (an ``.npz``), atomically."""
    from sb3_pola.common.datasets import load_offline_dataset

    data = load_offline_dataset(dataset_id)
    arrays = export_arrays(data, episode_lengths(dataset_id))
    if not str(arrays["env_id"]):
        raise ValueError(f"dataset {dataset_id!r} records no environment (env_spec): the baselines cannot be evaluated")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez(tmp, **arrays)  # type: ignore[arg-type]
    tmp.replace(path)
    return path


# ----------------------------------------------------------------------------------------- the peers venv


def venv_python(venv: pathlib.Path) -> pathlib.Path:
    return venv / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


def ensure_venv(venv: pathlib.Path, python: str = sys.executable, verbose: int = 1) -> pathlib.Path:
    """The peers venv's Python: the venv is created and :data:`PEER_REQUIREMENTS` installed unless its stamp says so."""
    stamp = venv / ".peers-installed"
    wanted = "\n".join([*PEER_REQUIREMENTS, *(f"{r} --no-deps" for r in PEER_NO_DEPS_REQUIREMENTS)])
    if stamp.is_file() and stamp.read_text() == wanted and venv_python(venv).exists():
        return venv_python(venv)
    if not venv_python(venv).exists():
        if verbose:
            print(f"[peers] creating {venv}")
        subprocess.run([python, "-m", "venv", str(venv)], check=True)
    if verbose:
        print(f"[peers] installing {' '.join(PEER_REQUIREMENTS)} into {venv}")
    subprocess.run([str(venv_python(venv)), "-m", "pip", "install", "-q", *PEER_REQUIREMENTS], check=True)
    subprocess.run([str(venv_python(venv)), "-m", "pip", "install", "-q", "--no-deps", *PEER_NO_DEPS_REQUIREMENTS], check=True)
    stamp.write_text(wanted)
    return venv_python(venv)


def peer_versions(python: pathlib.Path) -> dict[str, str]:
    """Library versions of the peers venv (as the worker reports them)."""
    result = subprocess.run([str(python), str(WORKER), "--versions"], check=True, capture_output=True, text=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


# ----------------------------------------------------------------------------------------- cells


def cell_name(dataset: str, algo: str, seed: int) -> str:
    return f"{slug(dataset)}__d3rlpy-{algo}__seed{seed}"


def worker_env(threads: int) -> dict[str, str]:
    """The worker's environment: one BLAS/OpenMP thread per torch thread, nothing of this venv's Python path."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        env[name] = str(threads)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def run_cell(
    python: pathlib.Path,
    npz: pathlib.Path,
    dataset: str,
    algo: str,
    seed: int,
    args: argparse.Namespace,
    out: pathlib.Path,
) -> dict[str, Any]:
    """Run one cell in the peers venv; its rows go to ``<out>/peers.csv``, its marker to ``<out>/peers_cells/``.

    The worker resumes from ``<out>/peers_ckpt/<cell>.pkl`` if an interrupted run left one, and drops the
    cell's rows that its checkpoint does not cover.
    """
    name = cell_name(dataset, algo, seed)
    csv_path = out / "peers.csv"
    log_dir, cells = out / "peers_logs", out / "peers_cells"
    log_dir.mkdir(parents=True, exist_ok=True)
    cells.mkdir(parents=True, exist_ok=True)
    result = cells / f"{name}.running.json"
    command = [str(python), str(WORKER), "--npz", str(npz), "--algo", algo, "--seed", str(seed)]
    command += ["--steps", str(args.steps), "--eval-freq", str(args.eval_freq), "--eval-episodes", str(args.eval_episodes)]
    command += ["--csv", str(csv_path), "--dataset", dataset, "--result", str(result), "--threads", str(args.threads)]
    command += ["--ckpt", str(out / "peers_ckpt" / f"{name}.pkl")]
    start = time.perf_counter()
    with (log_dir / f"{name}.log").open("a") as log:
        process = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=worker_env(args.threads)
        )
        assert process.stdout is not None
        for line in process.stdout:
            log.write(line)
            log.flush()
            if args.verbose and line.startswith("[peers]"):
                print(line, end="", flush=True)
        code = process.wait()
    if code != 0:
        raise RuntimeError(f"[peers] {name} failed (exit code {code}): see {log_dir / f'{name}.log'}")
    info = json.loads(result.read_text())
    info["process_wall_s"] = round(time.perf_counter() - start, 1)
    (cells / f"{name}.json").write_text(json.dumps(info, indent=1))
    result.unlink()
    return info
