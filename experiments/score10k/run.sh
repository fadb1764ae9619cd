#!/usr/bin/env bash
# The #12 grid: CPU preset (10,000 steps, 10 episodes), BC / T=0 / T=3 with the Q-scale floor and the
# look-ahead weights normalised, 3 seeds; one process (one core) per dataset. Re-running resumes.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${MINARI_DATASETS_PATH:?set it to the folder of Minari datasets}" --device cpu --threads 1 \
  --extra '{"q_scale_floor": "auto", "lookahead_normalization": "weights"}' \
  --variants T3 T0 BC --datasets "$1" --seeds 0 1 2 --out "${OUT:-outputs/score10k}"
