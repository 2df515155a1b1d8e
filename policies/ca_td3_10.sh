#!/usr/bin/env bash
# Paper configuration: CA-TD3 on IDM, 10 followers, seeds 0-14.
# Usage: bash policies/ca_td3_10.sh   (DATA=PATH for another NGSIM event table)
source "$(dirname "$0")/recipe.sh"
train_seeds ca_td3_10 "$(seq -s " " 0 14)" --algo ca-td3 --vehicles 10 --steps 10000 $COMMON $PAPER
