#!/usr/bin/env bash
# #12: the main job with the paper's form (the light configuration's own), bash results/main_paper/run.sh 1 2
exec bash "$(dirname "$0")/../main_seeds.sh" results/main_paper '{}' "$@"
