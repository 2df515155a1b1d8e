#!/usr/bin/env bash
# Sixth training round (the shipped policies): the fifth round's runs unchanged (same recipe, same
# seeds, hence the same training trajectories and learning curves), with a new rule for the
# checkpoint that is kept: --select margin keeps the checkpoint whose smallest paired z-statistic
# of the improvement over IDM on the validation events (less jerk, a lower dampening ratio, a
# higher mean speed) is largest. The fifth round's rule (--select metrics: jerk/IDM's +
# dampening/IDM's, any mean speed at least IDM's) could keep a checkpoint with no speed margin.
# Seeds 3 and 4 of CA-TD3, CA-DDPG, TD3 and DDPG (added to measure the spread across seeds; the
# shipped files stay the seed-0 ones) make five seeds of each.
# Usage: bash policies/train_round6.sh [PATH_TO_ngsim_cf_events.csv.gz]
set -euo pipefail
SELECT=margin SEEDS="1 2 3 4" exec bash "$(dirname "$0")/train_round5.sh" "$@"
