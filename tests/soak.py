"""Reliability harness: a resumable training worker, a kill-and-resume soak loop, and a peak-memory probe.

A test tool, not part of the package: ``tests/test_checkpoint.py`` runs short versions; the long runs are
not run in CI. Commands, from the repository's root::

    # hours of training with periodic checkpoints, SIGKILLed at random moments (some mid-write) and
    # resumed, each finished run compared bit for bit with one uninterrupted run:
    python tests/soak.py soak --minutes 120 --total 20000 --save-freq 500 --out soak_report.json

    # peak resident memory when training on a 2M-transition (HalfCheetah medium-expert sized) dataset:
    python tests/soak.py memory --n 2000000 --obs-dim 17 --act-dim 6 --steps 200

    # one training process (what the soak loop starts and kills):
    python tests/soak.py worker --dataset ID --dir runs/x --total 5000 --save-freq 100

Without ``--dataset`` the soak loop writes a small synthetic Minari dataset in a temp folder. Workers import
the package of this checkout afresh: run the soak from a checkout nobody edits (a changed source is detected,
such runs are reported as inconclusive and the reference is recomputed).

A worker is made to stop inside a checkpoint write (``--write-delay``) by patching, in its own process,
``os.replace`` (the temp file is complete, the rename has not happened) or ``torch.save`` (SB3 is writing the
zip): the library has no hook for it.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import random
import resource
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from typing import Any

from helpers import light_kwargs

# the checkout this file belongs to: its workers import that package (as ``python -m`` from the root would)
REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]

# helpers.light_kwargs (the tests' one light configuration) with what the soak needs on top: an EMA that starts
# late and skips steps, so a resume that gets its counters wrong shows
LIGHT_CONFIG: dict[str, Any] = {key: value for key, value in light_kwargs().items() if key not in ("seed", "device")} | dict(
    n_critics=2, batch_size=64, rollout_length=1, ema_start=20, ema_update_freq=2
)


def make_light_model(dataset: Any, seed: int = 0, **overrides: Any) -> Any:
    """POLA with :data:`LIGHT_CONFIG` on CPU and a decaying learning rate (a resume with a wrong schedule would show).

    :param dataset: what ``POLA(dataset=...)`` takes
    :param seed: random seed
    :param overrides: replace entries of :data:`LIGHT_CONFIG`
    """
    from sb3_pola.pola.pola import POLA

    config = {**LIGHT_CONFIG, **overrides}
    return POLA(
        "MlpPolicy", dataset=dataset, seed=seed, device="cpu", learning_rate=lambda p: 1e-3 * (0.1 + 0.9 * p), **config
    )


def slow_down_checkpoint_writes(stage: str, delay: float, marker: pathlib.Path) -> Callable[[], None]:
    """Make every checkpoint write of this process write ``marker`` and sleep ``delay`` seconds at ``stage``.

    :param stage: ``"before_replace"``: the temp file is complete, the rename has not happened (``os.replace``
        patched); ``"mid_zip"``: inside SB3's zip writing, the temp file is a truncated zip (``torch.save`` patched)
    :param delay: seconds to sleep there (the parent kills the process meanwhile)
    :param marker: file written when a write reaches ``stage``
    :return: undoes the patch
    """
    import torch as th

    def pause(where: str) -> None:
        marker.write_text(where)  # the parent kills us now
        time.sleep(delay)

    real_replace, real_save = os.replace, th.save

    def slow_replace(src: Any, dst: Any, *replace_args: Any, **replace_kwargs: Any) -> None:
        if str(src).endswith(".tmp.zip"):
            pause(str(src))
        real_replace(src, dst, *replace_args, **replace_kwargs)

    def slow_save(*save_args: Any, **save_kwargs: Any) -> None:
        pause("mid_zip")
        real_save(*save_args, **save_kwargs)

    if stage == "before_replace":
        os.replace = slow_replace
    else:
        th.save = slow_save

    def undo() -> None:
        os.replace, th.save = real_replace, real_save

    return undo


def pause_at(step: int, marker: pathlib.Path, delay: float = 600.0) -> Any:
    """A callback that, once training reaches gradient step ``step`` (its checkpoint, if any, written first), writes
    ``marker`` and sleeps ``delay`` seconds: the parent kills the process there, at a step it chose."""
    from stable_baselines3.common.callbacks import BaseCallback

    class PauseAt(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps == step:
                marker.write_text(str(step))
                time.sleep(delay)
            return True

    return PauseAt()


def run_worker(args: argparse.Namespace) -> int:
    """Train to ``--total`` steps, resuming from ``--dir`` if a checkpoint is there; save ``--final`` at the end."""
    import torch as th

    from sb3_pola.common import checkpoint
    from sb3_pola.pola.pola import POLA

    th.set_num_threads(1)
    undo: Callable[[], None] | None = None
    if args.write_delay > 0:
        undo = slow_down_checkpoint_writes(args.write_stage, args.write_delay, pathlib.Path(args.write_marker))
    model = checkpoint.learn_with_checkpoints(
        POLA,
        lambda: make_light_model(args.dataset, args.seed),
        total_timesteps=args.total,
        save_path=args.dir,
        save_freq=args.save_freq,
        load_kwargs=dict(dataset=args.dataset, device="cpu"),
        callback=pause_at(args.pause_at, pathlib.Path(args.pause_marker)) if args.pause_at is not None else None,
        log_interval=0,
    )
    if undo is not None:
        undo()
    if args.final:
        checkpoint.save_checkpoint(model, args.final)
    return 0


def worker_command(
    dataset: str,
    directory: str | os.PathLike,
    total: int,
    save_freq: int,
    seed: int = 0,
    final: str | os.PathLike | None = None,
) -> list[str]:
    """The command line of one worker process."""
    command = [sys.executable, str(pathlib.Path(__file__).resolve()), "worker", "--dataset", dataset, "--dir", str(directory)]
    command += ["--total", str(total), "--save-freq", str(save_freq), "--seed", str(seed)]
    if final is not None:
        command += ["--final", str(final)]
    return command


def compare_checkpoints(path_a: str | os.PathLike, path_b: str | os.PathLike) -> list[str]:
    """Differences between two checkpoints: every tensor of the policy and optimizers, the step counters, the RNG states.

    :return: names of what differs (empty: bit-identical)
    """
    import torch as th
    from stable_baselines3.common.save_util import load_from_zip_file

    from sb3_pola.common.checkpoint import read_rng_state

    data_a, params_a, _ = load_from_zip_file(pathlib.Path(path_a), device="cpu")
    data_b, params_b, _ = load_from_zip_file(pathlib.Path(path_b), device="cpu")
    assert data_a is not None and data_b is not None
    diffs = [key for key in ("num_timesteps", "_n_updates", "_total_timesteps") if data_a.get(key) != data_b.get(key)]

    def walk(a: Any, b: Any, name: str) -> None:
        if isinstance(a, dict) and isinstance(b, dict):
            if a.keys() != b.keys():
                diffs.append(f"{name} (keys)")
            for key in a.keys() & b.keys():
                walk(a[key], b[key], f"{name}.{key}")
        elif isinstance(a, list | tuple) and isinstance(b, list | tuple):
            if len(a) != len(b):
                diffs.append(f"{name} (length)")
            for i, (x, y) in enumerate(zip(a, b, strict=False)):
                walk(x, y, f"{name}[{i}]")
        elif isinstance(a, th.Tensor) and isinstance(b, th.Tensor):
            if a.dtype != b.dtype or a.shape != b.shape or not th.equal(a, b):
                diffs.append(name)
        elif a != b:
            diffs.append(name)

    walk(params_a, params_b, "params")
    walk(read_rng_state(path_a), read_rng_state(path_b), "rng")
    return diffs


def source_fingerprint() -> str:
    """SHA-256 of the package's Python sources: workers import them afresh, so an edit mid-soak changes the numbers."""
    import hashlib

    package = REPO_ROOT / "sb3_pola"
    digest = hashlib.sha256()
    for source in sorted(package.rglob("*.py")):
        digest.update(str(source.relative_to(package)).encode() + b"\0" + source.read_bytes())
    return digest.hexdigest()


def checkpoint_step(path: pathlib.Path) -> int | None:
    """The step of a valid checkpoint, ``None`` if there is none; raises if the file is broken."""
    from sb3_pola.common.integrity import validate_model_file

    if not path.is_file():
        return None
    return int(validate_model_file(path)["num_timesteps"])


def make_synthetic_minari(root: pathlib.Path, dataset_id: str = "soak/synthetic-v0", n_episodes: int = 20) -> str:
    """Write a small random Minari dataset (4-d observations, 2-d actions, no env) under ``root``."""
    import warnings

    import gymnasium as gym
    import minari
    import numpy as np
    from minari.data_collector import EpisodeBuffer

    rng = np.random.default_rng(0)
    buffers = []
    for episode in range(n_episodes):
        length = 50
        obs = np.cumsum(rng.normal(size=(length + 1, 4)), axis=0) * 0.1
        terminations = np.zeros(length, dtype=bool)
        truncations = np.zeros(length, dtype=bool)
        truncations[-1] = True
        buffers.append(
            EpisodeBuffer(
                id=episode,
                observations=obs,
                actions=rng.uniform(-1, 1, size=(length, 2)).astype(np.float32),
                rewards=rng.normal(size=length),
                terminations=terminations,
                truncations=truncations,
            )
        )
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        minari.create_dataset_from_buffers(
            dataset_id=dataset_id,
            buffer=buffers,
            observation_space=gym.spaces.Box(-np.inf, np.inf, (4,), np.float64),
            action_space=gym.spaces.Box(-1.0, 1.0, (2,), np.float32),
            algorithm_name="soak",
            data_format="hdf5",
        )
    return dataset_id


def _check_after_kill(report: dict[str, Any], mid_write: bool, run_dir: pathlib.Path, last_step: int) -> int:
    """Count a kill in ``report`` and check the run's latest checkpoint: intact, and not older than before.

    :param report: the soak's counters, updated
    :param mid_write: the kill landed inside a checkpoint write
    :param run_dir: the run's checkpoint folder
    :param last_step: the latest checkpoint's step before the kill
    :return: the latest checkpoint's step now
    """
    latest = run_dir / "pola_latest.zip"
    report["kills"] += 1
    report["kills_during_checkpoint_write"] += int(mid_write)
    report["stale_temp_files_left_by_kills"] += len(list(run_dir.glob(".*.tmp.zip")))
    try:
        step = checkpoint_step(latest) or 0
    except Exception as error:  # a broken latest file is exactly what must never happen
        report["broken_latest_files"] += 1
        print(f"BROKEN latest checkpoint after a kill: {error}", flush=True)
        latest.unlink()
        step = 0
    if step < last_step:
        report["checkpoint_step_regressions"] += 1
    return max(last_step, step)


def run_soak(args: argparse.Namespace) -> int:
    """Train, kill at random moments (a share of them inside a checkpoint write), resume, repeat; check nothing is lost."""
    work = pathlib.Path(args.workdir or tempfile.mkdtemp(prefix="sb3_pola_soak_"))
    work.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "SB3_POLA_CACHE_DIR": str(work / "cache")}
    dataset = args.dataset
    if dataset is None:
        dataset = make_synthetic_minari(work / "datasets")
        env["MINARI_DATASETS_PATH"] = str(work / "datasets")
    rng = random.Random(args.seed)
    deadline = time.monotonic() + 60 * args.minutes

    def reference_run(index: int) -> tuple[pathlib.Path, str, float]:
        start, code = time.monotonic(), source_fingerprint()
        path = work / f"reference_{index}.zip"
        command = worker_command(dataset, work / f"reference_run_{index}", args.total, args.save_freq, 0, path)
        subprocess.run(command, env=env, check=True)
        seconds = time.monotonic() - start
        print(f"uninterrupted reference run: {args.total} steps in {seconds:.1f} s (code {code[:12]})", flush=True)
        return path, code, seconds

    reference, reference_code, reference_time = reference_run(0)

    report: dict[str, Any] = dict(
        total_steps_per_run=args.total,
        save_freq=args.save_freq,
        reference_seconds=round(reference_time, 1),
        runs_completed=0,
        runs_identical=0,
        kills=0,
        kills_during_checkpoint_write=0,
        resumes=0,
        broken_latest_files=0,
        checkpoint_step_regressions=0,
        steps_lost=0,
        max_steps_redone_after_kill=0,
        stale_temp_files_left_by_kills=0,
        mismatches=[],
        runs_inconclusive_code_changed=0,
        references_recomputed_after_code_change=0,
    )
    run_index = 0
    while time.monotonic() < deadline:
        run_dir = work / f"run_{run_index}"
        final = work / f"final_{run_index}.zip"
        latest = run_dir / "pola_latest.zip"
        last_step = 0
        attempts = 0
        run_code = source_fingerprint()
        while time.monotonic() < deadline:
            attempts += 1
            if latest.is_file():
                report["resumes"] += 1
            during_write = rng.random() < args.write_kill_share
            command = worker_command(dataset, run_dir, args.total, args.save_freq, 0, final)
            marker = work / "writing"
            marker.unlink(missing_ok=True)
            if during_write:
                stage = rng.choice(["before_replace", "mid_zip"])
                command += ["--write-delay", "5", "--write-marker", str(marker), "--write-stage", stage]
            log = work / "worker.log"
            with open(log, "wb") as log_file:  # a file, not a pipe: a chatty worker must never block on it
                process = subprocess.Popen(command, env=env, stdout=log_file, stderr=subprocess.STDOUT)
            if during_write:
                # wait for a checkpoint write to reach its slow point, then kill inside it
                waited = 0.0
                while process.poll() is None and not marker.exists() and waited < reference_time + 60:
                    time.sleep(0.05)
                    waited += 0.05
            else:
                time.sleep(rng.uniform(0.2, args.max_kill_after or (reference_time + 5.0)))
            if process.poll() is None:
                process.send_signal(signal.SIGKILL)
                process.wait()
                last_step = _check_after_kill(report, during_write and marker.exists(), run_dir, last_step)
                continue
            stderr = log.read_text(errors="replace")
            if process.returncode != 0:
                print(f"worker failed (rc {process.returncode}):\n{stderr[-3000:]}", flush=True)
                report["mismatches"].append(f"run {run_index}: worker exited with {process.returncode}")
                break
            report["runs_completed"] += 1
            if source_fingerprint() != run_code:
                # the package's code changed while this run was killed and resumed: nothing to compare with
                report["runs_inconclusive_code_changed"] += 1
                print(f"run {run_index}: the code changed during the run, not compared", flush=True)
                break
            if run_code != reference_code:
                report["references_recomputed_after_code_change"] += 1
                reference, reference_code, _ = reference_run(report["references_recomputed_after_code_change"])
            diffs = compare_checkpoints(reference, final)
            if diffs:
                report["mismatches"].append(f"run {run_index}: {diffs[:10]}")
                report["steps_lost"] += args.total  # a run that differs counts as entirely lost
            else:
                report["runs_identical"] += 1
            final_step = checkpoint_step(final) or 0
            report["steps_lost"] += max(0, args.total - final_step)
            print(
                f"run {run_index}: finished after {attempts} starts, identical to the reference: {not diffs} "
                f"(kills so far {report['kills']}, {report['kills_during_checkpoint_write']} mid-write)",
                flush=True,
            )
            break
        run_index += 1
    report["max_steps_redone_after_kill"] = args.save_freq  # resume starts at the last checkpoint: < save_freq steps redone
    report["workdir"] = str(work)
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        pathlib.Path(args.out).write_text(text)
    ok = not report["mismatches"] and not report["broken_latest_files"] and not report["checkpoint_step_regressions"]
    return 0 if ok else 1


def _rss_bytes() -> int:
    with open("/proc/self/statm") as file:
        return int(file.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _peak_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux reports KiB


def run_memory(args: argparse.Namespace) -> int:
    """Peak resident memory of training on a synthetic dataset of ``--n`` transitions, by phase."""
    import gymnasium as gym
    import numpy as np
    import torch as th

    from sb3_pola.common.datasets import OfflineDataset
    from sb3_pola.pola.pola import POLA

    th.set_num_threads(1)
    n, obs_dim, act_dim = args.n, args.obs_dim, args.act_dim

    def synthetic(n: int) -> OfflineDataset:
        rng = np.random.default_rng(0)
        observations = rng.standard_normal((n, obs_dim), dtype=np.float32)
        next_observations = rng.standard_normal((n, obs_dim), dtype=np.float32)
        next_observations *= 0.1
        next_observations += observations
        return OfflineDataset(
            observations=observations,
            actions=rng.random((n, act_dim), dtype=np.float32) * 2.0 - 1.0,
            rewards=rng.standard_normal(n, dtype=np.float32),
            next_observations=next_observations,
            dones=(rng.random(n, dtype=np.float32) < 1e-3).astype(np.float32),
            observation_space=gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32),
            action_space=gym.spaces.Box(-1.0, 1.0, (act_dim,), np.float32),
            dataset_id="synthetic",
        )

    config = dict(LIGHT_CONFIG, rollout_length=args.rollout_length)
    if args.full_size:
        config = dict(rollout_length=args.rollout_length, dynamics_fit_kwargs=dict(max_epochs=1))
    # warm-up on 1,000 transitions: imports, allocator pools and lazily built modules are not the dataset's cost
    POLA("MlpPolicy", dataset=synthetic(1000), seed=0, device="cpu", **config).learn(2, log_interval=0)
    baseline = _rss_bytes()
    data = synthetic(n)
    phases = {"dataset": _peak_bytes()}
    model = POLA("MlpPolicy", dataset=data, seed=0, device="cpu", **config)
    phases["model"] = _peak_bytes()  # with its replay buffer (tensors sharing the dataset's arrays on CPU)
    model._setup_learn(args.steps)
    phases["replay_buffer"] = _peak_bytes()
    model._before_training()
    phases["dynamics_fit"] = _peak_bytes()
    model.learn(args.steps, log_interval=0)
    phases["training"] = _peak_bytes()
    n_params = sum(p.numel() for p in model.policy.parameters())
    network_bytes = 4 * n_params * 3  # weights, gradients and two Adam moments of the trained part, roughly
    dataset_bytes = data.nbytes
    budget = 1.5 * dataset_bytes + network_bytes
    report = {
        "transitions": n,
        "dataset_float32_bytes": dataset_bytes,
        "network_parameters": n_params,
        "network_bytes_estimate": network_bytes,
        "baseline_rss_bytes_after_warmup": baseline,
        "peak_rss_bytes_by_phase": phases,
        "peak_above_baseline_bytes": {k: v - baseline for k, v in phases.items()},
        "budget_bytes_1.5x_dataset_plus_networks": int(budget),
        "ratio_peak_above_baseline_to_dataset": {k: round((v - baseline) / dataset_bytes, 3) for k, v in phases.items()},
        "within_budget": {k: v - baseline <= budget for k, v in phases.items()},
    }
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        pathlib.Path(args.out).write_text(text)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python tests/soak.py", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    worker = sub.add_parser("worker", help="train to --total steps, resuming from --dir")
    worker.add_argument("--dataset", required=True)
    worker.add_argument("--dir", required=True)
    worker.add_argument("--total", type=int, required=True)
    worker.add_argument("--save-freq", type=int, default=100)
    worker.add_argument("--seed", type=int, default=0)
    worker.add_argument("--final", default=None)
    worker.add_argument("--write-delay", type=float, default=0.0, help="sleep inside every checkpoint write (tests)")
    worker.add_argument("--write-marker", default=None)
    worker.add_argument("--write-stage", choices=["before_replace", "mid_zip"], default="before_replace")
    worker.add_argument("--pause-at", type=int, default=None, help="sleep at this gradient step, to be killed (tests)")
    worker.add_argument("--pause-marker", default=None, help="file written when the pause starts")
    soak = sub.add_parser("soak", help="kill and resume in a loop, compare with an uninterrupted run")
    soak.add_argument("--minutes", type=float, default=60.0)
    soak.add_argument("--total", type=int, default=5000)
    soak.add_argument("--save-freq", type=int, default=250)
    soak.add_argument("--dataset", default=None)
    soak.add_argument("--write-kill-share", type=float, default=0.25, help="share of kills made inside a checkpoint write")
    soak.add_argument("--max-kill-after", type=float, default=None, help="longest wait before a kill, seconds")
    soak.add_argument("--seed", type=int, default=0)
    soak.add_argument("--workdir", default=None)
    soak.add_argument("--out", default=None)
    memory = sub.add_parser("memory", help="peak RSS of training on a synthetic dataset")
    memory.add_argument("--n", type=int, default=2_000_000)
    memory.add_argument("--obs-dim", type=int, default=17)
    memory.add_argument("--act-dim", type=int, default=6)
    memory.add_argument("--steps", type=int, default=200)
    memory.add_argument("--rollout-length", type=int, default=1)
    memory.add_argument("--full-size", action="store_true", help="the paper's network sizes instead of the light config")
    memory.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    return {"worker": run_worker, "soak": run_soak, "memory": run_memory}[args.command](args)


if __name__ == "__main__":
    sys.path.insert(0, str(REPO_ROOT))
    sys.exit(main())
