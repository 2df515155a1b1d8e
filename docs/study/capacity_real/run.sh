#!/usr/bin/env bash
# Capacity against CACC penetration on the real plant (issue 54, item 6): the saturating demand of
# docs/study/saturated_real/ (demand x1.5: 3,000 veh/h offered on each of the six mainline lanes,
# 750 on the on-ramp), --plant real (80 % cars, 20 % trucks with their own lags and dead times,
# 0.1 s V2V delay), 300 s warm-up + 600 s measured, p = 0, 0.25, 0.5, 0.75, 1, one study process
# at a time (--workers 1). Seed 0 by `--seeds 1`; seed 1 by one_seed.py, the same run that
# `--seeds 2` makes for seed 1 (each run is seeded by its (p, seed) alone).
# Outputs: results/capacity_real/<folder>/; the small tables are copied to docs/study/capacity_real/<folder>/
# (runs.csv for seed 0, runs_seed1.csv for seed 1) and `python docs/study/capacity_real/table.py`
# makes the table of docs/study.md.
set -euo pipefail
cd "$(dirname "$0")/../../.."
PY=${PY:-python}
common="--net networks/i80.net.xml --demand-scale 1.5 --duration 600 --warmup 300 --plant real --workers 1"
MPF="mpf:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1:gn=6:op=2:ht=0.8:r=2:w2=0.3"
base() { echo "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=$1:ttc=2:rb=1:wo=5:gn=6:op=2:ht=0.8"; }
out=results/capacity_real
study() {  # seed folder controller penetrations
  if [ "$1" = 0 ]; then
    $PY -m carl_sumo study $common --seeds 1 --penetration "$4" --controller "$3" --out "$out/s0/$2"
  else
    $PY docs/study/capacity_real/one_seed.py "$1" $common --penetration "$4" --controller "$3" --out "$out/s$1/$2"
  fi
}
for seed in 0 1; do
  study $seed product_base product-base 0,0.25,0.5,0.75,1   # p = 0 is the human-only road
  study $seed mpf_r2 "$MPF" 0.25,0.5,0.75,1
  # the degraded head's gap: the same law with a shorter ACC fallback (ha) where chains are short
  study $seed product_base_ha1.0 "$(base 1.0)" 0.5,0.75
  study $seed product_base_ha0.8 "$(base 0.8)" 0.5,0.75
done
