#!/usr/bin/env bash
# Paper configuration: CA-DDPG on IDM, 10 followers, seeds 0-14.
# Usage: bash policies/ca_ddpg_10.sh   (DATA=PATH for another NGSIM event table)
source "$(dirname "$0")/recipe.sh"
train_seeds ca_ddpg_10 "$(seq -s " " 0 14)" --algo ca-ddpg --vehicles 10 --steps 10000 $COMMON $PAPER
