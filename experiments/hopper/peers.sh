#!/usr/bin/env bash
# #12: d3rlpy's baselines on our Hopper-v5 medium dataset, next to experiments/hopper/floor_edac_detached (the new
# defaults) and experiments/hopper/score (BC, the paper's form). bash experiments/hopper/peers.sh "ALGOS" "SEEDS". Resumes.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli peers --data-dir "${DATA:-${MINARI_DATASETS_PATH:?set DATA or MINARI_DATASETS_PATH to the folder of Minari datasets}}" --datasets hopper/medium-v0 \
  --algos ${1:-bc td3bc iql} --seeds ${2:-0 1 2} --steps 10000 --eval-freq 2000 --eval-episodes 10 --threads 1 \
  --out "${OUT:-outputs/hopper/floor_edac_detached}"
