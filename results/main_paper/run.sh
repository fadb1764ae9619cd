#!/usr/bin/env bash
# #12: the main job (shipped InvertedPendulum data, light config, the paper's form: the package defaults),
# one output folder per seed: bash results/main_paper/run.sh 1 2
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
for seed in "$@"; do
  .venv/bin/python -m sb3_pola.cli run --seed "$seed" --out "results/main_paper/seed$seed" > "results/main_paper/seed$seed.log" 2>&1
done
