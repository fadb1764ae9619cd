"""``sb3-pola datasets``: list the Minari datasets found locally; ``--check`` reads each one whole and says which are
broken; ``--cache`` lists the cache's entries (dataset arrays, fitted dynamics models), ``--prune`` removes the unused
ones."""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from typing import Any

from sb3_pola.common.arguments import ArgumentParser
from sb3_pola.common.dataset_cache import cache_entries, remove_entry
from sb3_pola.common.dataset_paths import (
    DatasetError,
    metadata_env_id,
    minari_root_label,
    package_datasets_dir,
    read_metadata,
    scan_datasets,
    search_roots,
)
from sb3_pola.common.datasets import default_cache_dir, load_offline_dataset
from sb3_pola.common.dynamics_cache import dynamics_entries


def print_table(header: tuple[str, ...], rows: Sequence[tuple[str, ...]]) -> None:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    for row in [header, *rows]:
        print("  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=False)).rstrip())


def check_dataset(data_dir: Any) -> str:
    """``"ok"``, or why the dataset cannot be used: every episode is read (nothing is cached).

    :param data_dir: the dataset's ``data`` folder
    :return: the status
    """
    try:
        load_offline_dataset(data_dir, use_cache=False)
    except DatasetError as error:
        return f"BROKEN: {' '.join(str(error).split())}"
    return "ok"


def list_datasets(check: bool) -> int:
    rows: list[tuple[str, ...]] = []
    seen, broken = set(), 0
    for root in search_roots():
        for dataset_id, data_dir in scan_datasets(root).items():
            if dataset_id in seen:
                continue  # the Minari folder shadows the shipped copy, as in load_offline_dataset
            seen.add(dataset_id)
            try:
                meta = read_metadata(data_dir)
            except (OSError, ValueError) as error:
                rows.append((dataset_id, "?", "?", f"unreadable metadata: {error}", "", "", str(root)))
                broken += 1
                continue
            row: tuple[str, ...] = (
                dataset_id,
                str(meta.get("total_steps", "?")),
                str(meta.get("total_episodes", "?")),
                metadata_env_id(meta) or "?",
                str(meta.get("ref_min_score", "-")),
                str(meta.get("ref_max_score", "-")),
                str(root),
            )
            if check:
                status = check_dataset(data_dir)
                broken += status != "ok"
                row = (*row, status)
            rows.append(row)
    print(f"datasets in {minari_root_label()} and {package_datasets_dir()} (shipped)")
    if not rows:
        print("none found: make one with `sb3-pola collect` or `minari download <id>`")
        return 0
    header = ("id", "steps", "episodes", "env", "ref_min", "ref_max", "root", *(("check",) if check else ()))
    print_table(header, rows)
    if check:
        print(f"{broken} broken" if broken else "all readable")
    else:
        print("(metadata only: `--check` reads every episode)")
    return 1 if broken else 0


def list_cache(prune: bool, older_than: float | None) -> int:
    root = default_cache_dir()
    entries = cache_entries(root) + dynamics_entries()
    now = time.time()
    for entry in entries:
        idle_days = (now - entry["last_used"]) / 86400
        if not entry["stale"] and older_than is not None and idle_days > older_than:
            entry["stale"] = f"unused for {idle_days:.0f} days"
    label = " (SB3_POLA_CACHE_DIR)" if os.environ.get("SB3_POLA_CACHE_DIR") else ""
    print(f"cache in {root}{label}: dataset arrays, fitted dynamics models (dynamics/)")
    if not entries:
        print("empty")
        return 0
    rows = [
        (
            entry["kind"],
            str(entry["dataset_id"]),
            f"{entry['bytes'] / 1e6:.1f} MB",
            f"{(now - entry['last_used']) / 86400:.1f} days ago",
            entry["stale"] or "in use",
            entry["path"].name,
        )
        for entry in entries
    ]
    print_table(("kind", "dataset", "size", "last used", "status", "entry"), rows)
    stale = [entry for entry in entries if entry["stale"]]
    if prune:
        for entry in stale:
            remove_entry(entry["path"])
        print(f"pruned {len(stale)} entries, {sum(e['bytes'] for e in stale) / 1e6:.1f} MB")
    elif stale:
        print(f"{len(stale)} unused entries, {sum(e['bytes'] for e in stale) / 1e6:.1f} MB: `--cache --prune` removes them")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``sb3-pola datasets``: list local datasets (id, steps, episodes, env, reference scores), or the cache."""
    parser = ArgumentParser(prog="sb3-pola datasets", description=__doc__)
    parser.add_argument("--check", action="store_true", help="read every dataset whole; exit status 1 if one is broken")
    parser.add_argument("--cache", action="store_true", help="list the cache's entries instead of the datasets")
    parser.add_argument("--prune", action="store_true", help="with --cache: remove the entries of no more use")
    parser.add_argument(
        "--older-than", type=float, metavar="DAYS", help="with --cache: entries unused for longer count as of no use too"
    )
    args = parser.parse_args(argv)
    if (args.prune or args.older_than is not None) and not args.cache:
        parser.error("--prune and --older-than go with --cache")
    if args.cache:
        return list_cache(args.prune, args.older_than)
    return list_datasets(args.check)


if __name__ == "__main__":
    raise SystemExit(main())
