#!/usr/bin/env bash
# #12: the main job with the paper's form (the light configuration's own), bash experiments/main_paper/run.sh 1 2
exec bash "$(dirname "$0")/../main_seeds.sh" "${OUT:-outputs/main_paper}" '{}' "$@"
