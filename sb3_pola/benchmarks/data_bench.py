"""Data-layer benchmark: first (episode-by-episode) and cached load times, and memory.

``python -m sb3_pola.benchmarks.data_bench [--quick]``. Always measures synthetic HalfCheetah-shaped
Minari datasets written to a temporary folder: 100k and 1M steps (100k only with ``--quick``), so the
figures exist on any machine. In full mode the HalfCheetah datasets of ``$MINARI_DATASETS_PATH`` (or
``--datasets``) are measured as extra rows when present.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import pathlib
import resource
import shutil
import tempfile
import time
import tracemalloc
import warnings
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_pola.common.buffers import OfflineReplayBuffer
from sb3_pola.common.datasets import load_offline_dataset

SHARED = ("halfcheetah/medium-v0", "halfcheetah/medium-expert-v0")


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # kB on Linux


def _current_rss_mb() -> float:
    with open("/proc/self/statm") as file:
        return int(file.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def make_synthetic(root: pathlib.Path, n_steps: int, episode_len: int = 1000, obs_dim: int = 17, act_dim: int = 6) -> str:
    """Write a HalfCheetah-shaped random Minari dataset of ``n_steps`` steps under ``root``."""
    import minari
    from minari.data_collector import EpisodeBuffer

    rng = np.random.default_rng(0)
    buffers = []
    for ep in range(n_steps // episode_len):
        truncations = np.zeros(episode_len, bool)
        truncations[-1] = True
        buffers.append(
            EpisodeBuffer(
                id=ep,
                observations=rng.normal(size=(episode_len + 1, obs_dim)),
                actions=rng.uniform(-1, 1, size=(episode_len, act_dim)).astype(np.float32),
                rewards=rng.normal(size=episode_len),
                terminations=np.zeros(episode_len, bool),
                truncations=truncations,
            )
        )
    dataset_id = f"synthetic/steps{n_steps}-v0"
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        minari.create_dataset_from_buffers(
            dataset_id,
            buffers,
            observation_space=gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float64),
            action_space=gym.spaces.Box(-1, 1, (act_dim,), np.float32),
            data_format="hdf5",
        )
    return dataset_id


def measure(dataset: Any, cache_dir: pathlib.Path) -> dict[str, Any]:
    """Time a first load (cache empty) and a cached load; memory of the arrays and the process."""
    gc.collect()
    rss_before = _current_rss_mb()
    start, cpu_start = time.perf_counter(), time.process_time()
    data = load_offline_dataset(dataset, cache_dir=cache_dir)
    first, first_cpu = time.perf_counter() - start, time.process_time() - cpu_start
    rss_after_first = _current_rss_mb()
    del data
    gc.collect()
    start, cpu_start = time.perf_counter(), time.process_time()
    data = load_offline_dataset(dataset, cache_dir=cache_dir)
    cached, cached_cpu = time.perf_counter() - start, time.process_time() - cpu_start
    float32_bytes = sum(
        int(np.prod(getattr(data, n).shape)) * 4 for n in ("observations", "next_observations", "actions", "rewards", "dones")
    )
    # Python-level peak (numpy reports its buffers to tracemalloc) while building and while reloading
    peaks = {}
    for label, use_cache in (("build", False), ("cached", True)):
        del data
        gc.collect()
        tracemalloc.start()
        data = load_offline_dataset(dataset, cache_dir=cache_dir, use_cache=use_cache)
        peaks[label] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    rss_before_buffer = _current_rss_mb()
    buffer = OfflineReplayBuffer(data, device="cpu")
    buffer_extra_mb = _current_rss_mb() - rss_before_buffer
    return {
        "steps": len(data),
        "episodes": len(data.episode_returns),
        "first_load_s": round(first, 3),
        "cached_load_s": round(cached, 3),
        # CPU time of this process: the wall times above grow on a shared, overloaded machine
        "first_load_cpu_s": round(first_cpu, 3),
        "cached_load_cpu_s": round(cached_cpu, 3),
        "float32_mb": round(float32_bytes / 2**20, 1),
        "arrays_mb": round(data.nbytes / 2**20, 1),
        "arrays_over_float32": round(data.nbytes / float32_bytes, 3),
        "tracemalloc_peak_build_over_float32": round(peaks["build"] / float32_bytes, 3),
        "tracemalloc_peak_cached_over_float32": round(peaks["cached"] / float32_bytes, 3),
        "rss_growth_first_load_mb": round(rss_after_first - rss_before, 1),
        "buffer_extra_rss_mb": round(buffer_extra_mb, 1),
        "buffer_shares_memory": bool(np.shares_memory(buffer.observations.numpy(), data.observations)),
    }


def synthetic_sizes(quick: bool) -> tuple[int, ...]:
    """Steps of the synthetic datasets measured: 100k, and 1M in full mode."""
    return (100_000,) if quick else (100_000, 1_000_000)


def run(quick: bool = False, datasets_path: str | None = None) -> dict[str, Any]:
    """Run the benchmark; returns ``{dataset id: figures, ..., "process_maxrss_mb": peak RSS}``.

    :param quick: the synthetic 100k-step dataset only (no 1M, no local datasets)
    :param datasets_path: Minari root holding the HalfCheetah datasets (default ``$MINARI_DATASETS_PATH``),
        measured in full mode when present
    """
    results: dict[str, Any] = {}
    old_path = os.environ.get("MINARI_DATASETS_PATH")
    shared = datasets_path or old_path
    with tempfile.TemporaryDirectory(prefix="sb3_pola_bench_") as tmp:
        tmp_path = pathlib.Path(tmp)
        try:
            for n_steps in synthetic_sizes(quick):
                start = time.perf_counter()
                synthetic = make_synthetic(tmp_path / "minari", n_steps)
                write_s = time.perf_counter() - start
                figures = measure(tmp_path / "minari" / synthetic, tmp_path / "cache" / f"synthetic{n_steps}")
                figures["write_s"] = round(write_s, 1)
                results[synthetic] = figures
                shutil.rmtree(tmp_path / "minari" / synthetic, ignore_errors=True)  # 1M steps: ~250 MB of disk
            if shared and not quick:
                for dataset_id in SHARED:
                    folder = pathlib.Path(shared) / dataset_id
                    if folder.is_dir():
                        results[dataset_id] = measure(folder, tmp_path / "cache" / dataset_id.replace("/", "_"))
        finally:
            if old_path is None:
                os.environ.pop("MINARI_DATASETS_PATH", None)
            else:
                os.environ["MINARI_DATASETS_PATH"] = old_path
    results["process_maxrss_mb"] = round(_maxrss_mb(), 1)
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="the 100k-step synthetic dataset only")
    parser.add_argument("--datasets", default=None, help="Minari root with the HalfCheetah datasets")
    args = parser.parse_args(argv)
    print(json.dumps(run(args.quick, args.datasets), indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
