#!/usr/bin/env bash
# First training round (replaced; the shipped policies come from train_round5.sh): every policy on
# the NGSIM train split, two runs at a time (2-core machine).
# Usage: bash policies/train_all.sh [PATH_TO_ngsim_cf_events.csv.gz]
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${1:-../shared/data/ngsim/ngsim_cf_events.csv.gz}
COMMON="--net networks/i80.net.xml --data $DATA --split train --seed 0 --w-comfort 30 --noise 0.05 --noise-correlation 0.99 --eval-every 1000 --checkpoint-every 2000"
cat <<RUNS | xargs -P 2 -I{} bash -c '{}'
carl-sumo train --algo ca-td3 --vehicles 10 --steps 12000 $COMMON --out policies/ca_td3_10.pt > policies/logs/ca_td3_10.log 2>&1
carl-sumo train --algo ca-ddpg --vehicles 10 --steps 12000 $COMMON --out policies/ca_ddpg_10.pt > policies/logs/ca_ddpg_10.log 2>&1
carl-sumo train --algo td3 --vehicles 1 --steps 20000 $COMMON --out policies/td3_1.pt > policies/logs/td3_1.log 2>&1
carl-sumo train --algo ddpg --vehicles 1 --steps 20000 $COMMON --out policies/ddpg_1.pt > policies/logs/ddpg_1.log 2>&1
carl-sumo train --algo maddpg --vehicles 10 --steps 12000 $COMMON --out policies/maddpg_10.pt > policies/logs/maddpg_10.log 2>&1
carl-sumo train --algo maddpg --vehicles 20 --steps 8000 $COMMON --out policies/maddpg_20.pt > policies/logs/maddpg_20.log 2>&1
carl-sumo train --algo ca-td3 --vehicles 20 --steps 8000 $COMMON --out policies/ca_td3_20.pt > policies/logs/ca_td3_20.log 2>&1
carl-sumo train --algo ca-ddpg --vehicles 20 --steps 8000 $COMMON --out policies/ca_ddpg_20.pt > policies/logs/ca_ddpg_20.log 2>&1
RUNS
