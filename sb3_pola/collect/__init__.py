"""``sb3-pola collect``: record D4RL-style Minari datasets.

:mod:`sb3_pola.collect.mujoco` records any continuous-action Gymnasium env with SB3's SAC (kinds ``random``,
``medium``, ``expert``, ``medium-replay``, ``medium-expert``); :mod:`sb3_pola.collect.maze` records
Gymnasium-Robotics point mazes with a scripted planner. Both write with :mod:`sb3_pola.collect.writer` and record
episodes with :mod:`sb3_pola.collect.episodes`.
"""

from __future__ import annotations

import argparse
import sys

from sb3_pola.collect import maze, mujoco


def main(argv: list[str] | None = None) -> int:
    """``sb3-pola collect`` / ``python -m sb3_pola.collect``: a point maze (``--env PointMaze_...``) or any other env."""
    argv = list(sys.argv[1:] if argv is None else argv)
    peek = argparse.ArgumentParser(add_help=False)
    peek.add_argument("--env")
    if maze.is_maze_env(peek.parse_known_args(argv)[0].env):
        return maze.main(argv)
    return mujoco.main(argv)
