#!/usr/bin/env bash
# REAL_SPACING_HA_OWN_GAP (recipe.sh): the degraded-head recipe with the spacing term at the base's 0.8 s, validated on
# every training source, seeds 0-4.
source "$(dirname "$0")/recipe.sh"
train_seeds ca_td3_real_ha_owngap_10 "0 1 2 3 4" --algo ca-td3 --vehicles 10 --steps 8000 $COMMON_ALLVAL $REAL_SPACING_HA_OWN_GAP
