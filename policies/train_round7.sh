#!/usr/bin/env bash
# Seventh training round, pre-registered (protocol in docs/training.md, "Seventh round", written
# and committed before any of these runs started): fresh seeds 5-9 of CA-TD3 and CA-DDPG
# (10 vehicles), TD3, DDPG (1 vehicle) and MADDPG (10 vehicles), with the sixth round's recipe
# unchanged (SELECT=margin). Afterwards `bash policies/ship_round7.sh` ships, for each of these
# five models, the run among seeds 5-9 with the best validation score; no test-split number is
# used for that choice.
# Usage: bash policies/train_round7.sh [PATH_TO_ngsim_cf_events.csv.gz]
set -euo pipefail
SELECT=margin EXTRA_ONLY=1 SEEDS="5 6 7 8 9" MADDPG_SEEDS="5 6 7 8 9" \
  exec bash "$(dirname "$0")/train_round5.sh" "$@"
