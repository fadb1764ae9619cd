#!/usr/bin/env bash
# #23: levers for the narrow hopper files (docs/results.md, twenty-fifth pass). On hopper/medium of collect.sh files
# ROOT/seed<S> (files.sh's layout), POLA at the CPU preset with one change each, one seed (SCREEN_SEEDS, default 0):
# a lower confidence bound (lcb_coef 2, 4), EDAC's term at 5, eta 2, the paper's 10 critics, and advantage-weighted
# imitation (bc_weight_temp 3 at eta 1 and eta 0, 1 at the default eta). One core.
#   FILES="0 1 2" ROOT=<folder> bash experiments/hopper/q_weight_screen.sh     (outputs in OUT)
# Then: python experiments/hopper/screen_table.py <OUT> > experiments/hopper/q_weight_screen.csv
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
PY="${PYTHON:-python}"
ROOT="${ROOT:?set ROOT to the folder holding seed<S>/ collections}"
OUT="${OUT:-outputs/hopper/q_weight_screen}"
declare -A EXTRA=(
  [lcb2]='{"lcb_coef": 2.0}' [lcb4]='{"lcb_coef": 4.0}' [cd5]='{"critic_diversity": 5.0}' [eta2]='{"eta": 2.0}'
  [n10]='{}' [e1t3]='{"eta": 1.0, "bc_weight_temp": 3.0}' [e0t3]='{"eta": 0.0, "bc_weight_temp": 3.0}'
  [e394t1]='{"bc_weight_temp": 1.0}'
)
declare -A FLAGS=([n10]="--n-critics 10")  # the preset's own arguments have flags; --extra refuses them
for S in ${FILES:-0 1 2}; do
  for tag in ${TAGS:-lcb2 lcb4 cd5 eta2 n10 e1t3 e0t3 e394t1}; do
    "$PY" -m sb3_pola.cli score --preset cpu --data-dir "$ROOT/seed$S" --device cpu --threads 1 --variants T3 \
      --datasets hopper/medium-v0 --seeds ${SCREEN_SEEDS:-0} ${FLAGS[$tag]:-} --extra "${EXTRA[$tag]}" --out "$OUT/${tag}_file$S"
  done
done
