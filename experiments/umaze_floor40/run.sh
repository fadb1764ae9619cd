#!/usr/bin/env bash
# #23: the U-maze's imitation floor over 40 seeds (docs/results.md, twenty-seventh pass). BC with the package's actor
# (the CPU preset's BC variant: the defaults at eta = 0) against d3rlpy's BC on the shipped U-maze, 10,000 steps, the
# score's 10 evaluation episodes, seeds 0-39: at a standard deviation of about 10 points a seed, three seeds cannot tell
# a gap of several points (nineteenth pass). One core; PART splits the work over two:
#   PART=bc SEEDS="$(seq -s ' ' 0 29)" bash experiments/umaze_floor40/run.sh
#   PART=peers SEEDS="$(seq -s ' ' 0 39)" bash experiments/umaze_floor40/run.sh
#   PART=bc SEEDS="$(seq -s ' ' 30 39)" OUT_BC=outputs/umaze_floor40/bc_b bash experiments/umaze_floor40/run.sh
# Table: python experiments/umaze_floor40/table.py (reads the CSVs kept here).
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY="${PYTHON:-python}"
OUT="${OUT:-outputs/umaze_floor40}"
SEEDS="${SEEDS:-$(seq -s ' ' 0 39)}"
U=sb3_pola/data/datasets
PART="${PART:-all}"
case "$PART" in bc | peers | all) ;; *) echo "PART must be bc, peers or all" >&2; exit 2 ;; esac
if [ "$PART" != peers ]; then
  # shellcheck disable=SC2086
  "$PY" -m sb3_pola.cli score --preset cpu --device cpu --threads 1 --variants BC --data-dir "$U" \
    --datasets pointmaze/umaze-v0 --seeds $SEEDS --out "${OUT_BC:-$OUT/bc}"
fi
if [ "$PART" != bc ]; then
  # shellcheck disable=SC2086
  "$PY" -m sb3_pola.cli peers --data-dir "$U" --datasets pointmaze/umaze-v0 --algos bc --seeds $SEEDS --steps 10000 \
    --eval-freq 2000 --eval-episodes 10 --threads 1 --out "$OUT/peers"
fi
