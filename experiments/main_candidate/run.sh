#!/usr/bin/env bash
# #12: the main job with the package defaults of 2026-12-02 instead of the paper's form: the weakened Q term,
# critic_diversity = 1, detached look-ahead states
exec bash "$(dirname "$0")/../main_seeds.sh" "${OUT:-outputs/main_candidate}" \
  '{"q_scale_floor": "auto", "lookahead_normalization": "weights", "critic_diversity": 1.0, "backprop_through_model": false}' "$@"
