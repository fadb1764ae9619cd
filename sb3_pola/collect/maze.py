"""Record D4RL maze2d-style Minari datasets in Gymnasium-Robotics point mazes (``sb3-pola collect --env PointMaze_*``).

Kinds:

- ``planner`` (D4RL's maze2d data, whose datasets have no kind in their name): a scripted expert,
  :class:`MazePlanner`, with Gaussian action noise. It follows a shortest path over the maze
  cells (breadth-first search from the goal cell) with a PD controller towards the centre of the
  next cell, and towards the goal itself once in the goal's cell. The env runs as a continuing
  task that draws a new goal whenever one is reached (``continuing_task=True, reset_target=True``),
  so one episode visits many goals; episodes are cut at ``--episode-steps``;
- ``random``: uniform random actions in the same env.

Observations are stored as the env gives them: a Dict of ``observation`` (x, y, vx, vy),
``achieved_goal`` and ``desired_goal``. The reward is the env's: ``sparse`` (1 within 0.45 of the
goal) for ``PointMaze_UMaze-v3`` and the like, dense for the ``...Dense-v3`` ids. On the step that
reaches a goal the returned observation still shows that goal; the next one shows the new goal.

The evaluation env (the dataset's ``eval_env_spec``) is D4RL's and Minari's: the goal is fixed to
one cell (``EVAL_GOAL_CELLS``; the env's own goal cells in other maps), the agent starts in a random
other cell, the goal is kept once reached, and episodes last the env's time limit (``--eval-steps``),
so the return counts the steps spent at the goal. ``ref_min_score`` is the mean return of uniform
random actions there, ``ref_max_score`` that of the planner without noise, each over
``--ref-episodes`` (>= 10) episodes; their success rates (an episode with a step within 0.45 of the
goal) go into the metadata as ``ref_min_success_rate`` / ``ref_max_success_rate``, and those of the
policy that recorded the data (the noisy planner, or random actions) as ``behavior_eval_return`` /
``behavior_eval_success_rate``.

Datasets are written like :mod:`sb3_pola.collect`'s: ``<name>/<maze>-v<version>`` (planner) and
``<name>/<maze>-random-v<version>`` under ``--out`` or ``$MINARI_DATASETS_PATH``; ``<name>`` is
``pointmaze``, ``<maze>`` the map's name (``umaze``, ``medium``, ``large``, ``umaze-dense``...).

Needs the ``maze`` extra (``pip install "sb3_pola[maze]"``: Gymnasium-Robotics). Example::

    sb3-pola collect --env PointMaze_UMaze-v3 --kind planner random --steps 100000 --seed 0 --out sb3_pola/data/datasets
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import sys
import time
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import EnvSpec

from sb3_pola.collect.episodes import rollout, run_episodes
from sb3_pola.collect.writer import MIN_REF_EPISODES, dataset_summary, datasets_root, write_dataset
from sb3_pola.common.arguments import ArgumentParser
from sb3_pola.common.extras import import_gymnasium_robotics, missing_extra_message

KINDS = ("planner", "random")
MAZE_PREFIX = "PointMaze_"
# D4RL maze2d's (and Minari's pointmaze) evaluation goal cell (row, column) of each map
EVAL_GOAL_CELLS = {"umaze": (1, 1), "medium": (6, 6), "large": (7, 9)}
# row, column steps to the four neighbouring cells
_MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))

Cell = tuple[int, int]


class MissingExtraError(ImportError):
    """Gymnasium-Robotics (the ``maze`` extra) is not installed; ``sb3-pola`` turns it into its extra message."""


def is_maze_env(env_id: str | None) -> bool:
    """Whether ``env_id`` names a Gymnasium-Robotics point maze (``PointMaze_UMaze-v3``...)."""
    return env_id is not None and env_id.split("/")[-1].startswith(MAZE_PREFIX)


def require_robotics() -> None:
    """Import Gymnasium-Robotics and register its envs; :class:`MissingExtraError` if it is not installed."""
    try:
        gymnasium_robotics = import_gymnasium_robotics()  # without its notice about the (unrelated) Adroit envs
    except ImportError as error:
        raise MissingExtraError(
            f"{missing_extra_message('collect', 'maze', error)} (or pip install gymnasium-robotics)"
        ) from error
    gym.register_envs(gymnasium_robotics)


def maze_name(env_id: str) -> str:
    """``PointMaze_UMaze-v3`` -> ``umaze``; ``PointMaze_MediumDense-v3`` -> ``medium-dense``."""
    name = env_id.split("/")[-1].removeprefix(MAZE_PREFIX).rsplit("-v", 1)[0]
    dense = name.endswith("Dense")
    name = name.removesuffix("Dense").replace("_", "-").lower()
    return f"{name}-dense" if dense else name


def is_free(maze_map: list[list[Any]], cell: Cell) -> bool:
    """Whether ``cell`` lies in the map and is not a wall (walls are 1; free cells 0, "g", "r" or "c")."""
    row, col = cell
    return 0 <= row < len(maze_map) and 0 <= col < len(maze_map[row]) and maze_map[row][col] != 1


def cell_distances(maze_map: list[list[Any]], goal: Cell) -> dict[Cell, int]:
    """Steps from every free cell that can reach ``goal`` to it, moving between side-by-side free cells (BFS)."""
    distances = {goal: 0}
    queue = collections.deque([goal])
    while queue:
        row, col = queue.popleft()
        for d_row, d_col in _MOVES:
            cell = (row + d_row, col + d_col)
            if cell not in distances and is_free(maze_map, cell):
                distances[cell] = distances[(row, col)] + 1
                queue.append(cell)
    return distances


def next_cell(distances: dict[Cell, int], cell: Cell) -> Cell | None:
    """The neighbour of ``cell`` one step closer to the goal of ``distances``; None at the goal or off the grid."""
    if distances.get(cell, 0) == 0:
        return None
    neighbours = [(cell[0] + d_row, cell[1] + d_col) for d_row, d_col in _MOVES]
    return min((n for n in neighbours if n in distances), key=distances.__getitem__)


def shortest_path(maze_map: list[list[Any]], start: Cell, goal: Cell) -> list[Cell]:
    """Cells from ``start`` to ``goal`` (both included) along a shortest path; empty if there is none."""
    distances = cell_distances(maze_map, goal)
    if start not in distances:
        return []
    path = [start]
    while (step := next_cell(distances, path[-1])) is not None:
        path.append(step)
    return path


class MazePlanner:
    """D4RL maze2d's scripted expert: a shortest path over the maze cells and a PD controller.

    The target is the centre of the next cell on a shortest path from the agent's cell to the
    goal's cell, and the goal itself once the agent is in the goal's cell; the action is
    ``p_gain * (target - position) + d_gain * velocity`` plus Gaussian noise, clipped to the bounds.

    :param maze: the env's ``Maze`` (``env.unwrapped.maze``: the map and the cell <-> x, y conversions)
    :param p_gain: gain on the distance to the target
    :param d_gain: gain on the velocity (negative: damping)
    :param noise: standard deviation of the Gaussian action noise (D4RL's datasets: 0.5)
    :param seed: seed of the noise
    :param low: lower action bound
    :param high: upper action bound
    """

    def __init__(
        self,
        maze: Any,
        p_gain: float = 10.0,
        d_gain: float = -1.0,
        noise: float = 0.0,
        seed: int | None = None,
        low: float | np.ndarray = -1.0,
        high: float | np.ndarray = 1.0,
    ) -> None:
        self.maze = maze
        self.p_gain = p_gain
        self.d_gain = d_gain
        self.noise = noise
        self.low, self.high = low, high
        self.rng = np.random.default_rng(seed)
        self._distances: dict[Cell, dict[Cell, int]] = {}

    def cell(self, xy: np.ndarray) -> Cell:
        row, col = self.maze.cell_xy_to_rowcol(xy)
        return int(row), int(col)

    def target(self, position: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Where the controller steers: the next cell's centre, or the goal in the goal's cell."""
        goal_cell = self.cell(goal)
        if goal_cell not in self._distances:
            self._distances[goal_cell] = cell_distances(self.maze.maze_map, goal_cell)
        step = next_cell(self._distances[goal_cell], self.cell(position))
        return goal if step is None else self.maze.cell_rowcol_to_xy(np.array(step))

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        position, velocity = obs["observation"][:2], obs["observation"][2:4]
        action = self.p_gain * (self.target(position, obs["desired_goal"]) - position) + self.d_gain * velocity
        if self.noise > 0:
            action = action + self.rng.normal(0.0, self.noise, size=action.shape)
        return np.clip(action, self.low, self.high).astype(np.float32)


def planner_for(env: gym.Env, noise: float = 0.0, seed: int | None = None, **kwargs: Any) -> MazePlanner:
    """A :class:`MazePlanner` for ``env``'s maze and action bounds."""
    space = env.action_space
    assert isinstance(space, gym.spaces.Box)
    return MazePlanner(env.unwrapped.maze, noise=noise, seed=seed, low=space.low, high=space.high, **kwargs)  # type: ignore[attr-defined]


def data_env_spec(env_id: str, episode_steps: int | None) -> EnvSpec:
    """The recording env: a continuing task with a new goal on reaching one, ``episode_steps`` long."""
    spec = gym.spec(env_id)
    kwargs = {**spec.kwargs, "continuing_task": True, "reset_target": True}
    return dataclasses.replace(spec, kwargs=kwargs, max_episode_steps=episode_steps or spec.max_episode_steps)


def eval_env_spec(env_id: str, eval_steps: int | None) -> EnvSpec:
    """The evaluation env: D4RL's fixed goal cell (if the map has one in ``EVAL_GOAL_CELLS``), goal kept once reached."""
    spec = gym.spec(env_id)
    kwargs = {**spec.kwargs, "continuing_task": True, "reset_target": False}
    goal_cell = EVAL_GOAL_CELLS.get(maze_name(env_id).removesuffix("-dense"))
    maze_map = kwargs.get("maze_map")
    if goal_cell is not None and maze_map is not None:
        maze_map = [list(row) for row in maze_map]
        row, col = goal_cell
        maze_map[row][col] = "g"  # the other free cells (0) become the start cells
        kwargs["maze_map"] = maze_map
    return dataclasses.replace(spec, kwargs=kwargs, max_episode_steps=eval_steps or spec.max_episode_steps)


def make_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog="sb3-pola collect", description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--env", required=True, help="Gymnasium-Robotics point maze id, e.g. PointMaze_UMaze-v3")
    parser.add_argument("--kind", nargs="+", choices=KINDS, default=["planner"], help="dataset kind(s) to make")
    parser.add_argument("--steps", type=int, default=100_000, help="transitions per dataset")
    parser.add_argument("--episode-steps", type=int, default=None, help="episode length (default the env's time limit)")
    parser.add_argument("--noise", type=float, default=0.5, help="std of the planner's Gaussian action noise (D4RL: 0.5)")
    parser.add_argument("--p-gain", type=float, default=10.0, help="planner's gain on the distance to the waypoint")
    parser.add_argument("--d-gain", type=float, default=-1.0, help="planner's gain on the velocity")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="datasets root (default $MINARI_DATASETS_PATH or ~/.minari/datasets)")
    parser.add_argument("--name", default="pointmaze", help="dataset id prefix")
    parser.add_argument("--version", type=int, default=0, help="dataset version suffix -v<N>")
    parser.add_argument("--ref-episodes", type=int, default=100, help="evaluation episodes for each reference score")
    parser.add_argument("--eval-steps", type=int, default=None, help="evaluation episode length (default the env's)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing datasets")
    parser.add_argument("--no-progress", action="store_true")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``sb3-pola collect --env PointMaze_...`` / ``python -m sb3_pola.collect.maze``."""
    args = make_parser().parse_args(argv)
    if args.ref_episodes < MIN_REF_EPISODES:
        print(f"--ref-episodes must be >= {MIN_REF_EPISODES}", file=sys.stderr)
        return 2
    if not is_maze_env(args.env):
        print(f"{args.env} is not a point maze ({MAZE_PREFIX}...-v3)", file=sys.stderr)
        return 2
    require_robotics()  # MissingExtraError: sb3-pola's dispatcher prints which extra to install
    try:
        data_spec, eval_spec = data_env_spec(args.env, args.episode_steps), eval_env_spec(args.env, args.eval_steps)
    except gym.error.Error as error:
        print(f"{args.env}: {error}", file=sys.stderr)
        return 2
    out_root = datasets_root(args.out)
    maze = maze_name(args.env)
    kinds = list(dict.fromkeys(args.kind))
    ids = {kind: f"{args.name}/{maze}{'' if kind == 'planner' else '-' + kind}-v{args.version}" for kind in kinds}
    for dataset_id in ids.values():
        if (out_root / dataset_id).exists() and not args.overwrite:
            print(f"{out_root / dataset_id} exists: pass --overwrite to replace it", file=sys.stderr)
            return 1
    start_time = time.perf_counter()
    gains = {"p_gain": args.p_gain, "d_gain": args.d_gain}

    eval_env = gym.make(eval_spec)
    random_returns, random_success = run_episodes(eval_env, None, args.ref_episodes, seed=args.seed + 20_000)
    expert_returns, expert_success = run_episodes(
        eval_env, planner_for(eval_env, **gains), args.ref_episodes, args.seed + 30_000
    )
    references = {
        "ref_min_score": float(np.mean(random_returns)),
        "ref_max_score": float(np.mean(expert_returns)),
        "ref_min_success_rate": float(np.mean(random_success)),
        "ref_max_success_rate": float(np.mean(expert_success)),
    }
    summary: dict[str, Any] = {"env": args.env, "seed": args.seed, **references, "ref_episodes": args.ref_episodes}
    summary["datasets"] = {}

    env = gym.make(data_spec)
    for kind in kinds:
        dataset_id = ids[kind]
        seed = args.seed + 1 + KINDS.index(kind) * 1000
        episode_steps = data_spec.max_episode_steps
        if kind == "planner":
            policy = planner_for(env, noise=args.noise, seed=seed, **gains)
            algorithm = f"maze planner (BFS over cells, PD p_gain {args.p_gain}, d_gain {args.d_gain}), noise std {args.noise}"
            description = f"D4RL maze2d-style: {algorithm}; a new goal on reaching one; episodes of {episode_steps} steps"
            episodes = rollout(env, policy, args.steps, seed, not args.no_progress, dataset_id)
            noisy = planner_for(eval_env, noise=args.noise, seed=seed + 500, **gains)
            behavior_returns, behavior_success = run_episodes(eval_env, noisy, args.ref_episodes, args.seed + 30_000)
        else:
            algorithm = "uniform random actions"
            description = f"uniform random actions; a new goal on reaching one; episodes of {episode_steps} steps"
            episodes = rollout(env, None, args.steps, seed, not args.no_progress, dataset_id)
            behavior_returns, behavior_success = random_returns, random_success
        extra = {key: value for key, value in references.items() if key.endswith("success_rate")}
        extra.update(
            behavior_eval_return=float(np.mean(behavior_returns)), behavior_eval_success_rate=float(np.mean(behavior_success))
        )
        path = write_dataset(
            out_root,
            dataset_id,
            episodes,
            data_spec,
            references["ref_min_score"],
            references["ref_max_score"],
            args.ref_episodes,
            algorithm,
            description,
            args.overwrite,
            eval_env=eval_spec,
            extra_metadata=extra,
            code_permalink="sb3_pola/collect/maze.py",
        )
        summary["datasets"][dataset_id] = {**dataset_summary(path, episodes), **extra}
    summary["seconds"] = round(time.perf_counter() - start_time, 1)
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
