#!/usr/bin/env bash
# #23: the paper's 10 critics (the package default) against the CPU preset's 5 (docs/results.md, twenty-sixth pass).
# POLA at the CPU preset (T = 3, seeds 0-2, the mazes 0-4, 10,000 steps) with --n-critics 10, and with the preset's 5 where this
# machine has no run of them yet: the shipped U-maze, the medium maze, halfcheetah/medium and medium-replay, and
# hopper/medium of collect.sh files and hopper/medium-replay of the SEED=0 one (ROOT/seed<S>, files.sh's layout; the
# 5-critic rows are files.sh's). The U-maze's BC re-evaluated under the other evaluation rules. One core.
#   HC=<folder with halfcheetah/> MAZE=<folder with pointmaze/medium-v0> ROOT=<folder> bash experiments/critics10/run.sh
# The medium maze, if MAZE has none: sb3-pola collect --env PointMaze_Medium-v3 --kind planner --steps 100000 --seed 0
# --out "$MAZE". Timing: python experiments/critics10/timing.py (and --eager). Table: python experiments/critics10/table.py
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY="${PYTHON:-python}"
OUT="${OUT:-outputs/critics10}"
score() { "$PY" -m sb3_pola.cli score --preset cpu --device cpu --threads 1 --variants T3 "$@"; }
for n in 10 5; do  # the mazes' seeds spread more: 5 seeds there
  score --data-dir sb3_pola/data/datasets --datasets pointmaze/umaze-v0 --seeds 0 1 2 3 4 --n-critics $n --out "$OUT/n${n}_umaze"
  score --data-dir "${MAZE:?set MAZE}" --datasets pointmaze/medium-v0 --seeds 0 1 2 3 4 --n-critics $n --out "$OUT/n${n}_mmaze"
  for d in medium medium-replay; do
    score --data-dir "${HC:?set HC}" --datasets "halfcheetah/$d-v0" --seeds 0 1 2 --n-critics $n --out "$OUT/n${n}_halfcheetah_$d"
  done
done
# BC with the package's actor and d3rlpy BC on the medium maze made here
"$PY" -m sb3_pola.cli score --preset cpu --device cpu --threads 1 --variants BC --seeds 0 1 2 --data-dir "$MAZE" \
  --datasets pointmaze/medium-v0 --out "$OUT/bc_mmaze"
"$PY" -m sb3_pola.cli peers --data-dir "$MAZE" --datasets pointmaze/medium-v0 --algos bc --seeds 0 1 2 --steps 10000 \
  --eval-freq 2000 --eval-episodes 10 --threads 1 --out "$OUT/peers_mmaze"
for S in ${FILES:-0 1 2 3}; do
  score --data-dir "${ROOT:?set ROOT}/seed$S" --datasets hopper/medium-v0 --seeds 0 1 2 --n-critics 10 --out "$OUT/n10_hopper_file$S"
done
# the U-maze's imitation floor under the other evaluation rules: BC with the package's actor, its final models again
"$PY" -m sb3_pola.cli score --preset cpu --device cpu --threads 1 --variants BC --seeds 0 1 2 \
  --data-dir sb3_pola/data/datasets --datasets pointmaze/umaze-v0 --out "$OUT/bc_umaze"
"$PY" -m sb3_pola.cli score --preset cpu --device cpu --threads 1 --variants BC --seeds 0 1 2 \
  --data-dir sb3_pola/data/datasets --datasets pointmaze/umaze-v0 --out "$OUT/bc_umaze" --reevaluate online stochastic online-stochastic
score --data-dir "$ROOT/seed0" --datasets hopper/medium-replay-v0 --seeds 0 1 2 --n-critics 10 --out "$OUT/n10_hopper_replay_file0"
