"""sb3-pola collect on Gymnasium-Robotics point mazes: the planner, Dict-observation datasets, the shipped U-maze."""

from __future__ import annotations

import sys

import gymnasium as gym
import minari
import numpy as np
import pytest

from sb3_pola import cli, collect
from sb3_pola.collect import maze as collect_maze
from sb3_pola.collect.episodes import run_episodes
from sb3_pola.collect.maze import (
    cell_distances,
    data_env_spec,
    eval_env_spec,
    maze_name,
    planner_for,
    require_robotics,
    shortest_path,
)
from sb3_pola.common.dataset_paths import package_datasets_dir
from sb3_pola.common.errors import UsageError

U_MAZE = [
    [1, 1, 1, 1, 1],
    [1, 0, 0, 0, 1],
    [1, 1, 1, 0, 1],
    [1, 0, 0, 0, 1],
    [1, 1, 1, 1, 1],
]


@pytest.fixture(scope="module", autouse=True)
def _robotics() -> None:
    require_robotics()


def test_shortest_path_on_known_maps():
    # the U: from the bottom-left arm round the bend to the top-left arm
    assert shortest_path(U_MAZE, (3, 1), (1, 1)) == [(3, 1), (3, 2), (3, 3), (2, 3), (1, 3), (1, 2), (1, 1)]
    assert shortest_path(U_MAZE, (1, 2), (1, 2)) == [(1, 2)]
    assert cell_distances(U_MAZE, (1, 1)) == {(1, 1): 0, (1, 2): 1, (1, 3): 2, (2, 3): 3, (3, 3): 4, (3, 2): 5, (3, 1): 6}
    # two ways round a pillar: the shorter one; a walled-off cell ("c" and "g" cells are free too)
    ring = [
        [1, 1, 1, 1, 1, 1],
        [1, "c", 0, 0, 0, 1],
        [1, 0, 1, 1, 0, 1],
        [1, 0, 0, "g", 0, 1],
        [1, 1, 1, 1, 1, 1],
        [1, 0, 1, 1, 1, 1],
    ]
    path = shortest_path(ring, (1, 1), (3, 3))
    assert path == [(1, 1), (2, 1), (3, 1), (3, 2), (3, 3)]
    assert shortest_path(ring, (5, 1), (3, 3)) == [] and shortest_path(ring, (1, 1), (5, 1)) == []


def test_maze_names_and_specs():
    assert maze_name("PointMaze_UMaze-v3") == "umaze"
    assert maze_name("PointMaze_MediumDense-v3") == "medium-dense"
    assert maze_name("PointMaze_Large_Diverse_G-v3") == "large-diverse-g"
    data = data_env_spec("PointMaze_Medium-v3", 123)
    assert data.max_episode_steps == 123 and data.kwargs["continuing_task"] and data.kwargs["reset_target"]
    evaluation = eval_env_spec("PointMaze_Medium-v3", None)
    assert evaluation.max_episode_steps == gym.spec("PointMaze_Medium-v3").max_episode_steps
    assert evaluation.kwargs["maze_map"][6][6] == "g" and not evaluation.kwargs["reset_target"]
    assert sum(row.count("g") for row in evaluation.kwargs["maze_map"]) == 1
    # the registered map is left as it was
    assert gym.spec("PointMaze_Medium-v3").kwargs["maze_map"][6][6] == 0


def test_planner_reaches_goals():
    env = gym.make(eval_env_spec("PointMaze_UMaze-v3", 200))
    returns, successes = run_episodes(env, planner_for(env), 4, seed=0)
    assert all(successes) and np.mean(returns) > 40
    _, random_successes = run_episodes(env, None, 4, seed=0)
    # a continuing task with a new goal on reaching one: several goals in a few hundred steps
    env = gym.make(data_env_spec("PointMaze_UMaze-v3", 400))
    planner = planner_for(env)
    obs, _ = env.reset(seed=1)
    goals = 0.0
    for _ in range(400):
        obs, reward, terminated, truncated, _ = env.step(planner(obs))
        goals += float(reward)
        assert not terminated
    assert goals >= 3 and truncated
    assert np.mean(random_successes) < 1.0


def test_collect_dict_dataset(tmp_path, monkeypatch):
    argv = ["--env", "PointMaze_UMaze-v3", "--kind", "planner", "random", "--steps", "250", "--episode-steps", "100"]
    # a ball at full speed crosses a cell in ~20 steps: 150 steps reach the goal from any U-maze cell
    argv += ["--ref-episodes", "10", "--eval-steps", "150", "--out", str(tmp_path), "--no-progress"]
    assert collect.main(argv) == 0  # `collect` hands point mazes to collect_maze
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    env_space = gym.make("PointMaze_UMaze-v3").observation_space
    means = {}
    for dataset_id in ("pointmaze/umaze-v0", "pointmaze/umaze-random-v0"):
        dataset = minari.load_dataset(dataset_id)
        assert dataset.observation_space == env_space and isinstance(dataset.observation_space, gym.spaces.Dict)
        assert dataset.total_steps == 250 and dataset.total_episodes == 3
        episodes = list(dataset.iterate_episodes())
        assert [len(e.rewards) for e in episodes] == [100, 100, 50] and all(e.truncations[-1] for e in episodes)
        first = episodes[0]
        assert set(first.observations) == {"observation", "achieved_goal", "desired_goal"}
        assert first.observations["observation"].shape == (101, 4)
        np.testing.assert_array_equal(first.observations["achieved_goal"], first.observations["observation"][:, :2])
        assert set(np.unique(np.concatenate([e.rewards for e in episodes]))) <= {0.0, 1.0}  # sparse
        metadata = dataset.storage.metadata
        assert metadata["ref_min_score"] < metadata["ref_max_score"]
        assert metadata["ref_min_success_rate"] < metadata["ref_max_success_rate"] == 1.0
        behavior = metadata["behavior_eval_return"]  # the noisy planner's return in the eval env, or random's
        assert behavior > metadata["ref_min_score"] if "random" not in dataset_id else behavior == metadata["ref_min_score"]
        assert dataset.recover_environment().spec.kwargs["reset_target"]
        eval_env = dataset.recover_environment(eval_env=True)
        assert eval_env.spec.max_episode_steps == 150 and eval_env.spec.kwargs["maze_map"][1][1] == "g"
        means[dataset_id] = np.mean([e.rewards.sum() for e in episodes])
    assert means["pointmaze/umaze-v0"] > means["pointmaze/umaze-random-v0"]
    assert collect.main(argv) == 1  # exists


def test_shipped_umaze_dataset(monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(package_datasets_dir()))
    dataset = minari.load_dataset("pointmaze/umaze-v0")
    eval_env = dataset.recover_environment(eval_env=True)
    assert dataset.observation_space == eval_env.observation_space == gym.make("PointMaze_UMaze-v3").observation_space
    assert dataset.total_steps >= 50_000
    metadata = dataset.storage.metadata
    assert metadata["ref_max_score"] > metadata["ref_min_score"] and metadata["num_episodes_average_score"] >= 10
    obs, _ = eval_env.reset(seed=0)
    assert eval_env.observation_space.contains(obs)
    episode = next(dataset.iterate_episodes())
    assert episode.rewards.sum() > 0


def test_bad_arguments_and_missing_extra(tmp_path, monkeypatch, capsys):
    argv = ["--env", "PointMaze_UMaze-v3", "--out", str(tmp_path), "--no-progress"]
    assert collect_maze.main([*argv, "--ref-episodes", "3"]) == 2
    assert collect_maze.main(["--env", "Pendulum-v1", "--out", str(tmp_path)]) == 2
    with pytest.raises(UsageError, match="--kind"):  # sb3-pola prints it as one line
        collect.main([*argv, "--kind", "medium"])  # a locomotion kind
    capsys.readouterr()
    monkeypatch.setitem(sys.modules, "gymnasium_robotics", None)  # as if not installed
    with pytest.raises(collect_maze.MissingExtraError, match=r'pip install "sb3_pola\[maze\]"'):
        collect.main(argv)
    assert cli.main(["collect", *argv]) == 2  # the command line turns it into one line and status 2
    err = capsys.readouterr().err
    assert 'sb3-pola collect needs the "maze" extra: pip install "sb3_pola[maze]"' in err and "Traceback" not in err
    assert not (tmp_path / "pointmaze").exists()
