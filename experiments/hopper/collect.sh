#!/usr/bin/env bash
# #12: a dataset of our own for an environment with terminations (Hopper-v5): SAC to a medium level
# (first checkpoint with an eval return in [1000, 2000]), kinds medium and medium-replay, 100,000 steps each.
# Reference scores: D4RL's for Hopper (random -20.272305, expert 3234.3), since a CPU cannot train an expert here.
# SEED (default 0) seeds SAC and the collection: another seed makes another file (as another CPU does).
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli collect --env Hopper-v5 --kind medium medium-replay --steps 100000 --seed "${SEED:-0}" \
  --train-steps 150000 --eval-freq 5000 --eval-episodes 5 --medium-return 1000 --medium-max-return 2000 \
  --expert-return 2000 --ref-min-score -20.272305 --ref-max-score 3234.3 --ref-episodes 10 \
  --save-policies "outputs/hopper/policies${SEED:+_s$SEED}" --no-progress --out "${DATA:-${MINARI_DATASETS_PATH:?set DATA or MINARI_DATASETS_PATH to the folder of Minari datasets}}"
