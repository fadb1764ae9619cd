#!/usr/bin/env bash
# #14, the medium maze: pointmaze/medium-v0 (100,000 steps of the noisy maze planner, recorded with
#   sb3-pola collect --env PointMaze_Medium-v3 --kind planner --steps 100000 --seed 0 --out "$DATA"
# ), CPU preset with the package defaults (the paper's form of the Q term), BC / T=0 / T=1 / T=3, seeds 0-2,
# 10,000 steps, 10 evaluation episodes. DATA: the datasets root holding pointmaze/medium-v0. Re-running resumes.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${DATA:-${MINARI_DATASETS_PATH:?set DATA or MINARI_DATASETS_PATH to the folder of Minari datasets}}" --device cpu --threads 1 \
  --variants ${VARIANTS:-BC T0 T1 T3} --datasets pointmaze/medium-v0 --seeds ${SEEDS:-0 1 2} --out "${OUT:-outputs/maze_medium}"
