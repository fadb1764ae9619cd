"""``sb3-pola datasets``: list the Minari datasets found locally."""

from __future__ import annotations

from sb3_pola.common.arguments import ArgumentParser
from sb3_pola.common.datasets import _env_id, _scan, _search_roots, minari_datasets_dir, package_datasets_dir, read_metadata


def main(argv: list[str] | None = None) -> int:
    """``sb3-pola datasets``: list local datasets (id, steps, episodes, env, reference scores)."""
    parser = ArgumentParser(prog="sb3-pola datasets", description="List the Minari datasets found locally.")
    parser.parse_args(argv)
    rows = []
    seen = set()
    for root in _search_roots():
        for dataset_id, data_dir in _scan(root).items():
            if dataset_id in seen:
                continue  # the Minari folder shadows the shipped copy, as in load_offline_dataset
            seen.add(dataset_id)
            try:
                meta = read_metadata(data_dir)
            except (OSError, ValueError) as error:
                rows.append((dataset_id, "?", "?", f"unreadable: {error}", "", "", str(root)))
                continue
            rows.append(
                (
                    dataset_id,
                    str(meta.get("total_steps", "?")),
                    str(meta.get("total_episodes", "?")),
                    _env_id(meta) or "?",
                    str(meta.get("ref_min_score", "-")),
                    str(meta.get("ref_max_score", "-")),
                    str(root),
                )
            )
    print(f"datasets in {minari_datasets_dir()} (MINARI_DATASETS_PATH) and {package_datasets_dir()} (shipped)")
    if not rows:
        print("none found: make one with `sb3-pola collect` or `minari download <id>`")
        return 0
    header = ("id", "steps", "episodes", "env", "ref_min", "ref_max", "root")
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    for row in [header, *rows]:
        print("  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=False)).rstrip())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
