#!/usr/bin/env bash
# REAL_SPACING_HA validated on every training source (COMMON_ALLVAL, recipe.sh), seeds 0-4.
source "$(dirname "$0")/recipe.sh"
train_seeds ca_td3_real_ha_allval_10 "0 1 2 3 4" --algo ca-td3 --vehicles 10 --steps 8000 $COMMON_ALLVAL $REAL_SPACING_HA_ALLVAL
