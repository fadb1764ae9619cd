#!/usr/bin/env bash
# #23: hopper on several collections (docs/results.md, twenty-fourth pass). For each SEED, collect.sh makes a file in
# ROOT/seed<SEED> (skipped if there), then the README's 10,000-step grid runs on it: POLA's defaults (T3), T = 0, BC
# with the package's actor, eta 1; d3rlpy's BC, TD3+BC and IQL. One core; a second core can run another SEED.
#   SEEDS="2 3" ROOT=<folder> bash experiments/hopper/files.sh      (outputs in OUT, default outputs/hopper/files)
# Then: python experiments/hopper/file_stats.py --data-dir <ROOT>/seed2 <ROOT>/seed3
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY="${PYTHON:-python}"
ROOT="${ROOT:?set ROOT to the folder for the collections}"
OUT="${OUT:-outputs/hopper/files}"
for S in ${SEEDS:-0 1 2 3}; do
  DATA="$ROOT/seed$S"
  [ -d "$DATA/hopper/medium-v0" ] || SEED="$S" DATA="$DATA" PYTHON="$PY" bash experiments/hopper/collect.sh
  for d in hopper/medium-v0 hopper/medium-replay-v0; do
    cell="$OUT/seed${S}_${d//\//_}"
    "$PY" -m sb3_pola.cli score --preset cpu --data-dir "$DATA" --device cpu --threads 1 --variants T3 T0 BC \
      --datasets "$d" --seeds 0 1 2 --out "$cell"
    "$PY" -m sb3_pola.cli peers --data-dir "$DATA" --datasets "$d" --algos bc td3bc iql --seeds 0 1 2 --steps 10000 \
      --eval-freq 2000 --eval-episodes 10 --threads 1 --out "$cell"
  done
  "$PY" -m sb3_pola.cli score --preset cpu --data-dir "$DATA" --device cpu --threads 1 --variants T3 \
    --extra '{"eta": 1.0}' --datasets hopper/medium-v0 --seeds 0 1 2 --out "$OUT/seed${S}_eta1_hopper_medium-v0"
done
