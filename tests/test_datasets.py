"""Loader of Minari datasets: transitions, rescaling, cache, errors."""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import subprocess
import sys
import warnings

import gymnasium as gym
import minari
import numpy as np
import pytest
from helpers import ACT_HIGH, ACT_LOW, EPISODES, OBS_DIM, make_episodes, write_minari_dataset

from sb3_pola.cli import datasets as datasets_cli
from sb3_pola.common import dataset_paths, metrics
from sb3_pola.common import datasets as ds
from sb3_pola.common.datasets import (
    DatasetError,
    DatasetNotFoundError,
    OfflineDataset,
    SpaceMismatchError,
    list_local_datasets,
    load_offline_dataset,
    make_env,
    normalized_score,
    synthetic_dataset,
)

N_STEPS = sum(length for length, _ in EPISODES)


def _files(root: pathlib.Path) -> dict[str, tuple[int, int]]:
    return {str(p): (p.stat().st_size, p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()}


def _entries(cache: pathlib.Path) -> list[pathlib.Path]:
    """The cache's entries (folders; the file digests' memo beside them is not one)."""
    return sorted(p for p in cache.iterdir() if p.is_dir())


def test_transitions_and_boundaries(tiny_dataset):
    data = load_offline_dataset(tiny_dataset)
    assert isinstance(data, OfflineDataset)
    assert len(data) == N_STEPS
    assert data.dataset_id == tiny_dataset
    for name in ("observations", "actions", "rewards", "next_observations", "dones"):
        assert getattr(data, name).dtype == np.float32, name
    assert data.observations.shape == data.next_observations.shape == (N_STEPS, OBS_DIM)
    assert data.episode_returns.shape == (len(EPISODES),) and data.episode_returns.dtype == np.float64
    # obs[:, 0] = episode index, obs[:, 1] = step: next_obs is always the same episode's next step
    np.testing.assert_array_equal(data.next_observations[:, 0], data.observations[:, 0])
    np.testing.assert_array_equal(data.next_observations[:, 1], data.observations[:, 1] + 1)
    start = 0
    for ep, (length, terminated) in enumerate(EPISODES):
        end = start + length
        assert np.all(data.observations[start:end, 0] == ep)
        # only a termination is terminal; a truncated episode's last transition is not
        assert data.dones[end - 1] == float(terminated)
        assert not data.dones[start : end - 1].any()
        # the last transition's next_obs is the episode's final obs, not the next episode's first
        assert data.next_observations[end - 1, 1] == length
        if ep + 1 < len(EPISODES):
            assert not np.array_equal(data.next_observations[end - 1], data.observations[end])
        start = end
    raw = list(minari.load_dataset(tiny_dataset).iterate_episodes())
    np.testing.assert_allclose(data.episode_returns, [ep.rewards.sum() for ep in raw])
    np.testing.assert_allclose(data.rewards, np.concatenate([ep.rewards for ep in raw]).astype(np.float32))


def test_action_rescaling(tiny_dataset):
    data = load_offline_dataset(tiny_dataset)
    raw = np.concatenate([ep.actions for ep in minari.load_dataset(tiny_dataset).iterate_episodes()])
    expected = 2.0 * (raw - ACT_LOW) / (ACT_HIGH - ACT_LOW) - 1.0
    np.testing.assert_allclose(data.actions, expected, atol=1e-6)
    assert data.actions.min() >= -1.0 and data.actions.max() <= 1.0
    np.testing.assert_allclose(data.unscale_action(data.actions), raw, atol=1e-5)
    np.testing.assert_array_equal(data.action_space.low, ACT_LOW)  # original space kept


def test_out_of_bounds_actions_clipped(make_dataset):
    buffers = make_episodes()
    buffers[0].actions[0] = ACT_HIGH + 5.0
    data = load_offline_dataset(make_dataset(buffers=buffers))
    np.testing.assert_array_equal(data.actions[0], [1.0, 1.0])


def test_path_and_object_inputs(tiny_dataset, tiny_datasets_root):
    folder = tiny_datasets_root / tiny_dataset
    by_id = load_offline_dataset(tiny_dataset, use_cache=False)
    for source in (folder, folder / "data", str(folder), minari.load_dataset(tiny_dataset)):
        data = load_offline_dataset(source, use_cache=False)
        np.testing.assert_array_equal(data.observations, by_id.observations)
        assert data.dataset_id == tiny_dataset


def test_shipped_folder_is_searched(tmp_path, monkeypatch):
    shipped = tmp_path / "shipped"
    write_minari_dataset(shipped, "pkg/ship-v0", make_episodes())
    monkeypatch.setattr(dataset_paths, "package_datasets_dir", lambda: shipped)
    assert "pkg/ship-v0" in list_local_datasets()
    assert len(load_offline_dataset("pkg/ship-v0")) == N_STEPS


def test_obs_stats(tiny_dataset):
    data = load_offline_dataset(tiny_dataset)
    mean, std = data.obs_stats()
    assert mean.dtype == std.dtype == np.float32 and mean.shape == (OBS_DIM,)
    np.testing.assert_allclose(mean, data.observations.mean(0), rtol=1e-5)
    np.testing.assert_allclose(std, np.maximum(data.observations.std(0), 1e-3), rtol=1e-5)
    data.observations[:, 2] = 7.0  # constant feature: std floored
    assert data.obs_stats(eps=0.5)[1][2] == pytest.approx(0.5)


def test_normalized_score(tiny_dataset, tiny_datasets_root, make_dataset):
    data = load_offline_dataset(tiny_datasets_root / tiny_dataset)
    assert data.ref_min_score == -10.0 and data.ref_max_score == 10.0
    assert data.normalized_score([0.0, 10.0]) == pytest.approx(75.0)
    assert normalized_score(10.0, -10.0, 10.0) == pytest.approx(100.0)
    metrics._warned_no_ref.clear()
    bare = load_offline_dataset(make_dataset("test/noref-v0", ref_scores=False))
    assert bare.ref_min_score is None
    with pytest.warns(UserWarning, match="no ref"):
        assert bare.normalized_score([1.0]) is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once only
        assert bare.normalized_score([1.0]) is None
    with pytest.warns(UserWarning):
        assert normalized_score([1.0], None, 5.0) is None


def test_one_normalized_score() -> None:
    """Dataset, model, callbacks and the peers worker score through ``sb3_pola.common.metrics``."""
    import inspect

    from sb3_pola.common import callbacks, offline_algorithm
    from sb3_pola.grid import peers_worker

    assert ds.normalized_score is metrics.normalized_score
    assert callbacks.normalized_score is offline_algorithm.normalized_score is metrics.normalized_score
    assert inspect.getsourcefile(peers_worker.normalized_scores) == inspect.getsourcefile(metrics.normalized_scores)
    returns = np.array([-10.0, 0.0, 5.0])
    np.testing.assert_array_equal(metrics.normalized_scores(returns, -10.0, 10.0), [0.0, 50.0, 75.0])
    assert metrics.normalized_score(returns, -10.0, 10.0) == pytest.approx(np.mean([0.0, 50.0, 75.0]))
    assert np.isnan(metrics.normalized_scores(returns, 1.0, 1.0)).all()
    nan_score = metrics.normalized_score(float("nan"), 0.0, 1.0)  # a NaN return scores NaN: not "no reference scores"
    assert nan_score is not None and np.isnan(nan_score)


def test_cache_hit(tiny_dataset, tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    first = load_offline_dataset(tiny_dataset, cache_dir=cache)
    entries = _entries(cache)
    assert len(entries) == 1 and (entries[0] / "manifest.json").is_file()

    def no_read(*args, **kwargs):
        raise AssertionError("episodes read despite a valid cache")

    monkeypatch.setattr(ds, "_build_arrays", no_read)
    second = load_offline_dataset(tiny_dataset, cache_dir=cache)
    for name in ("observations", "actions", "rewards", "next_observations", "dones", "episode_returns"):
        np.testing.assert_array_equal(getattr(first, name), getattr(second, name))
    # env var decides the default cache folder
    monkeypatch.setenv("SB3_POLA_CACHE_DIR", str(cache))
    load_offline_dataset(tiny_dataset)


def test_cache_invalidated_when_dataset_changes(make_dataset, tmp_path):
    cache = tmp_path / "cache"
    dataset_id = make_dataset("test/change-v0")
    before = load_offline_dataset(dataset_id, cache_dir=cache)
    root = pathlib.Path(os.environ["MINARI_DATASETS_PATH"])
    shutil.rmtree(root / dataset_id)
    # same id, same number of steps, different data
    write_minari_dataset(root, dataset_id, make_episodes(seed=1))
    after = load_offline_dataset(dataset_id, cache_dir=cache)
    assert not np.array_equal(before.observations, after.observations)
    fresh = load_offline_dataset(dataset_id, use_cache=False)
    np.testing.assert_array_equal(after.observations, fresh.observations)
    assert len(_entries(cache)) == 2


@pytest.mark.parametrize("damage", ["truncate", "bitflip", "wrong_shape", "manifest"])
def test_corrupt_cache_rebuilt(tiny_dataset, tmp_path, damage):
    cache = tmp_path / "cache"
    good = load_offline_dataset(tiny_dataset, cache_dir=cache)
    (entry,) = _entries(cache)
    path = entry / "observations.npy"
    if damage == "truncate":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "bitflip":
        raw = bytearray(path.read_bytes())
        raw[-5] ^= 0xFF  # a data byte: only the CRC-32 sees it
        path.write_bytes(bytes(raw))
    elif damage == "wrong_shape":
        np.save(path, np.load(path)[:-1])
    else:
        (entry / "manifest.json").write_text("{not json")
    with pytest.warns(UserWarning, match="cache"):
        again = load_offline_dataset(tiny_dataset, cache_dir=cache)
    np.testing.assert_array_equal(again.observations, good.observations)
    # rebuilt in place: the next load is a clean hit
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_offline_dataset(tiny_dataset, cache_dir=cache)


def test_unknown_id(tiny_dataset, tiny_datasets_root):
    before = _files(tiny_datasets_root)
    with pytest.raises(DatasetNotFoundError) as info:
        load_offline_dataset("test/missing-v0")
    message = str(info.value)
    assert "test/missing-v0" in message and tiny_dataset in message
    assert "minari download" in message and "download=True" in message
    assert isinstance(info.value, ValueError)
    assert _files(tiny_datasets_root) == before
    with pytest.raises(DatasetNotFoundError):
        load_offline_dataset(tiny_datasets_root / "nothing-here")


def test_space_mismatch(tiny_dataset):
    env = gym.make("Pendulum-v1")
    with pytest.raises(SpaceMismatchError) as info:
        load_offline_dataset(tiny_dataset, env=env)
    message = str(info.value)
    assert "Box(-inf, inf, (3,)" in message and str(env.observation_space) in message
    assert str(env.action_space) in message


def test_matching_env_accepted(make_dataset):
    from minari.data_collector import EpisodeBuffer

    env = gym.make("Pendulum-v1")
    obs, _ = env.reset(seed=0)
    observations, actions = [obs], []
    for _ in range(5):
        action = env.action_space.sample()
        obs, *_ = env.step(action)
        observations.append(obs)
        actions.append(action)
    buffer = EpisodeBuffer(
        observations=np.array(observations),
        actions=np.array(actions),
        rewards=np.ones(5),
        terminations=np.zeros(5, bool),
        truncations=np.array([0, 0, 0, 0, 1], bool),
    )
    root = pathlib.Path(os.environ["MINARI_DATASETS_PATH"])
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    minari.create_dataset_from_buffers("pendulum/tiny-v0", [buffer], env="Pendulum-v1", data_format="hdf5")
    data = load_offline_dataset("pendulum/tiny-v0", env=env)
    assert data.env_id == "Pendulum-v1"
    made = make_env(data)
    assert made.spec.id == "Pendulum-v1" and made.spec.max_episode_steps == 200
    assert make_env("pendulum/tiny-v0").spec.id == "Pendulum-v1"


def test_discrete_actions_rejected(make_dataset):
    dataset_id = make_dataset("test/discrete-v0", buffers=make_episodes(discrete=True), discrete=True)
    with pytest.raises(DatasetError, match="continuous"):
        load_offline_dataset(dataset_id)


@pytest.mark.parametrize("field,count", [("observations", 2), ("actions", 1), ("rewards", 3)])
def test_non_finite_rejected(make_dataset, tmp_path, field, count):
    buffers = make_episodes()
    target = getattr(buffers[1], field)
    flat = target.reshape(-1)
    flat[:count] = [np.nan, np.inf, -np.inf][:count]
    dataset_id = make_dataset(f"test/nan-{field}-v0", buffers=buffers)
    cache = tmp_path / "cache"
    with pytest.raises(DatasetError, match=rf"{field}: {count} values"):
        load_offline_dataset(dataset_id, cache_dir=cache)
    assert not cache.exists() or not any(cache.iterdir())  # nothing written


def test_empty_dataset_rejected(make_dataset):
    dataset_id = make_dataset("test/empty-v0", buffers=[])
    with pytest.raises(DatasetError, match="empty"):
        load_offline_dataset(dataset_id)


def test_datasets_cli(tiny_dataset, capsys):
    assert datasets_cli.main([]) == 0
    out = capsys.readouterr().out
    assert tiny_dataset in out and str(N_STEPS) in out and "-10.0" in out


def test_shipped_dataset_loads():
    """The dataset shipped in sb3_pola/data/datasets loads by id with reference scores."""
    shipped = [i for i in list_local_datasets() if i.startswith("invertedpendulum/")]
    if not shipped:
        pytest.skip("no shipped dataset in this checkout")
    data = load_offline_dataset("invertedpendulum/medium-v0")
    assert data.env_id == "InvertedPendulum-v5" and data.observations.shape[1] == 4
    assert data.ref_min_score is not None and data.ref_max_score is not None
    assert 0 < data.normalized_score(data.episode_returns) < 100


# ----------------------------------------------------------------------------- issue #25: corrupt files, the cache's key


def _truncated_copy(tiny_datasets_root: pathlib.Path, tiny_dataset: str, root: pathlib.Path) -> pathlib.Path:
    """A copy of the tiny dataset under ``root`` as ``test/broken-v0``, its HDF5 file cut in half."""
    target = root / "test" / "broken-v0"
    shutil.copytree(tiny_datasets_root / tiny_dataset, target)
    (hdf5,) = (target / "data").glob("*.hdf5")
    hdf5.write_bytes(hdf5.read_bytes()[: hdf5.stat().st_size // 2])
    return hdf5


def test_truncated_file_is_named_with_a_fix(tiny_dataset, tiny_datasets_root, tmp_path, monkeypatch, capsys):
    root = tmp_path / "datasets"
    shutil.copytree(tiny_datasets_root / tiny_dataset, root / tiny_dataset)  # the intact copy
    hdf5 = _truncated_copy(tiny_datasets_root, tiny_dataset, root)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    cache = tmp_path / "cache"
    monkeypatch.setenv("SB3_POLA_CACHE_DIR", str(cache))
    with pytest.raises(ds.DatasetCorruptError) as info:
        load_offline_dataset("test/broken-v0")
    message = str(info.value)
    assert "\n" not in message and str(hdf5) in message and "truncated or corrupt" in message
    assert "minari download --force test/tiny-v0" in message  # the id in its metadata, which Minari could re-download
    # nothing is cached from the broken file
    assert not cache.exists() or not any(p.is_dir() for p in cache.iterdir())
    # the command line: one line naming the file, exit status 2
    from sb3_pola import cli

    assert cli.main(["run", "--dataset", "test/broken-v0", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(hdf5) in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()
    # `datasets --check` reads every dataset and flags the broken one (exit status 1); plain `datasets` cannot see it
    assert datasets_cli.main([]) == 0
    assert "BROKEN" not in capsys.readouterr().out
    assert datasets_cli.main(["--check"]) == 1
    lines = capsys.readouterr().out.splitlines()
    broken = [line for line in lines if line.startswith("test/broken-v0")]
    intact = [line for line in lines if line.startswith(tiny_dataset)]
    assert len(broken) == 1 and "BROKEN" in broken[0] and str(hdf5) in broken[0]
    assert len(intact) == 1 and intact[0].rstrip().endswith("ok")
    assert not cache.exists() or not any(p.is_dir() for p in cache.iterdir())  # --check caches nothing
    # the intact copy still loads, and is cached
    assert len(load_offline_dataset(tiny_dataset)) == N_STEPS
    assert len([p for p in cache.iterdir() if p.is_dir()]) == 1


def test_collect_command_in_metadata_is_the_fix(tiny_dataset, tiny_datasets_root, tmp_path):
    hdf5 = _truncated_copy(tiny_datasets_root, tiny_dataset, tmp_path)
    metadata_file = hdf5.parent / "metadata.json"
    metadata = json.loads(metadata_file.read_text())
    metadata["collect_command"] = "sb3-pola collect --env Pendulum-v1 --kind random"
    metadata_file.write_text(json.dumps(metadata))
    with pytest.raises(
        ds.DatasetCorruptError, match="re-collect it with the command in its metadata: `sb3-pola collect --env"
    ):
        load_offline_dataset(hdf5.parent.parent)


def test_reinstall_reuses_the_cache_entry(tiny_dataset, tiny_datasets_root, tmp_path, monkeypatch):
    """The cache is keyed by content: new file times (a reinstall, a copy) find the same entry, no second one."""
    root = tmp_path / "datasets"
    shutil.copytree(tiny_datasets_root / tiny_dataset, root / tiny_dataset)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    cache = tmp_path / "cache"
    first = load_offline_dataset(tiny_dataset, cache_dir=cache)
    entries = [p for p in cache.iterdir() if p.is_dir()]
    for path in (root / tiny_dataset).rglob("*"):
        os.utime(path, ns=(path.stat().st_atime_ns + 10**9, path.stat().st_mtime_ns + 10**9))

    def no_read(*args, **kwargs):
        raise AssertionError("episodes read again after a reinstall")

    monkeypatch.setattr(ds, "_build_arrays", no_read)
    second = load_offline_dataset(tiny_dataset, cache_dir=cache)
    assert [p for p in cache.iterdir() if p.is_dir()] == entries
    assert second.fingerprint == first.fingerprint
    np.testing.assert_array_equal(first.observations, second.observations)


def test_cache_listing_and_prune(make_dataset, tmp_path, monkeypatch, capsys):
    cache = tmp_path / "cache"
    monkeypatch.setenv("SB3_POLA_CACHE_DIR", str(cache))
    dataset_id = make_dataset("test/prune-v0")
    load_offline_dataset(dataset_id)
    root = pathlib.Path(os.environ["MINARI_DATASETS_PATH"])
    shutil.rmtree(root / dataset_id)
    write_minari_dataset(root, dataset_id, make_episodes(seed=1))  # changed: the old entry is of no more use
    load_offline_dataset(dataset_id)
    (cache / "old-format-entry").mkdir()
    (cache / "old-format-entry" / "manifest.json").write_text('{"observations": {}}')
    assert datasets_cli.main(["--cache"]) == 0
    out = capsys.readouterr().out
    assert "its dataset has changed" in out and "older cache format" in out and "in use" in out
    assert "2 unused entries" in out
    assert datasets_cli.main(["--cache", "--prune"]) == 0
    assert "pruned 2 entries" in capsys.readouterr().out
    assert len([p for p in cache.iterdir() if p.is_dir()]) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_offline_dataset(dataset_id)  # the entry in use was kept: a clean hit


def test_minari_label_and_path_advice(tiny_dataset, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("MINARI_DATASETS_PATH")
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.minari/datasets
    with pytest.raises(DatasetNotFoundError) as info:
        load_offline_dataset("test/missing-v0")
    message = str(info.value)
    assert "(MINARI_DATASETS_PATH)" not in message and "Minari's default, not created yet" in message
    assert datasets_cli.main([]) == 0
    assert "(MINARI_DATASETS_PATH)" not in capsys.readouterr().out
    for path in ("outputs/my-data", str(tmp_path / "nothing-here"), "./x-v0"):
        with pytest.raises(DatasetNotFoundError) as info:
            load_offline_dataset(path)
        assert "minari download" not in str(info.value) and "no such folder" in str(info.value).lower(), str(info.value)


def test_maze_env_without_the_adroit_notice():
    """Gymnasium-Robotics' import prints a notice about its Adroit envs; making the maze's env does not show it."""
    pytest.importorskip("gymnasium_robotics")
    code = "from sb3_pola.common.datasets import make_env\nmake_env('pointmaze/umaze-v0')"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "Adroit" not in result.stderr


def test_returns_to_go_restart_at_terminations_and_truncations():
    data = synthetic_dataset(5, 1, 1)
    # two episodes: steps 0-2 truncated (the next transition does not continue it), steps 3-4 terminated
    data.observations = np.array([[0.0], [1.0], [2.0], [10.0], [11.0]], dtype=np.float32)
    data.next_observations = np.array([[1.0], [2.0], [3.0], [11.0], [12.0]], dtype=np.float32)
    data.rewards = np.array([1.0, 2.0, 4.0, 1.0, 1.0], dtype=np.float32)
    data.dones = np.array([0.0, 0.0, 0.0, 0.0, 1.0], dtype=np.float32)
    assert data.episode_ends().tolist() == [False, False, True, False, True]
    np.testing.assert_allclose(data.returns_to_go(0.5), [1 + 0.5 * 2 + 0.25 * 4, 2 + 0.5 * 4, 4, 1.5, 1.0])


def _three_episodes():
    """Episodes of lengths 2, 3, 1 with returns 3, 1.5 and 5 (chained observations, truncations between them)."""
    data = synthetic_dataset(6, 1, 1)
    data.observations = np.array([[0.0], [1.0], [10.0], [11.0], [12.0], [20.0]], dtype=np.float32)
    data.next_observations = data.observations + 1.0
    data.rewards = np.array([1.0, 2.0, 0.5, 0.5, 0.5, 5.0], dtype=np.float32)
    data.dones = np.zeros(6, dtype=np.float32)
    return data


def test_best_episode_rows_keep_the_best_episodes_whole_in_the_files_order():
    data = _three_episodes()
    assert data.best_episode_rows(0.3).tolist() == [5]  # ceil(0.9) = 1 episode: the return-5 one
    assert data.best_episode_rows(0.5).tolist() == [0, 1, 5]  # 2 episodes, back in the file's order
    assert data.best_episode_rows(1.0).tolist() == [0, 1, 2, 3, 4, 5]
    assert data.best_episode_rows(0.01).tolist() == [5]  # at least one episode
    with pytest.raises(ValueError, match="fraction"):
        data.best_episode_rows(0.0)
