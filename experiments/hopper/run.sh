#!/usr/bin/env bash
# #12, an environment with terminations: BC, T=0 and T=3 on our Hopper-v5 medium dataset (experiments/hopper/collect.sh),
# CPU preset, 10,000 steps, 3 seeds. bash experiments/hopper/run.sh "VARIANTS" "SEEDS" OUT [EXTRA_JSON]. Re-running resumes.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
extra=${4:-'{}'}
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${DATA:-${MINARI_DATASETS_PATH:?set DATA or MINARI_DATASETS_PATH to the folder of Minari datasets}}" --device cpu --threads 1 \
  --extra "$extra" --variants ${1:-BC T0 T3} --datasets hopper/medium-v0 --seeds ${2:-0 1 2} --out "${3:-outputs/hopper/score}"
