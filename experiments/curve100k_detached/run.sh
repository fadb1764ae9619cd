#!/usr/bin/env bash
# As experiments/curve100k, POLA T=3 with detached look-ahead states (backprop_through_model=False), the variant
# that doubled T=3 at 10k steps. bash experiments/curve100k_detached/run.sh [SEED]. Re-running resumes.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${MINARI_DATASETS_PATH:?set it to the folder of Minari datasets}" --device cpu --threads 1 \
  --extra '{"q_scale_floor": "auto", "lookahead_normalization": "weights", "backprop_through_model": false}' \
  --eval-rule stochastic --steps 100000 --eval-freq 5000 --eval-episodes 10 --variants T3 \
  --datasets halfcheetah/medium-replay-v0 --seeds "${1:-0}" --out "${OUT:-outputs/curve100k_detached}"
