"""Write a Minari dataset holding a dataset's best episodes by return (the "%BC" data of the Decision Transformer
paper's filtered behaviour cloning), to ask whether a file holds better behaviour than its mean that imitation alone
can find.

    python experiments/policy_quality/top_episodes.py --dataset hopper/medium-v0 --fraction 0.1 \\
        --out-id hopper/medium-top10-v0

The new dataset is written under ``$MINARI_DATASETS_PATH`` (or ``--root``) with the source's env, evaluation env and
reference scores, so its scores are normalised as the source's are; its metadata names the source and the fraction.
Ties at the cut keep the earlier episodes. ``--keep-all`` writes every episode, the best first (their transitions are
the first ``first_rows``), for ``screen.py --imitation-rows``: the actor trains on the best episodes, the critics on all.
Prints one JSON line: episodes and steps written, the best episodes' mean normalised return against the source's.
"""

from __future__ import annotations

import argparse
import json

import minari
import numpy as np
from gymnasium.envs.registration import EnvSpec
from minari.data_collector import EpisodeBuffer

from sb3_pola.collect.writer import datasets_root, write_dataset
from sb3_pola.common.dataset_paths import resolve_dataset_path
from sb3_pola.common.datasets import best_episodes
from sb3_pola.common.metrics import normalized_score


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", required=True, help="the source Minari id")
    parser.add_argument("--fraction", type=float, required=True, help="share of the episodes kept, best first")
    parser.add_argument("--out-id", required=True, help="the new dataset's id")
    parser.add_argument("--root", default=None, help="datasets root (default $MINARI_DATASETS_PATH)")
    parser.add_argument(
        "--keep-all",
        action="store_true",
        help="write every episode, the best fraction first (screen.py --imitation-rows: the actor's rows come first)",
    )
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args()
    if not 0 < args.fraction <= 1:
        parser.error("--fraction must be in (0, 1]")

    source = minari.MinariDataset(resolve_dataset_path(args.dataset))  # Minari's folder or the package's
    episodes = list(source.iterate_episodes())
    returns = np.array([float(np.sum(episode.rewards)) for episode in episodes])
    kept = best_episodes(returns, args.fraction)
    n_kept = len(kept)
    first_rows = int(sum(len(episodes[i].rewards) for i in kept))
    if args.keep_all:
        kept = np.concatenate([kept, np.setdiff1d(np.arange(len(episodes)), kept)])
    buffers = [
        EpisodeBuffer(
            id=new_id,
            observations=episodes[i].observations,
            actions=episodes[i].actions,
            rewards=episodes[i].rewards,
            terminations=episodes[i].terminations,
            truncations=episodes[i].truncations,
        )
        for new_id, i in enumerate(kept)
    ]
    metadata = source.storage.metadata
    ref_min, ref_max = metadata["ref_min_score"], metadata["ref_max_score"]
    path = write_dataset(
        datasets_root(args.root),
        args.out_id,
        buffers,
        source.spec.env_spec,
        ref_min=ref_min,
        ref_max=ref_max,
        ref_episodes=metadata.get("num_episodes_average_score", 100),
        algorithm_name=f"{args.dataset}'s episodes, the best {args.fraction:g} by return"
        + (" first" if args.keep_all else " only"),
        description=f"{args.dataset}'s {n_kept} best episodes of {len(episodes)} by return (filtered BC's data)"
        + (f", then the others: the first {first_rows} transitions are the best episodes'." if args.keep_all else "."),
        overwrite=args.overwrite,
        eval_env=EnvSpec.from_json(metadata["eval_env_spec"]) if metadata.get("eval_env_spec") else None,
        extra_metadata={"source_dataset": args.dataset, "top_fraction": args.fraction, "top_rows": first_rows},
        code_permalink="experiments/policy_quality/top_episodes.py",
    )

    def normalised(values: np.ndarray) -> float | None:
        score = normalized_score(values, ref_min, ref_max)
        return None if score is None else round(score, 1)

    print(
        json.dumps(
            {
                "dataset": args.out_id,
                "path": str(path),
                "episodes": len(kept),
                "best_episodes": int(n_kept),
                "first_rows": first_rows,
                "of": len(episodes),
                "steps": int(sum(len(buffer.rewards) for buffer in buffers)),
                "mean_score": normalised(returns[kept[:n_kept]]),
                "source_mean_score": normalised(returns),
            }
        )
    )


if __name__ == "__main__":
    main()
