"""``sb3-pola score --ray``: the score grid's (dataset, variant, seed) cells as Ray tasks, on one machine or a cluster.

Every cell is one task running :func:`~sb3_pola.grid.run_stored_cell` against the output,
which every worker must see: a shared folder, or an fsspec URL (``s3://bucket/run`` with s3fs installed;
each task then works in a local scratch folder, pulling its files first and pushing them at every checkpoint,
:mod:`sb3_pola.grid.storage`). A dynamics model shared by several cells is
fitted first by a task of the cell that fits it in the sequential run: it stops after its first gradient
step with a checkpoint, then every cell sharing the model starts, that one continuing from its checkpoint.
On CPU the scores are therefore those of the sequential run.

Each cell writes its evaluation rows to ``rows/<cell>.csv``; the driver merges them into ``scores.csv``
(in the sequential run's order) while the grid runs, and rewrites ``table.md``, the figures and the
diagnostics every few minutes and at the end. The same command resumes: finished cells are skipped and an interrupted cell
continues from its checkpoint. A cell whose worker dies is retried (``--max-retries``); a failing cell is
reported with its error while the others go on, and the exit code is then 1.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time
from collections.abc import Callable
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from sb3_pola.common.extras import missing_extra_message
from sb3_pola.grid.cell import dynamics_path, run_stored_cell
from sb3_pola.grid.report import publish_reports
from sb3_pola.grid.rows import Cell, adopt_rows, cell_name, marker_path, merge_rows
from sb3_pola.grid.storage import open_workspace
from sb3_pola.grid.variants import Config, needs_dynamics

if TYPE_CHECKING:
    from sb3_pola.grid.storage import Workspace

MISSING_RAY = missing_extra_message("score", "ray") + " (for --ray)"
# seconds between two merges of the cells' rows into scores.csv, and between two rewrites of the reports (the
# figures take seconds: not after every one of a large grid's cells)
MERGE_INTERVAL = 10.0
REPORT_INTERVAL = 120.0


def plan_dynamics_fits(
    cells: list[Cell], config: Config, out: pathlib.Path, exists: Callable[[pathlib.Path], bool] = pathlib.Path.exists
) -> dict[pathlib.Path, Cell]:
    """For each dynamics model still to fit, the cell fitting it in the sequential run: the first one needing it.

    :param cells: the cells to run, in the sequential run's order
    :param config: the grid's configuration
    :param out: output folder
    :param exists: whether a file under ``out`` exists (in the storage: :meth:`Workspace.exists`)
    :return: dynamics model path -> cell
    """
    fits: dict[pathlib.Path, Cell] = {}
    for cell in cells:
        path = dynamics_path(out, cell[0], cell[2], config)
        if needs_dynamics(cell[1], config) and not exists(path) and path not in fits:
            fits[path] = cell
    return fits


def cell_task(
    cell: Cell,
    config: dict[str, Any],
    out: str,
    device: str,
    threads: int,
    verbose: int,
    stop_after_dynamics: bool,
    environ: dict[str, str],
    *after: Any,
) -> bool:
    """One cell on a Ray worker: :func:`~sb3_pola.grid.run_stored_cell` writing its rows to ``rows/``.

    :param cell: (dataset, variant, seed)
    :param config: the grid's :class:`~sb3_pola.grid.Config` as a dict
    :param out: output folder or fsspec URL, seen by every worker
    :param device: torch device
    :param threads: torch CPU threads (a fixed count: results on CPU depend on it)
    :param verbose: 0 silent, 1 a line per evaluation
    :param stop_after_dynamics: only fit and save the dynamics model (see ``run_cell``)
    :param environ: environment variables to set first (the datasets' folder)
    :param after: results of the tasks to wait for (Ray passes them once they are done)
    :return: whether the cell finished
    """
    import torch as th

    os.environ.update(environ)
    th.set_num_threads(threads)
    with open_workspace(out) as view:  # a URL: a scratch folder of this task's own
        if view.exists(marker_path(view.folder, cell)):  # finished by its dynamics-fit task (a one-step budget) or a retry
            return True
        return run_stored_cell(view, *cell, Config(**config), device, verbose, stop_after_dynamics)


def _error_text(error: BaseException) -> str:
    """The error of a failed task: the cell's own exception and traceback, or why Ray lost its worker."""
    import ray

    if isinstance(error, ray.exceptions.RayTaskError):
        return str(error).strip()
    return f"{type(error).__name__}: {error}"


def _submit_cells(submit: Callable[..., Any], todo: list[Cell], config: Config, view: Workspace) -> tuple[dict[Any, str], int]:
    """Start the dynamics-fit tasks, then every cell, each after the fit of the dynamics model it uses.

    :param submit: starts a :func:`cell_task` of ``(name, cell, stop_after_dynamics, *tasks_to_wait_for)``
    :param todo: the cells to run, in the sequential run's order
    :param config: the grid's configuration
    :param view: the workspace of the output
    :return: the tasks (object ref -> name), and how many of them are dynamics fits
    """
    out = view.folder
    pending: dict[Any, str] = {}
    fits: dict[pathlib.Path, Any] = {}
    for path, cell in plan_dynamics_fits(todo, config, out, view.exists).items():
        name = f"{cell_name(*cell)} (dynamics fit)"
        fits[path] = submit(name, cell, True)
        pending[fits[path]] = name
    for cell in todo:
        name = cell_name(*cell)
        fit = fits.get(dynamics_path(out, cell[0], cell[2], config))
        after = [fit] if fit is not None and needs_dynamics(cell[1], config) else []
        pending[submit(name, cell, False, *after)] = name
    return pending, len(fits)


def _wait_for_cells(
    pending: dict[Any, str], cells: list[Cell], view: Workspace, variants: list[str], info: dict[str, Any]
) -> list[tuple[str, BaseException]]:
    """Wait for every task, merging the rows into ``scores.csv`` as they come and rewriting the reports now and then.

    :param pending: the tasks (object ref -> name); emptied
    :param cells: the grid, in the sequential run's order
    :param view: the workspace of the output
    :param variants: the variants of the reports
    :param info: the content of ``config.json``
    :return: the failed tasks' names and errors
    """
    import ray

    failures: list[tuple[str, BaseException]] = []
    last_merge = last_report = time.monotonic()
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1, timeout=MERGE_INTERVAL)
        for ref in done:
            name = pending.pop(ref)
            try:
                ray.get(ref)
            except Exception as error:  # the cell's exception, or a worker lost more often than retried
                failures.append((name, error))
                print(f"[score] {name} failed:\n{_error_text(error)}", file=sys.stderr)
        now = time.monotonic()
        if now - last_merge >= MERGE_INTERVAL or done:
            merge_rows(view, cells)
            last_merge = now
        if now - last_report >= REPORT_INTERVAL and pending:
            publish_reports(view, variants, info)
            last_report = now
    return failures


def run_grid(
    args: argparse.Namespace,
    cells: list[Cell],
    config: Config,
    info: dict[str, Any],
    view: Workspace,
    device: str,
) -> int:
    """Run the cells as Ray tasks and write the sequential run's outputs; returns the exit code.

    Uses the Ray instance this process is already connected to; else starts one on this machine (``--ray``
    without an address) or joins the cluster at ``args.ray`` (``auto`` or ``host:port``), and stops it at the end.

    :param args: the ``sb3-pola score`` arguments (``ray``, ``cpus_per_cell``, ``gpus_per_cell``, ``max_retries``,
        ``threads``, ``data_dir``, ``variants``, ``verbose``)
    :param cells: the grid, in the sequential run's order
    :param config: its configuration
    :param info: the content of ``config.json``
    :param view: the workspace of the output (a folder or an fsspec URL every worker sees)
    :param device: torch device of the cells
    :return: 0, 1 if a cell failed, 2 without Ray
    """
    try:
        import ray
    except ImportError:
        print(MISSING_RAY, file=sys.stderr)
        return 2
    out = view.folder
    todo = [cell for cell in cells if not view.exists(marker_path(out, cell))]
    if args.verbose:
        for cell in cells:
            if cell not in todo:
                print(f"[score] {cell_name(*cell)}: done, skipped")
    view.pull("scores.csv")
    view.pull_tree("rows")
    adopt_rows(out, todo)
    view.push_tree("rows", "*.csv")
    environ = {"MINARI_DATASETS_PATH": os.environ["MINARI_DATASETS_PATH"]} if args.data_dir else {}
    threads = args.threads or max(1, int(args.cpus_per_cell))
    started = not ray.is_initialized()
    if started and args.ray == "local":
        ray.init(include_dashboard=False, log_to_driver=args.verbose > 0)
    elif started:
        ray.init(address=args.ray, log_to_driver=args.verbose > 0)
    try:
        remote = ray.remote(cell_task)
        resources = dict(num_cpus=args.cpus_per_cell, num_gpus=args.gpus_per_cell, max_retries=args.max_retries)
        common = (asdict(config), view.location, device, threads, args.verbose)

        def submit(name: str, cell: Cell, stop_after_dynamics: bool, *after: Any) -> Any:
            return remote.options(name=name, **resources).remote(cell, *common, stop_after_dynamics, environ, *after)

        pending, n_fits = _submit_cells(submit, todo, config, view)
        cpus = ray.cluster_resources().get("CPU", 0)
        print(f"[score] {len(todo)} cells on Ray ({cpus:.0f} CPUs), {n_fits} dynamics fits")
        failures = _wait_for_cells(pending, cells, view, args.variants, info)
    finally:
        if started:
            ray.shutdown()
    merge_rows(view, cells)
    publish_reports(view, args.variants, info)
    if failures:
        print(f"[score] {len(failures)} task(s) failed: " + ", ".join(name for name, _ in failures), file=sys.stderr)
        print("[score] the same command resumes them (finished cells are skipped)", file=sys.stderr)
        return 1
    return 0
