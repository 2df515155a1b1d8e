#!/usr/bin/env bash
# The communication test with REAL_CRIT's reward and a command feed-forward (REAL_ACC_CMD in recipe.sh): CA-TD3 on the
# robust CACC's law without its V2V feed-forward, warm-started by copying that CACC with the predecessor's command as
# the feed-forward, validated on every training source, 10 followers, seeds 0-4.
source "$(dirname "$0")/recipe.sh"
train_seeds ca_td3_real_acccmd_10 "0 1 2 3 4" --algo ca-td3 --vehicles 10 --steps 8000 $COMMON_ALLVAL $REAL_ACC_CMD
