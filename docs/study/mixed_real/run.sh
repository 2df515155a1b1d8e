#!/usr/bin/env bash
# Half the vehicles CACC on the real plant (--plant real: 80 % cars, 20 % trucks with their lags and
# dead times, 0.1 s V2V delay) at the saturating demand of docs/study/saturated_real/: demand x1.5,
# 300 s warm-up + 600 s measured, seeds 0 and 1, p = 0.5. Outputs: results/study_mixed_real/<controller>/.
set -euo pipefail
cd "$(dirname "$0")/../../.."
common="--net networks/i80.net.xml --demand-scale 1.5 --duration 600 --warmup 300 --seeds 2 --plant real --penetration 0.5"
out=results/study_mixed_real
carl-sumo study $common --controller policies/ca_td3_real_10.pt --out $out/ca_td3_real_10
# the former product (git show ecbde40:policies/ca_td3_real_truck_10.pt > policies/ca_td3_real_truck_10.pt):
# carl-sumo study $common --controller policies/ca_td3_real_truck_10.pt --out $out/ca_td3_real_truck_10
carl-sumo study $common --controller ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1 --out $out/ploeg_robust_h08_layers
