#!/usr/bin/env bash
# #12, a critic ensemble that disagrees off the data: EDAC's ensemble-similarity term (critic_diversity) on the
# results/score10k cells (CPU preset, N = 5, the same weakened Q term), so rows compare with that grid.
# bash results/edac/run.sh VARIANT DATASET "SEEDS" [ETA_ES] [EXTRA_JSON_FIELDS]. Re-running resumes.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
variant=${1:-T0} dataset=${2:-halfcheetah/medium-v0} seeds=${3:-0} div=${4:-1.0} more=${5:-}
out=results/edac/div${div}${more:+_$(echo "$more" | tr -dc 'a-z0-9_')}
.venv/bin/python -m sb3_pola.cli score --preset cpu --data-dir ../shared/datasets --device cpu --threads 1 \
  --extra "{\"q_scale_floor\": \"auto\", \"lookahead_normalization\": \"weights\", \"critic_diversity\": ${div}${more:+, $more}}" \
  --variants $variant --datasets $dataset --seeds $seeds --out "$out"
