#!/usr/bin/env bash
# Shipped the seventh round (protocol in docs/training.md, "Seventh round"): for each model, the
# run among seeds 5-9 with the best validation score became <stem>.pt and the sixth round's
# seed-0 file <stem>_seed0.pt; the rankings are in policies/round7_ranking.md. It ran once, after
# policies/train_round7.sh (commit 5db535d); the steps are in policies/ship_best.sh.
set -euo pipefail
exec bash "$(dirname "$0")/ship_best.sh" 7 "5 6 7 8 9"
