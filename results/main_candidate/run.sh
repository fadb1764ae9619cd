#!/usr/bin/env bash
# #12: the main job (shipped InvertedPendulum data, light config) with the candidate defaults: the weakened Q term
# (q_scale_floor="auto", lookahead_normalization="weights"), critic_diversity = 1, detached look-ahead states.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
for seed in "$@"; do
  .venv/bin/python -m sb3_pola.cli run --seed "$seed" --extra '{"q_scale_floor": "auto", "lookahead_normalization": "weights", "critic_diversity": 1.0, "backprop_through_model": false}' \
    --out "results/main_candidate/seed$seed" > "results/main_candidate/seed$seed.log" 2>&1
done
