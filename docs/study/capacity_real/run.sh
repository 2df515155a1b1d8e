#!/usr/bin/env bash
# Capacity against CACC penetration on the real plant (issue 54, item 6): the saturating demand of
# docs/study/saturated_real/ (demand x1.5: 3,000 veh/h offered on each of the six mainline lanes,
# 750 on the on-ramp), --plant real (80 % cars, 20 % trucks with their own lags and dead times,
# 0.1 s V2V delay), 300 s warm-up + 600 s measured, one study process at a time (--workers 1).
# Seed 0 (`--seeds 1`); SEEDS="0 1" adds seed 1 through one_seed.py, the run `--seeds 2` makes
# for seed 1 (each run is seeded by its (p, seed) alone).
# Outputs: results/capacity_real/s<seed>/<folder>[/p<p>]/. Copy each runs.csv to
# docs/study/capacity_real/<folder>/ (runs.csv, runs_p<p>.csv; seed 1: runs_seed1*.csv), then
# `python docs/study/capacity_real/table.py` makes the table of docs/study.md and
# `python docs/study/capacity_real/entries.py results/capacity_real/s0` entries.csv.
set -euo pipefail
cd "$(dirname "$0")/../../.."
PY=${PY:-python}
common="--net networks/i80.net.xml --demand-scale 1.5 --duration 600 --warmup 300 --plant real --workers 1"
MPF="mpf:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1:gn=6:op=2:ht=0.8:r=2:w2=0.3"
MPC_GN="mpc:h=0.6:N=30:wq=0.8:wv=0.666667:wu=2:wj=0.2:ha=2:ht=0.8:ttc=2:rb=1:ra=1:go=0.5:gn=6"  # mpc-tuned + gn=6
MPC_GC="mpc:h=0.6:N=30:wq=0.8:wv=0.666667:wu=2:wj=0.2:ha=2:ht=0.8:ttc=2:rb=1:ra=1:go=0.5:gc=1"  # mpc-tuned + gc=1
GAP="mpf:h=0.5:kp=0.0445:kd=1:r=3:w1=0.5:w2=0.4:w3=0.1:aw=1:ha=2.3:ttc=2:rb=1:gn=6:op=2:ht=0.8"  # the gap trade
base() { echo "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=$1:ttc=2:rb=1:wo=5:gn=6:op=2:ht=0.8"; }  # product-base with ha=$1
out=results/capacity_real
study() {  # seed out-folder controller penetrations
  if [ "$1" = 0 ]; then
    $PY -m carl_sumo study $common --seeds 1 --penetration "$4" --controller "$3" --out "$out/s0/$2"
  else
    $PY docs/study/capacity_real/one_seed.py "$1" $common --penetration "$4" --controller "$3" --out "$out/s$1/$2"
  fi
}
for seed in ${SEEDS:-0}; do
  study $seed product_base product-base 0,0.25,0.5,0.75,1   # p = 0 is the human-only road
  for p in 0.5 0.75; do  # the degraded head's gap: product-base with a shorter ACC fallback
    study $seed product_base_ha0.8/p$p "$(base 0.8)" $p
    study $seed product_base_ha1.0/p$p "$(base 1.0)" $p
    study $seed mpf_r2/p$p "$MPF" $p
  done
  for p in 0.25 1; do study $seed mpf_r2/p$p "$MPF" $p; done
  for p in 0.25 0.5 0.75 1; do study $seed mpf_tuned/p$p mpf-tuned $p; done  # its weights tuned for the fleet (r = 3)
  for p in 0.5 0.75; do study $seed mpc/p$p mpc $p; done  # the distributed MPC, its defaults
  for p in 0.25 0.5 0.75 1; do study $seed mpc_tuned/p$p mpc-tuned $p; done  # tuned for the fleet
  for p in 0.25 0.5 0.75 1; do study $seed mpc_tuned_gn/p$p "$MPC_GN" $p; done  # the same with Ploeg's gn layers (the merge point)
  study $seed mpc_tuned_gc/p0.25 "$MPC_GC" 0.25  # the same closing a long gap at most 1 m/s
  for p in 0.5 0.75; do study $seed gap_trade/p$p "$GAP" $p; done  # cars 0.5 s, heads at 2.3 s
done
# p = 1 at a higher demand (x1.75: 3,500 veh/h offered per mainline lane, 875 on the ramp), seed 0
$PY -m carl_sumo study ${common/--demand-scale 1.5/--demand-scale 1.75} --seeds 1 --penetration 1 --controller product-base --out $out/s0/product_base_d1.75/p1
# diagnostic: the same law at p = 0.5 with a fleet of cars only (no trucks), seed 0
$PY -m carl_sumo study $common --seeds 1 --fleet car:1 --penetration 0.5 --controller product-base --out $out/s0/product_base_cars/p0.5
# seed 1 where the table has it beyond the reused runs: p = 0.5, product-base and its 0.8 s fallback
study 1 product_base/p0.5 product-base 0.5
study 1 product_base_ha0.8/p0.5 "$(base 0.8)" 0.5
