#!/usr/bin/env bash
# Plain TD3 with the same per-vehicle inputs and recipe as ca_td3_real_truck_10 (REAL_TRUCK: no CA module, so it copies
# only the two-ahead target's mean given o_i), trained in a platoon of 10 (a per-vehicle network: it runs any length),
# seeds 0-4.
source "$(dirname "$0")/recipe.sh"
train_seeds td3_real_truck_1 "${SEEDS:-0 1 2 3 4}" --algo td3 --vehicles 10 --steps 8000 $COMMON_ALLVAL $REAL_TRUCK
