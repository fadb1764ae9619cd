#!/usr/bin/env bash
# #12: the main job (paper's form) with the look-ahead states detached from the actor
exec bash "$(dirname "$0")/../main_seeds.sh" "${OUT:-outputs/main_nobackprop}" '{"backprop_through_model": false}' "$@"
