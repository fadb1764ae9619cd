"""``sb3-pola score``: POLA and its ablations over datasets and seeds, learning curves, a Table-I-style table.

Every (dataset, variant, seed) *cell* trains one POLA model for ``--steps`` gradient steps and
evaluates its EMA policy every ``--eval-freq`` steps on ``--eval-episodes`` episodes of the
dataset's env (D4RL-normalised score from the dataset's reference scores). Outputs, all under
``--out``:

- ``scores.csv``: one row per evaluation (written as it happens);
- ``table.md``: final and best score, mean +- std over seeds, next to the paper's Table I;
- ``fig_rollout_<dataset>.png`` (paper Fig. 3: T in {0, 1, 3, 5}) and
  ``fig_products_<dataset>.png`` (paper Fig. 4: the actor on the products (``-products``) or the raw state (the
  default), products in the critic too), BC as the floor;
- ``config.json`` (budget, machine, date), ``cells/`` (finished cells), ``ckpt/`` (a checkpoint
  per running cell, saved at every evaluation), ``dynamics/`` (fitted dynamics models),
  ``models/`` (every finished cell's final model) and ``train/<cell>/`` (the training statistics
  of the SB3 logger, ``train/*`` every ``--log-interval`` steps, as CSV: one file per segment of a
  resumed run).

``--out`` is a folder, or an fsspec URL (``s3://bucket/run`` with s3fs installed, ``file:///nfs/run``, ...):
each cell then works in a local scratch folder synchronised with the storage and writes its rows to
``rows/<cell>.csv``, merged into ``scores.csv`` by the driver (:func:`~sb3_pola.grid.cell.run_stored_cell`,
:mod:`sb3_pola.grid.storage`).

``--reevaluate RULE ...`` evaluates the saved final models again under other evaluation rules
(``ema``, ``online``, ``stochastic``: one sample of the noisy reverse chain, ``candidates<N>``: N noisy
candidates ranked by the critic, as Diffusion-QL evaluates) and writes ``reeval.csv`` and ``reeval.md``.

An interrupted run is resumed by the same command: finished cells are skipped, a running cell
continues from its last checkpoint. ``--ray [ADDRESS]`` runs the cells as Ray tasks, on this machine or a
cluster (:mod:`sb3_pola.grid.ray_runner`). Presets: ``cpu`` (light networks, a few thousand steps),
``paper`` (the paper's configuration, for a CUDA GPU), ``auto`` (``paper`` on CUDA, else ``cpu``).
Any preset value can be overridden from the command line.
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from dataclasses import asdict

import torch as th

from sb3_pola.cli.options import datasets_path
from sb3_pola.common.arguments import ArgumentParser, int_at_least, json_object
from sb3_pola.common.machine import machine_info
from sb3_pola.grid.ray_runner import run_grid
from sb3_pola.grid.reevaluate import reevaluate
from sb3_pola.grid.report import publish_reports
from sb3_pola.grid.runner import run_sequential, run_stored_sequential
from sb3_pola.grid.storage import Storage, Workspace, is_url, open_workspace
from sb3_pola.grid.variants import (
    ALL_VARIANTS,
    DEFAULT_DATASETS,
    DEFAULT_VARIANTS,
    PRESETS,
    build_config,
    parse_eval_rule,
    resolve_device,
)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = ArgumentParser(
        prog="sb3-pola score",
        description="Train POLA and its ablations over datasets and seeds; write scores.csv, table.md and learning curves.",
    )
    parser.add_argument("--preset", choices=["auto", *PRESETS], default="auto", help="auto: paper on CUDA, cpu otherwise")
    parser.add_argument("--datasets", nargs="+", default=DEFAULT_DATASETS, help="Minari dataset ids")
    parser.add_argument("--variants", nargs="+", default=DEFAULT_VARIANTS, choices=ALL_VARIANTS, metavar="VARIANT")
    parser.add_argument("--seeds", nargs="+", type=int_at_least(0), default=[0, 1, 2])
    parser.add_argument("--steps", type=int_at_least(1), help="gradient steps per run")
    parser.add_argument("--eval-freq", type=int_at_least(1), help="gradient steps between evaluations")
    parser.add_argument("--eval-episodes", type=int_at_least(1), help="episodes per evaluation")
    parser.add_argument("--batch-size", type=int_at_least(1))
    parser.add_argument("--net-arch", type=int, nargs="+", help="hidden sizes of actor and critics")
    parser.add_argument("--n-critics", type=int_at_least(1))
    parser.add_argument("--top-k", type=int_at_least(1))
    parser.add_argument("--n-action-samples", type=int_at_least(1), help="candidate actions per state at evaluation")
    parser.add_argument("--dynamics-steps", type=int_at_least(1), help="cap on the dynamics model's fit (gradient steps)")
    parser.add_argument(
        "--dynamics-kwargs", type=json_object, help="JSON of EnsembleDynamics arguments, e.g. '{\"hidden_dim\": 128}'"
    )
    parser.add_argument(
        "--share-dynamics", action=argparse.BooleanOptionalAction, default=None, help="one dynamics fit per dataset"
    )
    parser.add_argument(
        "--extra",
        type=json_object,
        help='JSON of further POLA arguments, e.g. \'{"eta": 0.5}\'; a "policy_kwargs" entry adds to the policy\'s '
        "arguments; batch size, critics, top-K, the dynamics model, seeds and device have their own flags",
    )
    parser.add_argument(
        "--compile", action=argparse.BooleanOptionalAction, default=None, help="compile_update (the cpu preset: on)"
    )
    parser.add_argument("--device", default="auto", help="cpu, cuda, cuda:1 or auto")
    parser.add_argument("--data-dir", help="folder of the Minari datasets (sets MINARI_DATASETS_PATH)")
    parser.add_argument(
        "--out", default="outputs/score", help="output folder, or an fsspec URL (s3://bucket/run with s3fs installed, ...)"
    )
    parser.add_argument("--threads", type=int_at_least(0), help="torch CPU threads")
    parser.add_argument("--log-interval", type=int, help="gradient steps between rows of the training statistics")
    parser.add_argument(
        "--eval-rule",
        metavar="RULE",
        help="how the evaluations during training act: ema (default: predict(deterministic=True), the EMA actor's "
        "chain under the policy's deterministic_rule, the mode of its samples by default), online, "
        "[online-]stochastic (one sample of the noisy chain), [online-]candidates<N>",
    )
    parser.add_argument(
        "--reevaluate",
        nargs="+",
        metavar="RULE",
        help="re-evaluate the saved final models under these rules: ema, online, [online-]stochastic, [online-]candidates<N>",
    )
    parser.add_argument(
        "--ray",
        nargs="?",
        const="local",
        metavar="ADDRESS",
        help="run the cells as Ray tasks: no ADDRESS starts Ray on this machine, 'auto' or host:port joins a cluster",
    )
    parser.add_argument("--cpus-per-cell", type=float, default=1.0, help="with --ray: CPUs reserved per cell")
    parser.add_argument("--gpus-per-cell", type=float, default=0.0, help="with --ray: GPUs per cell (0.25: four per GPU)")
    parser.add_argument("--max-retries", type=int, default=3, help="with --ray: reruns of a cell whose worker died")
    parser.add_argument("--report-only", action="store_true", help="only rewrite table.md and the figures from scores.csv")
    parser.add_argument("--dry-run", action="store_true", help="print the resolved configuration and the cells, run nothing")
    parser.add_argument("-v", "--verbose", type=int, default=1)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """``sb3-pola score``; returns the exit code."""
    args = parse_args(argv)
    if is_url(args.out):
        try:
            Storage(args.out)
        except (ImportError, ValueError) as error:  # the URL's fsspec backend is missing, or an unknown protocol
            print(f"[score] --out {args.out}: {error}", file=sys.stderr)
            return 2
    with open_workspace(args.out) as view, datasets_path(args.data_dir):
        return _main(args, argv, view)


def _main(args: argparse.Namespace, argv: list[str] | None, view: Workspace) -> int:
    """``sb3-pola score`` with its output's workspace opened (:func:`main`)."""
    out = view.folder
    config_path = out / "config.json"
    view.pull("config.json")
    if args.report_only:
        saved = json.loads(config_path.read_text()) if config_path.exists() else None
        publish_reports(view, args.variants, saved)
        return 0
    if args.threads:
        th.set_num_threads(args.threads)
    # the cells run on the cluster's GPUs, not on the driver's
    device = "cuda" if args.ray and args.gpus_per_cell > 0 and args.device == "auto" else resolve_device(args.device)
    if args.reevaluate:
        return _reevaluate_in(view, args, device)
    config = build_config(args, device)
    cells = [(d, v, s) for s in args.seeds for d in args.datasets for v in args.variants]
    info = {
        **asdict(config),
        "signature": config.signature(),
        "device": device,
        "machine": machine_info(device),
        "date": datetime.date.today().isoformat(),
        "command": "sb3-pola score " + " ".join(sys.argv[1:] if argv is None else argv),
    }
    if config_path.exists():
        saved = json.loads(config_path.read_text())
        if saved.get("signature") != config.signature():
            print(
                f"[score] {args.out} holds runs of another configuration (signature {saved.get('signature')}, this one "
                f"{config.signature()}): use another --out, or the same options",
                file=sys.stderr,
            )
            return 2
        info["started"] = saved.get("started", info["date"])
    else:
        info["started"] = info["date"]
    print(f"[score] preset {config.preset} on {device}: {len(cells)} runs of {config.steps} steps -> {args.out}")
    if args.dry_run:
        print(json.dumps(info, indent=1))
        return 0
    config_path.write_text(json.dumps(info, indent=1))
    view.push("config.json")
    if args.ray:
        return run_grid(args, cells, config, info, view, device)
    if view.storage is not None:
        return run_stored_sequential(args, cells, config, info, view, device)
    return run_sequential(args, cells, config, info, view, device)


def _reevaluate_in(view: Workspace, args: argparse.Namespace, device: str) -> int:
    """``--reevaluate``: the saved models and markers pulled, ``reeval.csv`` and ``reeval.md`` pushed."""
    for rule in args.reevaluate:  # unknown rules fail before any model is downloaded
        parse_eval_rule(rule)
    config_path = view.folder / "config.json"
    saved = json.loads(config_path.read_text()) if config_path.exists() else {}
    episodes = args.eval_episodes or int(saved.get("eval_episodes", 10))
    view.pull("reeval.csv")
    view.pull_tree("cells")
    view.pull_tree("models")
    reevaluate(view.folder, args.reevaluate, episodes, device, verbose=args.verbose)
    view.push("reeval.csv", "reeval.md")
    print(f"[score] wrote {view.shown('reeval.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
