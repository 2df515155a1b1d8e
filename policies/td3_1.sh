#!/usr/bin/env bash
# Paper configuration: TD3 on IDM (one vehicle, runs any length), seeds 0-14.
# Usage: bash policies/td3_1.sh   (DATA=PATH for another NGSIM event table)
source "$(dirname "$0")/recipe.sh"
train_seeds td3_1 "$(seq -s " " 0 14)" --algo td3 --vehicles 1 --steps 20000 $COMMON $PAPER
