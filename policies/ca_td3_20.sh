#!/usr/bin/env bash
# Paper configuration: CA-TD3 on IDM trained on 20 followers, seed 0.
# Usage: bash policies/ca_td3_20.sh   (DATA=PATH for another NGSIM event table)
source "$(dirname "$0")/recipe.sh"
train_seeds ca_td3_20 0 --algo ca-td3 --vehicles 20 --steps 8000 $COMMON $PAPER
