#!/usr/bin/env bash
# The real-plant product recipe on the degraded CACC (ha=1.4) with the spacing term (REAL_SPACING_HA in recipe.sh), seeds 0-4.
source "$(dirname "$0")/recipe.sh"
train_seeds ca_td3_real_ha_10 "0 1 2 3 4" --algo ca-td3 --vehicles 10 --steps 8000 $COMMON $REAL_SPACING_HA
