#!/usr/bin/env bash
# Paper configuration: MADDPG on IDM, 10 followers, seeds 0 and 5-14.
# Usage: bash policies/maddpg_10.sh   (DATA=PATH for another NGSIM event table)
source "$(dirname "$0")/recipe.sh"
train_seeds maddpg_10 "0 $(seq -s " " 5 14)" --algo maddpg --vehicles 10 --steps 10000 $COMMON $PAPER
