#!/usr/bin/env bash
# Second training round (stronger comfort weight, lower learning rates, checkpoint chosen by the
# validation metrics): CA-TD3, CA-DDPG (10 vehicles) and their plain TD3, DDPG baselines (1 vehicle).
# Usage: bash policies/train_round2.sh [PATH_TO_ngsim_cf_events.csv.gz]
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p policies/logs
DATA=${1:-../shared/data/ngsim/ngsim_cf_events.csv.gz}
COMMON="--net networks/i80.net.xml --data $DATA --split train --seed 0 --w-comfort 100 --actor-lr 1e-4 --critic-lr 3e-4 --noise 0.05 --noise-correlation 0.99 --select metrics --eval-every 1000 --checkpoint-every 2000"
cat <<RUNS | xargs -P 2 -I{} bash -c '{}'
carl-sumo train --algo ca-td3 --vehicles 10 --steps 14000 $COMMON --out policies/ca_td3_10.pt > policies/logs/ca_td3_10.log 2>&1
carl-sumo train --algo ca-ddpg --vehicles 10 --steps 14000 $COMMON --out policies/ca_ddpg_10.pt > policies/logs/ca_ddpg_10.log 2>&1
carl-sumo train --algo td3 --vehicles 1 --steps 20000 $COMMON --out policies/td3_1.pt > policies/logs/td3_1.log 2>&1
carl-sumo train --algo ddpg --vehicles 1 --steps 20000 $COMMON --out policies/ddpg_1.pt > policies/logs/ddpg_1.log 2>&1
RUNS
