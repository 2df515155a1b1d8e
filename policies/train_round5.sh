#!/usr/bin/env bash
# Fifth training round (replaced by the sixth, `train_round6.sh`, which runs this script with
# SELECT=margin): the fourth round's recipe (|a_adj| ≤ 1 m/s²,
# w_gap 0.3, w_comfort 300) plus CAPS-style actor smoothness terms (--smooth-jerk 0.05
# --smooth-accel 0.1), validated on 64 held-out training events that are the same for every run
# (--val-seed 0) and come from the source most like the test set (zhu2020_pool_transfollower:
# the same extraction of the same study as the test source zhu2020_testset), so seeds and
# algorithms are compared on one validation set that resembles the test.
# Every algorithm gets the same recipe. CA-TD3, CA-DDPG, TD3 and DDPG with seeds 0, 1, 2 (the
# seed-0 files are the shipped ones, the others `<name>_seed<K>.pt`); MADDPG and the CA models
# for 20 vehicles with seed 0. Two runs at a time on the 2-core machine.
# Usage: bash policies/train_round5.sh [PATH_TO_ngsim_cf_events.csv.gz]
# (SELECT=margin: the sixth round, policies/train_round6.sh; SEEDS="1 2 3 4": the extra seeds;
# EXTRA_ONLY=1: only the runs of SEEDS, no seed-0 run; MADDPG_SEEDS="...": extra MADDPG-10 seeds;
# DRY_RUN=1: print the commands instead of running them)
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p policies/logs
DATA=${1:-../shared/data/ngsim/ngsim_cf_events.csv.gz}
COMMON="--net networks/i80.net.xml --data $DATA --split train --adj-max 1 --w-gap 0.3 --w-comfort 300 --smooth-jerk 0.05 --smooth-accel 0.1 --actor-lr 1e-4 --critic-lr 3e-4 --noise 0.05 --noise-correlation 0.99 --select ${SELECT:-metrics} --eval-every 500 --eval-events 64 --val-seed 0 --val-source zhu2020_pool_transfollower --checkpoint-every 2000"
run() {  # NAME ALGO VEHICLES STEPS SEED
  local out=policies/$1.pt
  echo "carl-sumo train --algo $2 --vehicles $3 --steps $4 --seed $5 $COMMON --out $out > policies/logs/$1.log 2>&1"
}
SEEDS=${SEEDS:-1 2}  # the extra seeds of CA-TD3, CA-DDPG, TD3 and DDPG
seed0() { [ -z "${EXTRA_ONLY:-}" ] && run "$@" || true; }
{
  seed0 ca_td3_10 ca-td3 10 10000 0
  seed0 ca_ddpg_10 ca-ddpg 10 10000 0
  seed0 ca_td3_20 ca-td3 20 8000 0
  seed0 ca_ddpg_20 ca-ddpg 20 8000 0
  for s in $SEEDS; do run ca_td3_10_seed$s ca-td3 10 10000 $s; done
  for s in $SEEDS; do run ca_ddpg_10_seed$s ca-ddpg 10 10000 $s; done
  seed0 maddpg_10 maddpg 10 10000 0
  seed0 maddpg_20 maddpg 20 6000 0
  for s in ${MADDPG_SEEDS:-}; do run maddpg_10_seed$s maddpg 10 10000 $s; done
  seed0 td3_1 td3 1 20000 0
  for s in $SEEDS; do run td3_1_seed$s td3 1 20000 $s; done
  seed0 ddpg_1 ddpg 1 20000 0
  for s in $SEEDS; do run ddpg_1_seed$s ddpg 1 20000 $s; done
} | if [ -n "${DRY_RUN:-}" ]; then cat; else xargs -P 2 -I{} bash -c '{}'; fi
