#!/usr/bin/env bash
# #12: the main job (shipped InvertedPendulum data, light config, paper form of the Q term) with the
# look-ahead states detached from the actor; one output folder per seed.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
for seed in "$@"; do
  .venv/bin/python -m sb3_pola.cli run --seed "$seed" --extra '{"backprop_through_model": false}' \
    --out "results/main_nobackprop/seed$seed" > "results/main_nobackprop/seed$seed.log" 2>&1
done
