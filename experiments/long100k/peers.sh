#!/usr/bin/env bash
# #23's long runs, baselines half: d3rlpy BC, TD3+BC and IQL for 100,000 steps on hopper/medium and
# halfcheetah/medium-replay, seeds 0-2 (seed-major, so every method has seed 0 first), evaluation every 5,000 steps
# on 10 episodes. Independent of POLA's defaults. One core; re-running resumes (a cut run continues from its
# checkpoint in peers_ckpt/). bash experiments/long100k/peers.sh ["SEEDS"]
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli peers --data-dir "${DATA:-${MINARI_DATASETS_PATH:?set DATA or MINARI_DATASETS_PATH to the folder of Minari datasets}}" \
  --datasets hopper/medium-v0 halfcheetah/medium-replay-v0 --algos bc td3bc iql --seeds ${1:-0 1 2} \
  --steps 100000 --eval-freq 5000 --eval-episodes 10 --threads 1 --out "${OUT:-outputs/long100k}"
