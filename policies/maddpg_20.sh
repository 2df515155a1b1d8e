#!/usr/bin/env bash
# Paper configuration: MADDPG on IDM, 20 followers, seed 0.
# Usage: bash policies/maddpg_20.sh   (DATA=PATH for another NGSIM event table)
source "$(dirname "$0")/recipe.sh"
train_seeds maddpg_20 0 --algo maddpg --vehicles 20 --steps 6000 $COMMON $PAPER
