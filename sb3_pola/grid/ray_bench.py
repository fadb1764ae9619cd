"""Wall time of a small ``sb3-pola score`` grid, sequential against ``--ray`` (``python -m sb3_pola.grid.ray_bench``).

Both runs are ``sb3-pola score`` commands in subprocesses, one after the other, on the same grid (by default the
shipped InvertedPendulum datasets x T0, T1 x one seed, tiny networks, a few hundred steps), each into a fresh
folder. The Ray run starts a local Ray instance (its start-up is part of its time) or joins ``--address``.
Prints both wall times, their ratio and whether the two runs' scores are equal.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import subprocess
import sys
import tempfile
import time

from sb3_pola.grid.rows import CSV_FIELDS, read_rows

DATASETS = ["invertedpendulum/medium-v0", "invertedpendulum/medium-replay-v0"]
TINY = ["--preset", "cpu", "--no-compile", "--device", "cpu", "--threads", "1", "-v", "0", "--net-arch", "32", "32"]
TINY += ["--n-critics", "2", "--batch-size", "64", "--dynamics-steps", "100"]
TINY += ["--dynamics-kwargs", '{"hidden_dim": 32, "n_layers": 2, "n_members": 2, "n_elites": 1}']


def run_score(arguments: list[str]) -> float:
    """Run ``sb3-pola score`` with these arguments in a subprocess; return its wall time in seconds."""
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "sb3_pola.cli", "score", *arguments], check=True)
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sb3_pola.grid.ray_bench", description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", nargs="+", default=DATASETS)
    parser.add_argument("--variants", nargs="+", default=["T0", "T1"])
    parser.add_argument("--seeds", nargs="+", default=["0"])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--eval-freq", type=int, default=100)
    parser.add_argument("--eval-episodes", type=int, default=2)
    parser.add_argument("--address", help="join this Ray cluster (auto, host:port) instead of starting one")
    parser.add_argument("--data-dir", help="folder of the Minari datasets")
    parser.add_argument("--out", help="folder of the two runs (default: a temporary one)")
    args = parser.parse_args(argv)
    grid = ["--datasets", *args.datasets, "--variants", *args.variants, "--seeds", *args.seeds]
    grid += ["--steps", str(args.steps), "--eval-freq", str(args.eval_freq), "--eval-episodes", str(args.eval_episodes)]
    grid += TINY + (["--data-dir", args.data_dir] if args.data_dir else [])
    out = pathlib.Path(args.out or tempfile.mkdtemp(prefix="score_grid_bench_"))
    n_cells = len(args.datasets) * len(args.variants) * len(args.seeds)
    print(
        f"grid: {n_cells} cells ({' '.join(args.datasets)} x {' '.join(args.variants)} x seeds {' '.join(args.seeds)}), "
        f"{args.steps} steps, {os.cpu_count()} CPU cores; folders in {out}"
    )
    sequential = run_score([*grid, "--out", str(out / "sequential")])
    print(f"sequential: {sequential:.1f} s", flush=True)
    ray = run_score([*grid, "--out", str(out / "ray"), "--ray", *([args.address] if args.address else [])])
    print(f"--ray:      {ray:.1f} s", flush=True)

    def scores(folder: str) -> list[tuple]:
        rows = read_rows(out / folder / "scores.csv")
        return [tuple(str(r[k]) for k in CSV_FIELDS if k != "wall_s") for r in rows]  # str: NaN equals NaN

    print(f"ratio sequential / ray: {sequential / ray:.2f}")
    print(f"scores equal: {scores('sequential') == scores('ray')} ({len(scores('ray'))} rows)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
