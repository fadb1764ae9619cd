#!/usr/bin/env bash
# The long run of #12: halfcheetah/medium-replay, 100,000 steps, POLA T=3 (defaults) and BC, seed 0,
# evaluation every 5,000 steps on 10 episodes; one process per variant. Re-running resumes.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${MINARI_DATASETS_PATH:?set it to the folder of Minari datasets}" --device cpu --threads 1 \
  --steps 100000 --eval-freq 5000 --eval-episodes 10 --variants "$1" --datasets halfcheetah/medium-replay-v0 \
  --seeds 0 --out "${OUT:-outputs/score100k}"
