#!/usr/bin/env bash
# #12's long run: halfcheetah/medium-replay, 100,000 steps, seed 0, evaluation every 5,000 steps on 10 episodes
# with one sample of the reverse chain (--eval-rule stochastic), the weakened Q term of the 10k grid.
# One process per variant: bash experiments/curve100k/run.sh T0 (or BC). Re-running resumes.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${MINARI_DATASETS_PATH:?set it to the folder of Minari datasets}" --device cpu --threads 1 \
  --extra '{"q_scale_floor": "auto", "lookahead_normalization": "weights"}' --eval-rule stochastic \
  --steps 100000 --eval-freq 5000 --eval-episodes 10 --variants "$1" --datasets halfcheetah/medium-replay-v0 \
  --seeds "${2:-0}" --out "${OUT:-outputs/curve100k}"
