"""Checkpoints: determinism, exact resume after a crash or a SIGKILL (also mid-write), atomic writes, the divergence guard."""

from __future__ import annotations

import os
import pathlib
import re
import signal
import subprocess
import time
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from soak import compare_checkpoints, make_light_model, worker_command
from stable_baselines3.common.callbacks import ConvertCallback

from sb3_pola.common import checkpoint
from sb3_pola.common.checkpoint import (
    CheckpointCallback,
    learn_with_checkpoints,
    load_checkpoint,
    load_module_state,
    load_or_make,
    save_checkpoint,
    save_module_state,
)
from sb3_pola.common.datasets import OfflineDataset
from sb3_pola.common.integrity import DivergenceError, ModelFileError, validate_model_file
from sb3_pola.pola.pola import POLA

make_model = make_light_model  # POLA, light config, CPU, decaying learning rate: what the soak workers train


def assert_same_training_state(a: POLA, b: POLA) -> None:
    """Policy (actor, EMA, critics, targets, dynamics), both optimizers and the counters are bit-identical."""
    assert (a.num_timesteps, a._n_updates) == (b.num_timesteps, b._n_updates)
    state_a, state_b = a.policy.state_dict(), b.policy.state_dict()
    assert state_a.keys() == state_b.keys()
    different = [key for key in state_a if not th.equal(state_a[key], state_b[key])]
    assert not different, different
    for opt_a, opt_b in ((a.actor.optimizer, b.actor.optimizer), (a.critic.optimizer, b.critic.optimizer)):
        sa, sb = opt_a.state_dict(), opt_b.state_dict()
        assert sa["param_groups"] == sb["param_groups"]
        for key, value in sa["state"].items():
            for name, tensor in value.items():
                assert th.equal(tensor, sb["state"][key][name]), (key, name)


def in_memory_dataset(n: int = 64, rewards: np.ndarray | None = None) -> OfflineDataset:
    rng = np.random.default_rng(0)
    obs = rng.standard_normal((n, 3)).astype(np.float32)
    return OfflineDataset(
        observations=obs,
        actions=rng.uniform(-1, 1, (n, 2)).astype(np.float32),
        rewards=rng.standard_normal(n).astype(np.float32) if rewards is None else rewards.astype(np.float32),
        next_observations=(obs + 0.1).astype(np.float32),
        dones=np.zeros(n, dtype=np.float32),
        observation_space=gym.spaces.Box(-np.inf, np.inf, (3,), np.float32),
        action_space=gym.spaces.Box(-1.0, 1.0, (2,), np.float32),
        dataset_id="test/in-memory",
    )


# --------------------------------------------------------------------------- determinism and exact resume


def test_same_seed_same_parameters(tiny_dataset: str) -> None:
    a = make_model(tiny_dataset, seed=1).learn(40)
    th.manual_seed(999)  # the global RNG's state before a run must not matter: the model seeds it
    b = make_model(tiny_dataset, seed=1).learn(40)
    assert_same_training_state(a, b)
    c = make_model(tiny_dataset, seed=2).learn(40)
    assert not th.equal(a.policy.actor.input_layer.weight, c.policy.actor.input_layer.weight)


class Crash(Exception):
    pass


def test_crash_then_resume_is_exact(tiny_dataset: str, tmp_path: pathlib.Path) -> None:
    total, crash_at = 60, 37
    reference = make_model(tiny_dataset).learn(total)

    def crash(local_vars: dict, _globals: dict) -> bool:
        if local_vars["self"].num_timesteps == crash_at:
            raise Crash
        return True

    with pytest.raises(Crash):
        learn_with_checkpoints(POLA, lambda: make_model(tiny_dataset), total, tmp_path, save_freq=10, callback=crash)
    latest = tmp_path / "pola_latest.zip"
    assert validate_model_file(latest)["num_timesteps"] == 30
    th.manual_seed(12345)  # whatever ran in between, the checkpoint's RNG state is restored
    resumed = learn_with_checkpoints(
        POLA,
        lambda: make_model(tiny_dataset),
        total,
        tmp_path,
        save_freq=10,
        load_kwargs=dict(dataset=tiny_dataset, device="cpu"),
    )
    assert resumed._total_timesteps == total  # same learning-rate schedule
    assert_same_training_state(reference, resumed)
    # the dynamics model of a resumed run is frozen again
    assert resumed.policy.dynamics is not None
    assert not any(p.requires_grad for p in resumed.policy.dynamics.parameters())


def _wait_for(condition, process: subprocess.Popen, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition() and process.poll() is None:
        if time.monotonic() > deadline:
            process.kill()
            raise TimeoutError("worker did not reach the expected point")
        time.sleep(0.02)


def _kill_at_step(command: list[str], step: int, marker: pathlib.Path, env: dict[str, str]) -> None:
    """Run a worker that pauses at gradient ``step`` (after that step's checkpoint, if any) and SIGKILL it there."""
    process = subprocess.Popen([*command, "--pause-at", str(step), "--pause-marker", str(marker)], env=env)
    _wait_for(marker.exists, process)
    assert process.poll() is None
    process.send_signal(signal.SIGKILL)
    process.wait()
    marker.unlink()


def test_sigkill_during_training_and_during_checkpoint_write(tiny_dataset: str, tmp_path: pathlib.Path) -> None:
    """Real processes killed with SIGKILL at chosen steps (between checkpoints, after the last one) and inside a
    checkpoint write, then resumed to the parameters of the uninterrupted run."""
    total, save_freq = 100, 20
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    # the uninterrupted run, in this process with the worker's settings (one thread, as the workers)
    threads = th.get_num_threads()
    th.set_num_threads(1)
    try:
        reference = tmp_path / "reference.zip"
        uninterrupted = learn_with_checkpoints(
            POLA, lambda: make_model(tiny_dataset), total, tmp_path / "ref_run", save_freq, log_interval=0
        )
        save_checkpoint(uninterrupted, reference)
    finally:
        th.set_num_threads(threads)

    run_dir = tmp_path / "run"
    latest = run_dir / "pola_latest.zip"
    final = tmp_path / "final.zip"
    command = worker_command(tiny_dataset, run_dir, total, save_freq, final=final)

    # 1. kill between two checkpoints: at step 50, the last checkpoint is step 40's
    pause_marker = tmp_path / "paused"
    _kill_at_step(command, 50, pause_marker, env)
    step_1 = validate_model_file(latest)["num_timesteps"]
    assert step_1 == 40

    # 2. kill inside checkpoint writes: while SB3 writes the zip (the temp file is a truncated zip), and
    # after the temp file is complete but before the rename
    step = step_1
    for stage in ("mid_zip", "before_replace"):
        marker = tmp_path / f"writing_{stage}"
        process = subprocess.Popen(
            [*command, "--write-delay", "30", "--write-marker", str(marker), "--write-stage", stage], env=env
        )
        _wait_for(marker.exists, process)
        assert process.poll() is None
        process.send_signal(signal.SIGKILL)
        process.wait()
        stale = list(run_dir.glob(".pola_latest.zip.*.tmp.zip"))
        assert len(stale) == 1  # the kill did land mid-write (the stale file of the first kill was removed at start)
        if stage == "mid_zip":
            with pytest.raises(ModelFileError, match="truncated"):
                validate_model_file(stale[0])
        assert validate_model_file(latest)["num_timesteps"] >= step  # the latest file is intact
        step = validate_model_file(latest)["num_timesteps"]

    # 3. kill after the last checkpoint (the final step's), before the run's end
    _kill_at_step(command, total, pause_marker, env)
    assert validate_model_file(latest)["num_timesteps"] == total
    assert not final.exists()

    # 4. resume to the end
    subprocess.run(command, env=env, check=True)
    assert not list(run_dir.glob(".*.tmp.zip"))  # stale temp files are cleaned up
    assert compare_checkpoints(reference, final) == []


def test_failed_write_keeps_previous_checkpoint(tiny_dataset: str, tmp_path: pathlib.Path, monkeypatch) -> None:
    model = make_model(tiny_dataset).learn(5)
    path = save_checkpoint(model, tmp_path / "ckpt.zip")
    before = path.read_bytes()
    model.learn(5, reset_num_timesteps=False)
    renames = []

    def fail(tmp: str | os.PathLike, destination: str | os.PathLike) -> None:
        tmp = pathlib.Path(tmp)
        renames.append(destination)
        assert tmp.parent == path.parent and zipfile.is_zipfile(tmp)
        assert validate_model_file(tmp)["num_timesteps"] == 10  # the temp file is the complete new checkpoint
        assert path.read_bytes() == before  # while the new file is written, the old one is untouched
        raise OSError("disk full")

    monkeypatch.setattr(checkpoint.os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        save_checkpoint(model, path)
    assert renames == [path]  # the write failed at the rename over the checkpoint
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ckpt.zip"]  # no temp file left


def test_checkpoint_is_a_plain_model_file(tiny_dataset: str, tmp_path: pathlib.Path) -> None:
    model = make_model(tiny_dataset).learn(5)
    path = save_checkpoint(model, tmp_path / "ckpt")
    assert path.name == "ckpt.zip"
    loaded = POLA.load(path, device="cpu")  # SB3's load ignores the RNG member
    obs = np.zeros((4, 3), dtype=np.float32)
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    state = th.get_rng_state()
    load_checkpoint(POLA, path, device="cpu", dataset=tiny_dataset)
    assert not th.equal(state, th.get_rng_state())  # restored the saved state


# --------------------------------------------------------------------------- divergence guard


def test_nan_parameter_stops_training_and_keeps_good_checkpoint(tiny_dataset: str, tmp_path: pathlib.Path) -> None:
    def poison(local_vars: dict, _globals: dict) -> bool:
        model = local_vars["self"]
        if model.num_timesteps == 25:
            with th.no_grad():
                model.critic.q_net[0].weight[0, 0, 0] = float("nan")
        return True

    model = make_model(tiny_dataset, check_finite_freq=1)
    callback = CheckpointCallback(save_freq=10, save_path=tmp_path)
    with pytest.raises(
        DivergenceError,
        match=r"NaN or inf in losses .*critic_loss.*; parameters .* at gradient step 26 \(first non-finite after step 25,",
    ):
        model.learn(100, callback=[callback, ConvertCallback(poison)])
    latest = tmp_path / "pola_latest.zip"
    good = latest.read_bytes()
    assert validate_model_file(latest)["num_timesteps"] == 20
    loaded = POLA.load(latest, device="cpu")
    assert all(th.isfinite(v).all() for v in loaded.policy.state_dict().values() if v.is_floating_point())
    # neither an explicit save nor the callback writes the NaN weights over the good model
    with pytest.raises(DivergenceError, match="Not saving"):
        model.save(latest)
    with pytest.raises(DivergenceError):
        callback.save()
    assert latest.read_bytes() == good
    model.save(tmp_path / "debug.zip", check_finite=False)  # possible on purpose


def test_nan_loss_is_named(tmp_path: pathlib.Path) -> None:
    rewards = np.zeros(64)
    rewards[3] = np.inf  # one bad reward poisons the critic's TD target
    # a check every step: the error names the exact step
    model = make_model(in_memory_dataset(rewards=rewards), rollout_length=0, check_finite_freq=1)
    with pytest.raises(DivergenceError) as info:
        model.learn(100, callback=CheckpointCallback(save_freq=1000, save_path=tmp_path))
    message = str(info.value)
    match = re.search(r"NaN or inf in losses [a-z_0-9, ]*critic_loss.* at gradient step (\d+) ", message)
    assert match, message
    assert f"(first non-finite after step {int(match.group(1)) - 1}," in message
    latest = tmp_path / "pola_latest.zip"
    if latest.exists():  # a checkpoint written before the divergence was found holds finite weights only
        assert validate_model_file(latest)["num_timesteps"] < int(match.group(1))
        loaded = POLA.load(latest, device="cpu")
        assert all(th.isfinite(v).all() for v in loaded.policy.state_dict().values() if v.is_floating_point())


# --------------------------------------------------------------------------- loading or making, shared parts


def test_load_or_make(tiny_dataset: str, tmp_path: pathlib.Path) -> None:
    path = tmp_path / "ckpt.zip"
    stale = tmp_path / ".ckpt.zip.abc.tmp.zip"
    stale.write_bytes(b"killed mid-write")
    fresh = load_or_make(POLA, path, lambda: make_model(tiny_dataset))
    assert fresh.num_timesteps == 0 and not stale.exists()
    save_checkpoint(fresh.learn(4), path)
    resumed = load_or_make(POLA, path, lambda: pytest.fail("a checkpoint exists"), dataset=tiny_dataset, device="cpu")
    assert resumed.num_timesteps == 4
    assert_same_training_state(fresh, resumed)


def test_module_state_round_trip_and_atomic(tiny_dataset: str, tmp_path: pathlib.Path, monkeypatch) -> None:
    model = make_model(tiny_dataset).learn(2)  # fits the dynamics model
    dynamics = model.policy.dynamics
    assert dynamics is not None
    path = save_module_state(dynamics, tmp_path / "dynamics.pt")
    other = make_model(tiny_dataset, seed=3).policy.dynamics
    assert other is not None
    assert not all(th.equal(a, b) for a, b in zip(dynamics.state_dict().values(), other.state_dict().values(), strict=True))
    load_module_state(other, path)
    state, loaded = dynamics.state_dict(), other.state_dict()
    assert state.keys() == loaded.keys() and all(th.equal(state[k], loaded[k]) for k in state)
    before = path.read_bytes()

    def fail(tmp: str | os.PathLike, destination: str | os.PathLike) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(checkpoint.os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        save_module_state(other, path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dynamics.pt"]  # no temp file left
