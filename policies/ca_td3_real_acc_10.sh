#!/usr/bin/env bash
# The communication test on the real plant: CA-TD3 on a radar-only ACC base (h = 0.8 s), warm-started by imitating the CACC with its gains, randomised fleets, 10 followers, seeds 0-4.
# Usage: bash policies/ca_td3_real_acc_10.sh   (DATA=PATH for another NGSIM event table)
source "$(dirname "$0")/recipe.sh"
train_seeds ca_td3_real_acc_10 "0 1 2 3 4" --algo ca-td3 --vehicles 10 --steps 5000 $COMMON $REAL_ACC
