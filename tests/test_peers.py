"""``sb3-pola peers``: the export, the worker's d3rlpy dataset arrays, the table merge, the command's cells.

None of these needs d3rlpy, its venv, the network or ../shared; the one ``slow`` test runs a real
200-step cell when the repo's ``.venv-peers`` exists.
"""

from __future__ import annotations

import ast
import csv
import json
import math
import pathlib
import subprocess
import sys

import numpy as np
import pytest
from helpers import record_random_dataset

from sb3_pola.cli import peers as peers_cli
from sb3_pola.cli import score as score_cli
from sb3_pola.common.datasets import load_offline_dataset
from sb3_pola.grid import peers
from sb3_pola.grid import peers_worker as worker
from sb3_pola.grid import report as grid_report
from sb3_pola.grid import rows as grid_rows
from sb3_pola.grid import variants as grid_variants

REPO = pathlib.Path(__file__).resolve().parent.parent


def d3rlpy_transitions(prepared: dict[str, np.ndarray]) -> list[tuple]:
    """What d3rlpy 2.8's MDPDataset + BasicTransitionPicker make of flat arrays, written out independently.

    Episodes end after each terminal or timeout flag; step ``i`` is a transition if the episode
    terminated or ``i`` is not its last row; its next observation is row ``i + 1`` of the same
    episode, zeros on the terminal step.
    """
    out = []
    start = 0
    flags = (prepared["terminals"] > 0) | (prepared["timeouts"] > 0)
    for end in np.flatnonzero(flags):
        obs = prepared["observations"][start : end + 1]
        terminated = bool(prepared["terminals"][end])
        count = len(obs) if terminated else len(obs) - 1
        for i in range(count):
            last = terminated and i == len(obs) - 1
            next_obs = np.zeros_like(obs[i]) if last else obs[i + 1]
            out.append((obs[i], prepared["actions"][start + i], float(prepared["rewards"][start + i, 0]), next_obs, last))
        start = end + 1
    return out


# ----------------------------------------------------------------------------------------- export


def test_export_round_trip_keeps_episodes(tiny_dataset: str, tmp_path: pathlib.Path) -> None:
    """Tiny dataset: episodes (5, terminated), (7, truncated), (4, terminated), (6, truncated); obs (episode, step, noise)."""
    data = load_offline_dataset(tiny_dataset)
    lengths = peers.episode_lengths(tiny_dataset)
    assert lengths.tolist() == [5, 7, 4, 6]
    arrays = peers.export_arrays(data, lengths)
    path = tmp_path / "tiny.npz"
    np.savez(path, **arrays)
    meta = worker.load_npz(path)
    for name in ("observations", "actions", "rewards", "next_observations"):
        assert meta[name].dtype == np.float32
        np.testing.assert_array_equal(meta[name], getattr(data, name))
    assert np.all(np.abs(meta["actions"]) <= 1.0)
    ends = np.cumsum(lengths) - 1
    assert np.flatnonzero(meta["terminals"]).tolist() == [ends[0], ends[2]]
    assert np.flatnonzero(meta["timeouts"]).tolist() == [ends[1], ends[3]]
    # the next observation is the same episode's next step
    np.testing.assert_array_equal(meta["next_observations"][:, 0], meta["observations"][:, 0])
    np.testing.assert_array_equal(meta["next_observations"][:, 1], meta["observations"][:, 1] + 1)
    np.testing.assert_allclose(meta["action_low"], [-2.0, 0.0])
    np.testing.assert_allclose(meta["action_high"], [2.0, 4.0])
    assert meta["ref_min_score"] == -10.0 and meta["ref_max_score"] == 10.0
    assert meta["dataset_id"] == "test/tiny-v0" and meta["env_id"] == "" and meta["max_episode_steps"] is None
    np.testing.assert_allclose(meta["episode_returns"], data.episode_returns)


def test_export_rejects_wrong_episode_lengths(tiny_dataset: str) -> None:
    data = load_offline_dataset(tiny_dataset)
    with pytest.raises(ValueError, match="sum to"):
        peers.export_arrays(data, np.array([5, 7, 4, 5]))
    with pytest.raises(ValueError, match="terminations inside episodes"):
        peers.export_arrays(data, np.array([12, 4, 6]))  # episodes 0 and 1 merged: a termination inside
    with pytest.raises(ValueError, match="next observations"):
        peers.export_arrays(data, np.array([5, 11, 6]))  # episodes 1 (truncated) and 2 merged


def test_export_dataset_with_env_spec(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    root = tmp_path / "data"
    record_random_dataset(root, "test/pendulum-v0", "Pendulum-v1", 70, ref_scores=(-300.0, 0.0), max_episode_steps=30)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    meta = worker.load_npz(peers.export_dataset("test/pendulum-v0", tmp_path / "x" / "p.npz"))
    assert meta["env_id"] == "Pendulum-v1" and meta["max_episode_steps"] == 30
    assert json.loads(meta["env_kwargs"]) == {}
    assert meta["episode_lengths"].tolist() == [30, 30, 10]
    assert meta["terminals"].sum() == 0 and np.flatnonzero(meta["timeouts"]).tolist() == [29, 59, 69]
    env = worker.make_env(meta)
    assert env.spec is not None and env.spec.max_episode_steps == 30
    env.close()


def test_export_of_a_dict_observation_maze_evaluates_like_score(tmp_path: pathlib.Path) -> None:
    """The shipped U-maze: the worker's env is score's (fixed-goal eval env, same flattening) step for step."""
    pytest.importorskip("gymnasium_robotics")
    from sb3_pola.common.datasets import make_env

    data = load_offline_dataset("pointmaze/umaze-v0")
    assert data.dict_observation_space is not None
    meta = worker.load_npz(peers.export_dataset("pointmaze/umaze-v0", tmp_path / "u.npz"))
    assert json.loads(meta["dict_keys"]) == ["achieved_goal", "desired_goal", "observation"]
    assert "g" in json.dumps(json.loads(meta["env_kwargs"])["maze_map"])  # the eval env's fixed goal cell
    ours, theirs = make_env(data), worker.make_env(meta)
    assert theirs.spec is not None and theirs.spec.max_episode_steps == meta["max_episode_steps"] == 300
    obs_ours, _ = ours.reset(seed=3)
    obs_theirs, _ = theirs.reset(seed=3)
    np.testing.assert_array_equal(obs_theirs, obs_ours)
    assert obs_ours.shape == data.observations.shape[1:]
    for _ in range(5):
        action = np.array([0.5, -0.3], dtype=np.float32)
        step_ours, step_theirs = ours.step(action), theirs.step(action)
        np.testing.assert_array_equal(step_theirs[0], step_ours[0])
        assert step_theirs[1:4] == step_ours[1:4] and "success" in step_theirs[4]
    # data flattened in another order than the env's is refused
    with pytest.raises(ValueError, match="dict keys"):
        worker.make_env({**meta, "dict_keys": json.dumps(["observation", "achieved_goal", "desired_goal"])})
    ours.close()
    theirs.close()


# ----------------------------------------------------------------------------------------- worker arrays


def test_prepared_arrays_give_d3rlpy_exactly_our_transitions(tiny_dataset: str) -> None:
    data = load_offline_dataset(tiny_dataset)
    arrays = peers.export_arrays(data, peers.episode_lengths(tiny_dataset))
    prepared = worker.prepare_episode_arrays(*(arrays[name] for name in worker.TRANSITION_FIELDS))
    # one extra row per truncated episode, flagged timeout; the terminations stay on their steps
    assert len(prepared["rewards"]) == len(data) + 2
    assert prepared["rewards"].shape == (len(data) + 2, 1)
    assert np.flatnonzero(prepared["timeouts"]).tolist() == [5 + 7, 5 + 7 + 1 + 4 + 6]
    assert np.flatnonzero(prepared["terminals"]).tolist() == [4, 5 + 7 + 1 + 3]
    assert (prepared["rows"] >= 0).sum() == len(data) and sorted(prepared["rows"][prepared["rows"] >= 0]) == list(range(22))
    transitions = d3rlpy_transitions(prepared)
    assert len(transitions) == len(data)
    for k, (obs, action, reward, next_obs, terminal) in enumerate(transitions):
        np.testing.assert_array_equal(obs, arrays["observations"][k])
        np.testing.assert_array_equal(action, arrays["actions"][k])
        assert reward == arrays["rewards"][k]
        assert terminal == bool(arrays["terminals"][k])
        if not terminal:  # never the first observation of the next episode
            np.testing.assert_array_equal(next_obs, arrays["next_observations"][k])
            assert next_obs[0] == obs[0] and next_obs[1] == obs[1] + 1
    # without the extra rows d3rlpy would lose the last step of each truncated episode
    naive = {name: arrays[name] for name in ("observations", "actions", "terminals", "timeouts")}
    naive["rewards"] = arrays["rewards"].reshape(-1, 1)
    assert len(d3rlpy_transitions(naive)) == len(data) - 2


def test_prepared_arrays_edge_cases() -> None:
    obs = np.arange(6, dtype=np.float32).reshape(6, 1)
    next_obs = obs + 0.5
    actions, rewards = np.ones((6, 1), np.float32), np.arange(6, dtype=np.float32)
    zeros = np.zeros(6, np.float32)
    with pytest.raises(ValueError, match="ends no episode"):
        worker.prepare_episode_arrays(obs, actions, rewards, next_obs, zeros, zeros)
    both = zeros.copy()
    both[-1] = 1
    with pytest.raises(ValueError, match="both"):
        worker.prepare_episode_arrays(obs, actions, rewards, next_obs, both, both)
    # all timeouts (episodes of one step): each step gets its own extra row
    prepared = worker.prepare_episode_arrays(obs, actions, rewards, next_obs, zeros, np.ones(6, np.float32))
    np.testing.assert_array_equal(prepared["observations"][1::2, 0], next_obs[:, 0])
    np.testing.assert_array_equal(prepared["rewards"][0::2, 0], rewards)
    assert prepared["rewards"][1::2].sum() == 0 and prepared["actions"][1::2].sum() == 0
    assert len(d3rlpy_transitions(prepared)) == 6


def test_worker_imports_only_its_venv_libraries() -> None:
    tree = ast.parse(pathlib.Path(worker.__file__).read_text())
    modules = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            modules.add(node.module.split(".")[0])
    third_party = modules - set(sys.stdlib_module_names)
    assert third_party <= {"numpy", "gymnasium", "gymnasium_robotics", "d3rlpy", "torch", "mujoco"}, third_party
    assert worker.CSV_FIELDS == grid_rows.CSV_FIELDS


def test_peers_worker_loads_without_sb3_pola() -> None:
    """The d3rlpy venv has no ``sb3_pola``: the worker (and the normalised score it loads by path) must not need it."""
    code = f"""
import runpy, sys
sys.modules["sb3_pola"] = None  # any import of the package fails
namespace = runpy.run_path({str(pathlib.Path(worker.__file__).resolve())!r}, run_name="peers_worker")
print(namespace["normalized_scores"]([0.0, 15.0], 0.0, 30.0).tolist())
"""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[0.0, 50.0]"


def test_worker_hyperparameters() -> None:
    td3bc = worker.hyperparameters("td3bc", 10_000)
    assert td3bc["alpha"] == 2.5 and td3bc["batch_size"] == 256 and "Standard" in td3bc["observation_scaler"]
    iql = worker.hyperparameters("iql", 10_000)
    assert iql["expectile"] == 0.7 and iql["weight_temp"] == 3.0 and "1000" in iql["reward_scaler"]
    assert "T_max=10000" in iql["actor_lr_schedule"]
    assert worker.hyperparameters("bc", 10)["learning_rate"] == 1e-3
    with pytest.raises(ValueError):
        worker.hyperparameters("cql", 10)


class _RecordingEnv:
    """An env of 3-step episodes that records reset seeds and actions (reward = first action component)."""

    def __init__(self) -> None:
        import gymnasium as gym

        self.action_space = gym.spaces.Box(np.array([-2.0, 0.0], np.float32), np.array([2.0, 4.0], np.float32))
        self.seeds: list[int | None] = []
        self.actions: list[np.ndarray] = []
        self.t = 0

    def reset(self, seed: int | None = None):
        self.seeds.append(seed)
        self.t = 0
        return np.zeros(3), {}

    def step(self, action: np.ndarray):
        self.actions.append(np.asarray(action))
        self.t += 1
        return np.zeros(3), float(action[0]), False, self.t >= 3, {}


class _ConstantAlgo:
    def predict(self, x: np.ndarray) -> np.ndarray:
        assert x.dtype == np.float32 and x.shape == (1, 3)
        return np.array([[0.5, -1.5]], dtype=np.float32)


def test_worker_evaluation_protocol() -> None:
    """score's protocol: reset seeds 10_000 (seed + 1) + i, actions [-1, 1] -> env bounds, per-episode D4RL scores."""
    env = _RecordingEnv()
    meta = {"action_low": np.array([-2.0, 0.0]), "action_high": np.array([2.0, 4.0]), "ref_min_score": 0.0}
    meta["ref_max_score"] = 30.0
    row = worker.eval_row(_ConstantAlgo(), env, meta, "d", "d3rlpy-TD3+BC", seed=2, step=7, episodes=2)
    assert env.seeds == [30_000, 30_001]
    np.testing.assert_allclose(env.actions[0], [1.0, 0.0])  # 0.5 -> 1.0 in [-2, 2]; -1.5 clipped to -1 -> 0
    assert row["mean_return"] == 3.0 and row["score"] == 10.0 and row["score_std"] == 0.0
    assert row["eval_episodes"] == 2 and row["step"] == 7
    np.testing.assert_allclose(worker.normalized_scores(np.array([0.0, 15.0]), 0.0, 30.0), [0.0, 50.0])
    assert np.isnan(worker.normalized_scores(np.array([1.0]), None, None)).all()


def test_worker_drop_rows(tmp_path: pathlib.Path) -> None:
    path = tmp_path / "p.csv"
    for seed, step in [(0, 100), (0, 200), (1, 100), (0, 300)]:
        row = dict(dataset="d", variant="d3rlpy-BC", seed=seed, step=step, score=1.0, score_std=0.0, mean_return=0.0)
        worker.append_row(path, {**row, "eval_episodes": 1, "wall_s": 1.0})
    assert worker.drop_rows(path, "d", "d3rlpy-BC", 0, after_step=100) == 2
    assert [(r["seed"], r["step"]) for r in grid_rows.read_rows(path)] == [(0, 100), (1, 100)]
    assert worker.drop_rows(path, "d", "d3rlpy-BC", 0) == 1


def test_worker_upgrades_a_csv_from_before_the_success_column(tmp_path: pathlib.Path) -> None:
    path = tmp_path / "p.csv"
    old = [f for f in worker.CSV_FIELDS if f != "success"]
    path.write_text(",".join(old) + "\nd,d3rlpy-BC,0,100,1.0,0.0,0.0,1,1.0\n")
    worker.append_row(
        path,
        dict(
            dataset="d",
            variant="d3rlpy-BC",
            seed=0,
            step=200,
            score=2.0,
            score_std=0.0,
            mean_return=0.0,
            eval_episodes=1,
            wall_s=2.0,
            success=0.5,
        ),
    )
    rows = grid_rows.read_rows(path)
    assert [(r["step"], r["score"]) for r in rows] == [(100, 1.0), (200, 2.0)]
    assert math.isnan(rows[0]["success"]) and rows[1]["success"] == 0.5


# ----------------------------------------------------------------------------------------- table merge


def _rows(variant: str, base: float, seeds: tuple[int, ...], dataset: str = "halfcheetah/medium-v0") -> list[dict]:
    return [
        dict(
            dataset=dataset,
            variant=variant,
            seed=seed,
            step=step,
            score=base + bump + 2 * seed,
            score_std=1.0,
            mean_return=0.0,
            eval_episodes=2,
            wall_s=float(step),
        )
        for seed in seeds
        for step, bump in [(100, 0.0), (200, 4.0)]
    ]


def test_table_merges_peers(tmp_path: pathlib.Path) -> None:
    out = tmp_path / "r"
    out.mkdir()
    grid_rows.write_rows(out / "scores.csv", _rows("T0", 10.0, (0, 1)) + _rows("T3", 20.0, (0, 1)) + _rows("BC", 8.0, (0, 1)))
    peer_rows = _rows("d3rlpy-BC", 5.0, (0, 1, 2)) + _rows("d3rlpy-TD3+BC", 30.0, (0, 1, 2))
    peer_rows += _rows("d3rlpy-IQL", 40.0, (0,), dataset="halfcheetah/medium-replay-v0")
    grid_rows.write_rows(out / "peers.csv", peer_rows)
    (out / "peers_config.json").write_text(
        json.dumps({"steps": 200, "eval_freq": 100, "eval_episodes": 2, "versions": {"d3rlpy": "2.8.1"}})
    )
    assert score_cli.main(["--report-only", "--out", str(out), "--variants", "T0", "T3", "BC"]) == 0
    table = (out / "table.md").read_text()
    # TD3+BC final = 34, 36, 38 -> 36.0 ± 2.0; POLA rows first, then the baselines in a fixed order
    assert "| halfcheetah/medium-v0 | d3rlpy-TD3+BC | 36.0 ± 2.0 | 36.0 ± 2.0 | 0,1,2 | 200 |" in table
    assert "| halfcheetah/medium-replay-v0 | d3rlpy-IQL | 44.0 | 44.0 | 0 | 200 |" in table
    assert table.index("| BC |") < table.index("| d3rlpy-TD3+BC |") < table.index("| d3rlpy-BC |")
    assert "d3rlpy 2.8.1, 200 gradient steps" in table
    for name in ("fig_rollout_halfcheetah_medium-v0.png", "fig_peers_halfcheetah_medium-v0.png"):
        assert 0 < (out / name).stat().st_size < 200_000
    assert (out / "fig_peers_halfcheetah_medium-replay-v0.png").exists()  # baselines alone still get their figure


def test_table_of_peers_alone(tmp_path: pathlib.Path) -> None:
    out = tmp_path / "p"
    out.mkdir()
    grid_rows.write_rows(out / "peers.csv", _rows("d3rlpy-TD3+BC", 30.0, (0, 1)))
    grid_report.write_reports(out, grid_variants.DEFAULT_VARIANTS)
    table = (out / "table.md").read_text()
    assert "| halfcheetah/medium-v0 | d3rlpy-TD3+BC | 35.0 ± 1.4 |" in table and "Rows `d3rlpy-*`" in table


# ----------------------------------------------------------------------------------------- the command

FAKE_WORKER = """
import argparse, csv, json, pathlib, sys
p = argparse.ArgumentParser()
for a in ("--npz", "--algo", "--seed", "--steps", "--eval-freq", "--eval-episodes", "--csv", "--dataset", "--result",
          "--threads", "--ckpt"):
    p.add_argument(a)
p.add_argument("--versions", action="store_true")
a = p.parse_args()
if a.versions:
    print(json.dumps({"d3rlpy": "fake"}))
    sys.exit(0)
assert pathlib.Path(a.npz).is_file()
names = {"td3bc": "d3rlpy-TD3+BC", "iql": "d3rlpy-IQL", "bc": "d3rlpy-BC"}
fields = ["dataset", "variant", "seed", "step", "score", "score_std", "mean_return", "eval_episodes", "wall_s"]
path = pathlib.Path(a.csv)
new = not path.exists()
with path.open("a", newline="") as f:
    w = csv.DictWriter(f, fieldnames=fields)
    if new:
        w.writeheader()
    for step in range(int(a.eval_freq), int(a.steps) + 1, int(a.eval_freq)):
        w.writerow(dict(dataset=a.dataset, variant=names[a.algo], seed=a.seed, step=step, score=float(step),
                        score_std=0.0, mean_return=0.0, eval_episodes=a.eval_episodes, wall_s=1.0))
print("[peers] fake cell", a.algo, a.seed)
pathlib.Path(a.result).write_text(json.dumps({"algo": a.algo, "seed": int(a.seed), "ckpt": a.ckpt}))
"""


def test_peers_command_runs_skips_and_refuses(
    tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """The command with a stand-in worker: export, one process per cell, markers, skip, report, budget check."""
    root = tmp_path / "data"
    record_random_dataset(root, "test/pendulum-v0", "Pendulum-v1", 40, ref_scores=(-300.0, 0.0), max_episode_steps=20)
    fake = tmp_path / "fake_worker.py"
    fake.write_text(FAKE_WORKER)
    monkeypatch.setattr(peers, "WORKER", fake)
    monkeypatch.setattr(peers, "ensure_venv", lambda venv, python, verbose: pathlib.Path(sys.executable))
    out = tmp_path / "out"
    argv = ["--data-dir", str(root), "--datasets", "test/pendulum-v0", "--out", str(out), "--steps", "20"]
    argv += ["--eval-freq", "10", "--eval-episodes", "1", "--seeds", "0", "1", "--algos", "td3bc", "bc"]
    assert peers_cli.main(argv) == 0
    rows = grid_rows.read_rows(out / "peers.csv")
    assert {(r["variant"], r["seed"], r["step"]) for r in rows} == {
        (v, s, t) for v in ("d3rlpy-TD3+BC", "d3rlpy-BC") for s in (0, 1) for t in (10, 20)
    }
    markers = sorted(p.name for p in (out / "peers_cells").iterdir())
    assert markers == [f"test_pendulum-v0__d3rlpy-{a}__seed{s}.json" for a in ("bc", "td3bc") for s in (0, 1)]
    marker = json.loads((out / "peers_cells" / markers[0]).read_text())
    assert marker["ckpt"].endswith("peers_ckpt/test_pendulum-v0__d3rlpy-bc__seed0.pkl") and "process_wall_s" in marker
    config = json.loads((out / "peers_config.json").read_text())
    assert config["steps"] == 20 and config["versions"] == {"d3rlpy": "fake"} and config["algos"] == ["bc", "td3bc"]
    assert "| test/pendulum-v0 | d3rlpy-TD3+BC | 20.0 ± 0.0 |" in (out / "table.md").read_text()
    assert (out / "peers_data" / "test_pendulum-v0.npz").is_file()
    # the same command again: every cell is skipped
    capsys.readouterr()
    assert peers_cli.main(argv) == 0
    assert capsys.readouterr().out.count("done, skipped") == 4
    assert len(grid_rows.read_rows(out / "peers.csv")) == 8
    # another budget in the same folder is refused
    assert peers_cli.main([*argv, "--steps", "30"]) == 2


def test_peers_dry_run_lists_cells(capsys: pytest.CaptureFixture, tmp_path: pathlib.Path) -> None:
    assert peers_cli.main(["--dry-run", "--out", str(tmp_path / "o"), "--seeds", "0", "--datasets", "a/b-v0"]) == 0
    text = capsys.readouterr().out
    assert "3 d3rlpy runs" in text and "a_b-v0__d3rlpy-iql__seed0" in text
    assert not (tmp_path / "o").exists()


# ----------------------------------------------------------------------------------------- the real thing

PEERS_PYTHON = peers.venv_python(REPO / peers.DEFAULT_VENV)


@pytest.mark.slow
@pytest.mark.skipif(not PEERS_PYTHON.exists(), reason="no .venv-peers (made by `make peers`)")
def test_real_d3rlpy_cell(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A 200-step TD3+BC cell in the peers venv on random Hopper data (terminations and a truncation)."""
    root = tmp_path / "data"
    record_random_dataset(root, "test/hopper-v0", "Hopper-v5", 300, ref_scores=(-20.0, 3234.3))
    monkeypatch.setattr(peers, "ensure_venv", lambda venv, python, verbose: PEERS_PYTHON)
    out = tmp_path / "out"
    argv = ["--data-dir", str(root), "--datasets", "test/hopper-v0", "--out", str(out), "--steps", "200"]
    argv += ["--eval-freq", "100", "--eval-episodes", "2", "--seeds", "0", "--algos", "td3bc", "-v", "0"]
    assert peers_cli.main(argv) == 0
    rows = grid_rows.read_rows(out / "peers.csv")
    assert [(r["variant"], r["step"], r["eval_episodes"]) for r in rows] == [
        ("d3rlpy-TD3+BC", 100, 2),
        ("d3rlpy-TD3+BC", 200, 2),
    ]
    assert all(np.isfinite(r["score"]) for r in rows)
    log = (out / "peers_logs" / "test_hopper-v0__d3rlpy-td3bc__seed0.log").read_text()
    assert "300 transitions" in log and "aligned with the export" in log  # d3rlpy's own picker checked every one
    meta = worker.load_npz(out / "peers_data" / "test_hopper-v0.npz")
    assert meta["terminals"].sum() > 0 and meta["timeouts"].sum() == 1
    marker = json.loads((out / "peers_cells" / "test_hopper-v0__d3rlpy-td3bc__seed0.json").read_text())
    assert marker["versions"]["d3rlpy"] == "2.8.1" and marker["hyperparameters"]["alpha"] == 2.5
    assert not (out / "peers_ckpt" / "test_hopper-v0__d3rlpy-td3bc__seed0.pkl").exists()
    with (out / "peers.csv").open() as f:
        assert next(csv.reader(f)) == grid_rows.CSV_FIELDS
