"""``sb3-pola peers``: d3rlpy's baselines (TD3+BC, IQL, BC) on the score grid's datasets and evaluation protocol,
into score's output folder (:mod:`sb3_pola.grid.peers`)."""

from __future__ import annotations

import argparse
import datetime
import json
import pathlib
import sys
from typing import Any

from sb3_pola.cli.options import datasets_path
from sb3_pola.common.arguments import ArgumentParser, int_at_least
from sb3_pola.common.machine import machine_info
from sb3_pola.grid import peers
from sb3_pola.grid.report import write_reports
from sb3_pola.grid.rows import slug
from sb3_pola.grid.variants import DEFAULT_DATASETS, DEFAULT_VARIANTS


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = ArgumentParser(
        prog="sb3-pola peers",
        description="d3rlpy baselines (TD3+BC, IQL, BC) on the same datasets and evaluation protocol as sb3-pola score.",
    )
    parser.add_argument("--datasets", nargs="+", default=DEFAULT_DATASETS, help="Minari dataset ids")
    parser.add_argument("--seeds", nargs="+", type=int_at_least(0), default=[0, 1, 2])
    parser.add_argument("--algos", nargs="+", default=peers.ALGOS, choices=peers.ALGOS)
    parser.add_argument("--steps", type=int_at_least(1), default=10_000, help="gradient steps per run")
    parser.add_argument("--eval-freq", type=int_at_least(1), default=2_000, help="gradient steps between evaluations")
    parser.add_argument("--eval-episodes", type=int_at_least(1), default=10, help="episodes per evaluation")
    parser.add_argument("--data-dir", help="folder of the Minari datasets (sets MINARI_DATASETS_PATH)")
    parser.add_argument("--out", default="outputs/score", help="output folder (score's, so table.md shows both)")
    parser.add_argument("--threads", type=int_at_least(1), default=1, help="torch CPU threads of each run")
    parser.add_argument("--venv", default=peers.DEFAULT_VENV, help="virtual environment of d3rlpy (created if missing)")
    parser.add_argument("--python", default=sys.executable, help="Python that creates the venv")
    parser.add_argument("--dry-run", action="store_true", help="print the cells, run nothing")
    parser.add_argument("-v", "--verbose", type=int, default=1)
    return parser.parse_args(argv)


def budget(args: argparse.Namespace) -> dict[str, Any]:
    """What decides a cell's result (a change is another experiment: refused in the same folder)."""
    return {"steps": args.steps, "eval_freq": args.eval_freq, "eval_episodes": args.eval_episodes}


def main(argv: list[str] | None = None) -> int:
    """``sb3-pola peers``; returns the exit code."""
    args = parse_args(argv)
    with datasets_path(args.data_dir):
        return _main(args, argv)


def _main(args: argparse.Namespace, argv: list[str] | None) -> int:
    """``sb3-pola peers`` with ``--data-dir`` in effect (:func:`main`)."""
    out = pathlib.Path(args.out)
    cells = [(d, a, s) for s in args.seeds for d in args.datasets for a in args.algos]
    config_path = out / "peers_config.json"
    saved = json.loads(config_path.read_text()) if config_path.exists() else None
    if saved is not None and {k: saved.get(k) for k in budget(args)} != budget(args):
        print(
            f"[peers] {out} holds baselines of another budget ({ {k: saved.get(k) for k in budget(args)} }, this one "
            f"{budget(args)}): use another --out, or the same options",
            file=sys.stderr,
        )
        return 2
    print(f"[peers] {len(cells)} d3rlpy runs of {args.steps} steps -> {out}")
    if args.dry_run:
        for cell in cells:
            print("  " + peers.cell_name(*cell))
        return 0
    out.mkdir(parents=True, exist_ok=True)
    python = peers.ensure_venv(pathlib.Path(args.venv), args.python, args.verbose)
    info = {
        **budget(args),
        "algos": sorted({*args.algos, *(saved or {}).get("algos", [])}),
        "variants": {algo: peers.VARIANT_NAMES[algo] for algo in peers.ALGOS},
        "versions": peers.peer_versions(python),
        "machine": machine_info("cpu"),
        "threads": args.threads,
        "started": (saved or {}).get("started", datetime.date.today().isoformat()),
        "date": datetime.date.today().isoformat(),
        "command": "sb3-pola peers " + " ".join(sys.argv[1:] if argv is None else argv),
    }
    config_path.write_text(json.dumps(info, indent=1))
    exported: dict[str, pathlib.Path] = {}
    for dataset, algo, seed in cells:
        name = peers.cell_name(dataset, algo, seed)
        if (out / "peers_cells" / f"{name}.json").exists():
            if args.verbose:
                print(f"[peers] {name}: done, skipped")
            continue
        if dataset not in exported:
            exported[dataset] = peers.export_dataset(dataset, out / "peers_data" / f"{slug(dataset)}.npz")
        peers.run_cell(python, exported[dataset], dataset, algo, seed, args, out)
        write_reports(out, DEFAULT_VARIANTS, _score_config(out))
    write_reports(out, DEFAULT_VARIANTS, _score_config(out))
    return 0


def _score_config(out: pathlib.Path) -> dict[str, Any] | None:
    path = out / "config.json"
    return json.loads(path.read_text()) if path.exists() else None


if __name__ == "__main__":
    raise SystemExit(main())
