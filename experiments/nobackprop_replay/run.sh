#!/usr/bin/env bash
# #12, does the actor steer the model? The experiments/score10k T=3 cells on halfcheetah/medium-replay with the
# look-ahead states detached from the actor (backprop_through_model=False), 3 seeds. Same weakened
# Q term as score10k. Re-running resumes.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${MINARI_DATASETS_PATH:?set it to the folder of Minari datasets}" --device cpu --threads 1 \
  --extra '{"q_scale_floor": "auto", "lookahead_normalization": "weights", "backprop_through_model": false}' \
  --variants T3 --datasets halfcheetah/medium-replay-v0 --seeds 0 1 2 --out "${OUT:-outputs/nobackprop_replay}"
