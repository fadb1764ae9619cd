#!/usr/bin/env bash
# #23's long runs, POLA half: the package defaults (the CPU preset's T3 variant) for 100,000 steps on hopper/medium
# and halfcheetah/medium-replay, evaluation every 5,000 steps on 10 episodes, next to experiments/long100k/peers.sh.
# The tenth pass ran the defaults before the twelfth pass (eta 1, lookahead_weight 1: EXTRA='{"eta": 1.0,
# "lookahead_weight": 1.0}' now); the twelfth pass's runs are the new defaults (its scores in la16/).
# One core; re-running resumes from the run's checkpoints. bash experiments/long100k/run.sh ["SEEDS"] ["DATASETS"]
# VARIANTS picks other variants of the score grid: BC (the package's actor, eta = 0), T0 (no look-ahead); EXTRA is JSON
# of further POLA arguments (the eleventh pass: '{"eta": 3.94}', '{"lookahead_normalization": "weights"}',
# '{"model_td_weight": 1.0}', '{"model_conservatism": 1.0}'), STEPS the budget (default 100000). A different
# EXTRA or STEPS needs its own OUT (the grid keeps configurations apart by a signature).
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
"${PYTHON:-python}" -m sb3_pola.cli score --preset cpu --data-dir "${DATA:-${MINARI_DATASETS_PATH:?set DATA or MINARI_DATASETS_PATH to the folder of Minari datasets}}" \
  --device cpu --threads 1 --steps ${STEPS:-100000} --eval-freq 5000 --eval-episodes 10 --variants ${VARIANTS:-T3} \
  --datasets ${2:-hopper/medium-v0 halfcheetah/medium-replay-v0} --seeds ${1:-0 1 2} --out "${OUT:-outputs/long100k}" \
  ${EXTRA:+--extra "$EXTRA"}
