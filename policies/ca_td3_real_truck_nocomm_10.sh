#!/usr/bin/env bash
# The communication ablation of ca_td3_real_truck_10: the same recipe and seeds with the CA messages cut (--comm-off).
source "$(dirname "$0")/recipe.sh"
train_seeds ca_td3_real_truck_nocomm_10 "0 1 2 3 4" --algo ca-td3 --vehicles 10 --steps 8000 --comm-off $COMMON_ALLVAL $REAL_TRUCK
