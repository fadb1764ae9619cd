#!/usr/bin/env bash
# #12 / #14: the shipped U-maze with the look-ahead states detached from the actor (backprop_through_model=False),
# otherwise the package defaults (the paper's form), CPU preset, 10,000 steps, 10 episodes, seeds 0-2.
# Compare with experiments/maze_hint (same protocol, states through the model). Re-running resumes.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir sb3_pola/data/datasets --device cpu --threads 1 \
  --extra '{"backprop_through_model": false}' --variants ${VARIANTS:-T3} --datasets pointmaze/umaze-v0 \
  --seeds ${SEEDS:-0 1 2} --out "${OUT:-outputs/maze_detached}"
