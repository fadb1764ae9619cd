#!/usr/bin/env bash
# #12: the package defaults of 2026-12-02 (T = 3, weakened Q term, critic_diversity = 1, detached look-ahead states)
# over 100,000 steps on medium-replay, one sample of the chain at evaluation, as experiments/curve100k (T = 0, BC) and
# experiments/peers100k (TD3+BC). bash experiments/curve100k_defaults/run.sh [SEED]. Re-running resumes from ckpt/.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${MINARI_DATASETS_PATH:?set it to the folder of Minari datasets}" --device cpu --threads 1 \
  --eval-rule stochastic --steps 100000 --eval-freq 5000 --eval-episodes 10 --variants T3 \
  --datasets halfcheetah/medium-replay-v0 --seeds "${1:-0}" --out "${OUT:-outputs/curve100k_defaults}"
