#!/usr/bin/env bash
# Fourth training round (replaced by the fifth, train_round5.sh; kept for the record):
# the third round's recipe with a smaller adjustment bound (|a_adj| ≤ 1 m/s²), a weaker headway term
# (w_gap 0.3) and a stronger comfort term (w_comfort 300). Two runs at a time on the 2-core machine.
# CA-TD3 and TD3 with seeds 0, 1, 2 (the seed-0 files are the shipped ones, the others
# `<name>_seed<K>.pt`), CA-DDPG, DDPG, MADDPG for 10 and 20 vehicles.
# Usage: bash policies/train_round4.sh [PATH_TO_ngsim_cf_events.csv.gz]
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p policies/logs
DATA=${1:-../shared/data/ngsim/ngsim_cf_events.csv.gz}
COMMON="--net networks/i80.net.xml --data $DATA --split train --adj-max 1 --w-gap 0.3 --w-comfort 300 --actor-lr 1e-4 --critic-lr 3e-4 --noise 0.05 --noise-correlation 0.99 --select metrics --eval-every 500 --eval-events 16 --checkpoint-every 2000"
cat <<RUNS | xargs -P 2 -I{} bash -c '{}'
carl-sumo train --algo ca-td3 --vehicles 10 --steps 10000 --seed 0 $COMMON --out policies/ca_td3_10.pt > policies/logs/ca_td3_10.log 2>&1
carl-sumo train --algo ca-ddpg --vehicles 10 --steps 10000 --seed 0 $COMMON --out policies/ca_ddpg_10.pt > policies/logs/ca_ddpg_10.log 2>&1
carl-sumo train --algo ca-td3 --vehicles 10 --steps 10000 --seed 1 $COMMON --out policies/ca_td3_10_seed1.pt > policies/logs/ca_td3_10_seed1.log 2>&1
carl-sumo train --algo ca-td3 --vehicles 10 --steps 10000 --seed 2 $COMMON --out policies/ca_td3_10_seed2.pt > policies/logs/ca_td3_10_seed2.log 2>&1
carl-sumo train --algo maddpg --vehicles 10 --steps 10000 --seed 0 $COMMON --out policies/maddpg_10.pt > policies/logs/maddpg_10.log 2>&1
carl-sumo train --algo maddpg --vehicles 20 --steps 6000 --seed 0 $COMMON --out policies/maddpg_20.pt > policies/logs/maddpg_20.log 2>&1
carl-sumo train --algo td3 --vehicles 1 --steps 20000 --seed 0 $COMMON --out policies/td3_1.pt > policies/logs/td3_1.log 2>&1
carl-sumo train --algo td3 --vehicles 1 --steps 20000 --seed 1 $COMMON --out policies/td3_1_seed1.pt > policies/logs/td3_1_seed1.log 2>&1
carl-sumo train --algo td3 --vehicles 1 --steps 20000 --seed 2 $COMMON --out policies/td3_1_seed2.pt > policies/logs/td3_1_seed2.log 2>&1
carl-sumo train --algo ddpg --vehicles 1 --steps 20000 --seed 0 $COMMON --out policies/ddpg_1.pt > policies/logs/ddpg_1.log 2>&1
RUNS
