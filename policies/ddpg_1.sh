#!/usr/bin/env bash
# Paper configuration: DDPG on IDM (one vehicle, runs any length), seeds 0-14.
# Usage: bash policies/ddpg_1.sh   (DATA=PATH for another NGSIM event table)
source "$(dirname "$0")/recipe.sh"
train_seeds ddpg_1 "$(seq -s " " 0 14)" --algo ddpg --vehicles 1 --steps 20000 $COMMON $PAPER
