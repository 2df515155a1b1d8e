#!/usr/bin/env bash
# Paper configuration trained for impaired V2V: CA-TD3 on IDM, 10 followers, every training episode
# with its own delay, loss and sensor noise (--comm-randomize), validated also under impairments
# (--val-impaired), seeds 0-4.
# Usage: bash policies/ca_td3_10_robust.sh   (DATA=PATH for another NGSIM event table)
source "$(dirname "$0")/recipe.sh"
train_seeds ca_td3_10_robust "0 1 2 3 4" --algo ca-td3 --vehicles 10 --steps 10000 $COMMON $PAPER --comm-randomize --val-impaired
