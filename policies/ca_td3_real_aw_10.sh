#!/usr/bin/env bash
# The product recipe on the robust CACC with anti-windup (aw=1), randomised real-plant fleets, 10 followers, seeds 0-4.
source "$(dirname "$0")/recipe.sh"
train_seeds ca_td3_real_aw_10 "0 1 2 3 4" --algo ca-td3 --vehicles 10 --steps 8000 $COMMON $REAL_AW
