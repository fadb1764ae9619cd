#!/usr/bin/env bash
# #23: the U-maze's imitation floor over 40 seeds (docs/results.md, twenty-seventh pass). BC with the package's actor
# (the CPU preset's BC variant: the defaults at eta = 0) against d3rlpy's BC on the shipped U-maze, 10,000 steps, the
# score's 10 evaluation episodes, seeds 0-39: at a standard deviation of about 10 points a seed, three seeds cannot tell
# a gap of several points (nineteenth pass). One core; PART splits the work over two:
#   PART=bc SEEDS="$(seq -s ' ' 0 29)" bash experiments/umaze_floor40/run.sh
#   PART=peers SEEDS="$(seq -s ' ' 0 39)" bash experiments/umaze_floor40/run.sh
#   PART=bc SEEDS="$(seq -s ' ' 30 39)" OUT_BC=outputs/umaze_floor40/bc_b bash experiments/umaze_floor40/run.sh
#   PART=pieces SEEDS="$(seq -s ' ' 0 19)" bash experiments/umaze_floor40/run.sh   # where the gap comes from
# PART=pieces trains each imitator of PIECES in bc_screen.py's one loop (first 90% of the data, batch 128, 10,000 steps)
# and plays it on the score's resets, one JSON row each in $OUT/pieces.jsonl. Tables: python
# experiments/umaze_floor40/table.py and pieces.py (read the rows kept here).
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY="${PYTHON:-python}"
OUT="${OUT:-outputs/umaze_floor40}"
SEEDS="${SEEDS:-$(seq -s ' ' 0 39)}"
U=sb3_pola/data/datasets
PART="${PART:-all}"
case "$PART" in bc | peers | all | pieces) ;; *) echo "PART must be bc, peers, all or pieces" >&2; exit 2 ;; esac
if [ "$PART" = pieces ]; then
  mkdir -p "$OUT"
  for s in $SEEDS; do
    # shellcheck disable=SC2086
    "$PY" experiments/policy_quality/bc_screen.py --dataset pointmaze/umaze-v0 --seed "$s" --episodes 10 \
      --variants ${PIECES:-mse-d3rlpy x0-256-lr1e-3-relu-raw-noprod mse-lr1e-3 x0-lr1e-3 x0-lr1e-3-ema x0-lr1e-3-relu \
      x0-256-lr1e-3 x0-lr1e-3-raw x0-lr1e-3-noprod x0-d3rlpy-but-256 x0-d3rlpy-but-relu x0-d3rlpy-but-raw \
      x0-d3rlpy-but-noprod x0-lr1e-3-relu-noprod x0-lr1e-3-relu-noprod-ema} >>"$OUT/pieces.jsonl"
  done
  exit 0
fi
if [ "$PART" = bc ] || [ "$PART" = all ]; then
  # shellcheck disable=SC2086
  "$PY" -m sb3_pola.cli score --preset cpu --device cpu --threads 1 --variants BC --data-dir "$U" \
    --datasets pointmaze/umaze-v0 --seeds $SEEDS --out "${OUT_BC:-$OUT/bc}"
fi
if [ "$PART" = peers ] || [ "$PART" = all ]; then
  # shellcheck disable=SC2086
  "$PY" -m sb3_pola.cli peers --data-dir "$U" --datasets pointmaze/umaze-v0 --algos bc --seeds $SEEDS --steps 10000 \
    --eval-freq 2000 --eval-episodes 10 --threads 1 --out "$OUT/peers"
fi
