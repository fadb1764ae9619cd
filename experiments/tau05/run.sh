#!/usr/bin/env bash
# #12, the critic's speed: the experiments/score10k grid on halfcheetah/medium with a 10x faster target
# network (tau = 0.05 instead of 0.005), T=0, 3 seeds (T=3 dropped: T=0 got worse). Same weakened Q term as score10k.
# Re-running resumes.
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${MINARI_DATASETS_PATH:?set it to the folder of Minari datasets}" --device cpu --threads 1 \
  --extra '{"q_scale_floor": "auto", "lookahead_normalization": "weights", "tau": 0.05}' \
  --variants T0 --datasets halfcheetah/medium-v0 --seeds 0 1 2 --out "${OUT:-outputs/tau05}"
