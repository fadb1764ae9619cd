"""What is in a hopper collection: the spread of its episodes' scores, and how many of its steps come from episodes
well above its mean (the behaviour a Q term can pick out and plain imitation averages away).

    python experiments/hopper/file_stats.py --data-dir <DATA> [<DATA2> ...] [--above 60]

Each folder is one run of ``experiments/hopper/collect.sh`` (a Minari root holding ``hopper/medium-v0`` and
``hopper/medium-replay-v0``). Prints one markdown row per folder and dataset.
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np

from sb3_pola.common.datasets import load_offline_dataset
from sb3_pola.common.metrics import normalized_scores

DATASETS = ("hopper/medium-v0", "hopper/medium-replay-v0")


def file_row(data_dir: pathlib.Path, dataset_id: str, above: float) -> list[str]:
    data = load_offline_dataset(data_dir / dataset_id, use_cache=False)
    scores = normalized_scores(data.episode_returns, data.ref_min_score, data.ref_max_score)
    lengths = np.diff(np.concatenate([[-1], np.flatnonzero(data.episode_ends())]))
    if len(lengths) != len(scores):
        raise ValueError(f"{data_dir / dataset_id}: {len(lengths)} episode ends against {len(scores)} episode returns")
    weights = lengths / lengths.sum()  # a step's share: long episodes weigh more, as they do in a batch
    q50, q90 = np.percentile(scores, [50, 90])
    return [
        data_dir.name,
        dataset_id,
        str(len(scores)),
        f"{scores.mean():.1f} ± {scores.std():.1f}",
        f"{(weights * scores).sum():.1f}",
        f"{q50:.1f} / {q90:.1f} / {scores.max():.1f}",
        f"{weights[scores > above].sum():.3f}",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-dir", nargs="+", type=pathlib.Path, required=True, help="collect.sh output folders")
    parser.add_argument("--datasets", nargs="+", default=list(DATASETS))
    parser.add_argument("--above", type=float, default=60.0, help="score threshold for the last column")
    args = parser.parse_args()
    header = [
        "file",
        "dataset",
        "episodes",
        "episode score, mean ± std",
        "step-weighted mean score",
        "median / 90th pct / max",
        f"share of steps in episodes above {args.above:g}",
    ]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for data_dir in args.data_dir:
        for dataset_id in args.datasets:
            print("| " + " | ".join(file_row(data_dir, dataset_id, args.above)) + " |")


if __name__ == "__main__":
    main()
