#!/usr/bin/env bash
# #14, a first hint on the sparse-reward claim: the shipped U-maze data (50k steps of the noisy maze
# planner), CPU preset with the package defaults (the paper's form of the Q term), BC / T=0 / T=3, seed 0.
# DATA: folder holding pointmaze/umaze-v0 (the package's sb3_pola/data/datasets once merged).
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${DATA:-sb3_pola/data/datasets}" --device cpu --threads 1 \
  --variants BC T0 T3 --datasets pointmaze/umaze-v0 --seeds 0 --out "${OUT:-outputs/maze_hint}"
