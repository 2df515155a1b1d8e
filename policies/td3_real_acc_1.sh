#!/usr/bin/env bash
# Plain TD3 with the per-vehicle inputs and recipe of ca_td3_real_acc_10 (no CA module), trained in a platoon of 10, seeds 0-4.
source "$(dirname "$0")/recipe.sh"
train_seeds td3_real_acc_1 "0 1 2 3 4" --algo td3 --vehicles 10 --steps 5000 $COMMON $REAL_ACC
