"""The score grid's rows: the CSV schema of ``scores.csv`` and ``reeval.csv``, cell names, finished-cell markers, and
the merge of the cells' own rows files (``rows/<cell>.csv``) into ``scores.csv`` in the sequential run's order.
"""

from __future__ import annotations

import csv
import math
import pathlib
import re
from typing import TYPE_CHECKING, Any

from sb3_pola.common.metrics import EVALUATION_FIELDS

if TYPE_CHECKING:
    from sb3_pola.grid.storage import Workspace


CSV_FIELDS = EVALUATION_FIELDS  # scores.csv
REEVAL_FIELDS = ["dataset", "variant", "seed", "rule", "step", "score", "score_std", "mean_return", "eval_episodes", "success"]
Cell = tuple[str, str, int]


def slug(text: str) -> str:
    """File-name-safe version of a dataset id or variant."""
    return re.sub(r"[^A-Za-z0-9.-]+", "_", text).strip("_")


def cell_name(dataset: str, variant: str, seed: int) -> str:
    return f"{slug(dataset)}__{variant}__seed{seed}"


def rows_rel(dataset: str, variant: str, seed: int) -> str:
    """A cell's own rows file (``rows/<cell>.csv``, relative to the output), merged into ``scores.csv`` by the driver."""
    return f"rows/{cell_name(dataset, variant, seed)}.csv"


def read_rows(csv_path: pathlib.Path) -> list[dict[str, Any]]:
    """Rows of ``scores.csv`` with numbers parsed (empty list if there is no file)."""
    if not csv_path.exists():
        return []
    rows = []
    with csv_path.open(newline="") as f:
        for row in csv.DictReader(f):
            parsed: dict[str, Any] = dict(row)
            parsed["seed"], parsed["step"], parsed["eval_episodes"] = (
                int(row["seed"]),
                int(row["step"]),
                int(row["eval_episodes"]),
            )
            for key in ("score", "score_std", "mean_return", "wall_s", "success"):
                value = row.get(key)  # success: absent in files written before it was a column
                parsed[key] = float(value) if value not in (None, "", "None") else math.nan
            rows.append(parsed)
    return rows


def write_rows(csv_path: pathlib.Path, rows: list[dict[str, Any]]) -> None:
    """Rewrite ``scores.csv`` atomically."""
    tmp = csv_path.with_suffix(".tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        writer.writeheader()
        writer.writerows({k: row.get(k, math.nan) for k in CSV_FIELDS} for row in rows)
    tmp.replace(csv_path)


def csv_header(csv_path: pathlib.Path) -> list[str]:
    with csv_path.open(newline="") as f:
        return next(csv.reader(f), [])


def append_row(csv_path: pathlib.Path, row: dict[str, Any]) -> None:
    """Append one row to ``scores.csv`` (first rewriting a file from before the ``success`` column with it)."""
    if csv_path.exists() and csv_header(csv_path) != CSV_FIELDS:
        write_rows(csv_path, read_rows(csv_path))
    new = not csv_path.exists()
    with csv_path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        if new:
            writer.writeheader()
        writer.writerow({k: row.get(k, math.nan) for k in CSV_FIELDS})
        f.flush()


def rows_path(out: pathlib.Path, cell: Cell) -> pathlib.Path:
    """The file of a cell's evaluation rows (``rows/<cell>.csv``), merged into ``scores.csv`` by the driver."""
    return out / rows_rel(*cell)


def marker_path(out: pathlib.Path, cell: Cell) -> pathlib.Path:
    """The marker of a finished cell (``cells/<cell>.json``)."""
    return out / "cells" / f"{cell_name(*cell)}.json"


def _key(row: dict[str, Any]) -> Cell:
    return row["dataset"], row["variant"], row["seed"]


def adopt_rows(out: pathlib.Path, cells: list[Cell]) -> None:
    """Give each cell its own rows file, from ``scores.csv`` (a sequential run interrupted, resumed with ``--ray``).

    :param out: output folder
    :param cells: the cells about to run
    """
    rows = read_rows(out / "scores.csv")
    for cell in cells:
        path = rows_path(out, cell)
        mine = [r for r in rows if _key(r) == cell]
        if mine and not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            write_rows(path, mine)


def collect_rows(out: pathlib.Path, cells: list[Cell]) -> list[dict[str, Any]]:
    """Rewrite ``scores.csv`` from the cells' rows files: the grid's cells in its order, then any other cell.

    A cell with a rows file takes its rows from there; rows of other cells already in ``scores.csv`` are kept.

    :param out: output folder
    :param cells: the grid's cells, in the sequential run's order
    :return: the rows written
    """
    files = {cell: rows_path(out, cell) for cell in cells}
    listed = set(files.values())
    folder = out / "rows"
    others = sorted(p for p in folder.glob("*.csv") if p not in listed) if folder.is_dir() else []
    by_cell: dict[Cell, list[dict[str, Any]]] = {}
    for path in [*files.values(), *others]:
        try:
            rows = read_rows(path)
        except (ValueError, KeyError, TypeError):  # a row being written right now (the next merge reads it whole)
            continue
        for row in rows:
            by_cell.setdefault(_key(row), []).append(row)
    merged = [r for r in read_rows(out / "scores.csv") if _key(r) not in by_cell]
    for rows in by_cell.values():
        merged += rows
    if merged:
        write_rows(out / "scores.csv", merged)
    return merged


def merge_rows(view: Workspace, cells: list[Cell]) -> list[dict[str, Any]]:
    """:func:`collect_rows` in a workspace: ``scores.csv`` and the rows files pulled, the merged ``scores.csv`` pushed.

    :param view: the workspace of the output
    :param cells: the grid's cells, in the sequential run's order
    :return: the rows written
    """
    view.pull("scores.csv")
    view.pull_tree("rows")
    merged = collect_rows(view.folder, cells)
    view.push("scores.csv")
    return merged
