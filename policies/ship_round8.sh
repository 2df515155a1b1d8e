#!/usr/bin/env bash
# Ships the eighth round (protocol in docs/training.md, "Eighth round"): for each model, the run
# among seeds 10-14 with the best validation score becomes <stem>.pt, whatever the seventh
# round's file did; that file goes back to <stem>_seed<K>.pt. Run once, after
# policies/train_round8.sh.
set -euo pipefail
exec bash "$(dirname "$0")/ship_best.sh" 8 "10 11 12 13 14"
