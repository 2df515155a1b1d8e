#!/usr/bin/env bash
# Eighth training round, pre-registered (protocol in docs/training.md, "Eighth round", written and
# committed before any of these runs started): fresh seeds 10-14 of CA-TD3 and CA-DDPG
# (10 vehicles), TD3, DDPG (1 vehicle) and MADDPG (10 vehicles), with the sixth and seventh rounds'
# recipe unchanged (SELECT=margin). Afterwards `bash policies/ship_round8.sh` ships, for each of
# these five models, the run among seeds 10-14 with the best validation score; no test-split
# number is used for that choice.
# Usage: bash policies/train_round8.sh [PATH_TO_ngsim_cf_events.csv.gz]
set -euo pipefail
SELECT=margin EXTRA_ONLY=1 SEEDS="10 11 12 13 14" MADDPG_SEEDS="10 11 12 13 14" \
  exec bash "$(dirname "$0")/train_round5.sh" "$@"
