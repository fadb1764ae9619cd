#!/usr/bin/env bash
# #12: the main job (shipped InvertedPendulum data, light config) for several seeds, one output folder per seed:
# bash experiments/main_seeds.sh OUT 'EXTRA_JSON' SEED... (EXTRA_JSON: further POLA arguments, '{}' for none)
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
out=$1 extra=$2
shift 2
mkdir -p "$out"
for seed in "$@"; do
  "${PYTHON:-python}" -m sb3_pola.cli run --seed "$seed" --extra "$extra" --out "$out/seed$seed" > "$out/seed$seed.log" 2>&1
done
