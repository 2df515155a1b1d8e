#!/usr/bin/env bash
# REAL_TRUCK (recipe.sh): REAL_TWO_OPEN with trucks at 0.8 s (ht=0.8), CA-TD3, 10 followers, seeds 0-4; ships the
# best-validated seed that is string stable on the real plant.
source "$(dirname "$0")/recipe.sh"
SHIP_STRING_STABLE=real train_seeds ca_td3_real_truck_10 "${SEEDS:-0 1 2 3 4}" --algo ca-td3 --vehicles 10 --steps 8000 $COMMON_ALLVAL $REAL_TRUCK
