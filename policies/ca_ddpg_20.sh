#!/usr/bin/env bash
# Paper configuration: CA-DDPG on IDM trained on 20 followers, seed 0.
# Usage: bash policies/ca_ddpg_20.sh   (DATA=PATH for another NGSIM event table)
source "$(dirname "$0")/recipe.sh"
train_seeds ca_ddpg_20 0 --algo ca-ddpg --vehicles 20 --steps 8000 $COMMON $PAPER
