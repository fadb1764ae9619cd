#!/usr/bin/env bash
# #12, a critic ensemble that disagrees off the data: EDAC's ensemble-similarity term (critic_diversity = 1) on the
# experiments/score10k cells (CPU preset, N = 5, the same weakened Q term), so rows compare with that grid.
# bash experiments/edac/run.sh "VARIANTS" "DATASETS" "SEEDS" [NAME] [MORE_EXTRA_JSON_FIELDS]. Re-running resumes.
#   bash experiments/edac/run.sh "T0 T3" "halfcheetah/medium-v0 halfcheetah/medium-replay-v0" "0 1 2"      # div1.0
#   bash experiments/edac/run.sh T3 halfcheetah/medium-v0 "0 1 2" div1.0_sa '"critic_diversity_inputs": "states_and_actions"'
#   bash experiments/edac/run.sh T3 "halfcheetah/medium-v0 halfcheetah/medium-replay-v0" "0 1 2" div1.0_detached \
#     '"backprop_through_model": false'
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
variants=${1:-T0} datasets=${2:-halfcheetah/medium-v0} seeds=${3:-0} name=${4:-div1.0} more=${5:-}
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${MINARI_DATASETS_PATH:?set it to the folder of Minari datasets}" --device cpu --threads 1 \
  --extra "{\"q_scale_floor\": \"auto\", \"lookahead_normalization\": \"weights\", \"critic_diversity\": 1.0${more:+, $more}}" \
  --variants $variants --datasets $datasets --seeds $seeds --out "${OUT:-outputs/edac/$name}"
