"""The sequential executors of the score grid: the cells one after another, in a folder or against an fsspec URL
(each cell then in a scratch folder of its own, as the Ray workers of :mod:`sb3_pola.grid.ray_runner` run them).
"""

from __future__ import annotations

import argparse
from typing import Any

from sb3_pola.grid.cell import run_cell, run_stored_cell
from sb3_pola.grid.report import publish_reports
from sb3_pola.grid.rows import Cell, cell_name, merge_rows
from sb3_pola.grid.storage import Workspace, open_workspace
from sb3_pola.grid.variants import Config


def run_sequential(
    args: argparse.Namespace,
    cells: list[Cell],
    config: Config,
    info: dict[str, Any],
    view: Workspace,
    device: str,
) -> int:
    """The cells one after another in the output folder, the reports rewritten after each.

    :param args: the ``sb3-pola score`` arguments (``variants``, ``verbose``)
    :param cells: the grid, in order
    :param config: its configuration
    :param info: the content of ``config.json``
    :param view: the workspace of the output (a local folder)
    :param device: torch device
    :return: the exit code
    """
    out = view.folder
    for dataset, variant, seed in cells:
        marker = out / "cells" / f"{cell_name(dataset, variant, seed)}.json"
        if marker.exists():
            if args.verbose:
                print(f"[score] {marker.stem}: done, skipped")
            continue
        run_cell(dataset, variant, seed, config, out, device, verbose=args.verbose)
        publish_reports(view, args.variants, info)
    publish_reports(view, args.variants, info)
    return 0


def run_stored_sequential(
    args: argparse.Namespace,
    cells: list[Cell],
    config: Config,
    info: dict[str, Any],
    view: Workspace,
    device: str,
) -> int:
    """The cells one after another into an fsspec URL, as the Ray workers run them (:func:`run_stored_cell`).

    Each cell works in a scratch folder of its own (deleted after it) and writes ``rows/<cell>.csv``; after every
    cell the rows are merged into ``scores.csv`` and the reports rewritten.

    :param args: the ``sb3-pola score`` arguments
    :param cells: the grid, in order
    :param config: its configuration
    :param info: the content of ``config.json``
    :param view: the driver's workspace of the output
    :param device: torch device
    :return: the exit code
    """
    for cell in cells:
        if view.exists(f"cells/{cell_name(*cell)}.json"):
            if args.verbose:
                print(f"[score] {cell_name(*cell)}: done, skipped")
            continue
        with open_workspace(view.location) as cell_view:
            run_stored_cell(cell_view, *cell, config, device, verbose=args.verbose)
        merge_rows(view, cells)
        publish_reports(view, args.variants, info)
    merge_rows(view, cells)
    publish_reports(view, args.variants, info)
    return 0
