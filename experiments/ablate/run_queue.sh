#!/usr/bin/env bash
# Runs score commands one after another on one core: run_queue.sh NAME 'EXTRA_JSON' VARIANTS... -- DATASETS...
# Usage: bash experiments/ablate/run_queue.sh <out-name> '<extra json>' "<variants>" "<datasets>" "<seeds>"
set -u
cd "$(dirname "$0")/../.."
out=${OUT:-outputs/ablate/$1}; extra=$2; variants=$3; datasets=$4; seeds=${5:-0}
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${MINARI_DATASETS_PATH:?set it to the folder of Minari datasets}" --device cpu --threads 1 \
  --steps 10000 --eval-freq 2000 --eval-episodes 10 --extra "$extra" --variants $variants --datasets $datasets \
  --seeds $seeds --out "$out"
