#!/usr/bin/env bash
# #12: the main job (shipped InvertedPendulum data, light config, paper form of the Q term) with EDAC's
# ensemble-similarity term on the critics (critic_diversity = 1); one output folder per seed.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
for seed in "$@"; do
  .venv/bin/python -m sb3_pola.cli run --seed "$seed" --extra '{"critic_diversity": 1.0}' \
    --out "results/main_edac/seed$seed" > "results/main_edac/seed$seed.log" 2>&1
done
