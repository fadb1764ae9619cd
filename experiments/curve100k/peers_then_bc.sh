#!/usr/bin/env bash
# d3rlpy TD3+BC at the same budget (seed 0), then the BC curve. Re-running resumes / skips.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli peers --data-dir "${MINARI_DATASETS_PATH:?set it to the folder of Minari datasets}" --datasets halfcheetah/medium-replay-v0 --algos td3bc \
  --seeds 0 --steps 100000 --eval-freq 5000 --eval-episodes 10 --out "${OUT:-outputs/peers100k}" --threads 1
bash experiments/curve100k/run.sh BC
