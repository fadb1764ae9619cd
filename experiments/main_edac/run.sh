#!/usr/bin/env bash
# #12: the main job (paper's form) with EDAC's ensemble-similarity term on the critics (critic_diversity = 1)
exec bash "$(dirname "$0")/../main_seeds.sh" "${OUT:-outputs/main_edac}" '{"critic_diversity": 1.0}' "$@"
