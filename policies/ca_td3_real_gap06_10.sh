#!/usr/bin/env bash
# REAL_GAP on the robust CACC at h = 0.6 s (REAL_GAP06 in recipe.sh), CA-TD3, 10 followers, seeds 0-4; ships the
# best-validated seed that is string stable on the real plant.
source "$(dirname "$0")/recipe.sh"
SHIP_STRING_STABLE=real train_seeds ca_td3_real_gap06_10 "0 1 2 3 4" --algo ca-td3 --vehicles 10 --steps 8000 $COMMON_ALLVAL $REAL_GAP06
