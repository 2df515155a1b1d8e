#!/usr/bin/env bash
# The real-plant product recipe with a spacing term at a 0.7 s time gap (REAL_SPACING in recipe.sh), seeds 0-4.
source "$(dirname "$0")/recipe.sh"
train_seeds ca_td3_real_spacing_10 "0 1 2 3 4" --algo ca-td3 --vehicles 10 --steps 8000 $COMMON $REAL_SPACING
