#!/usr/bin/env bash
# The saturating-demand study of docs/study.md with the CACC vehicles on the real plant (--plant real:
# 80 % cars, 20 % trucks with their lags and dead times, 0.1 s V2V delay): demand x1.5, 300 s warm-up
# + 600 s measured, seeds 0 and 1, p = 1 for each controller (p = 0, humans only, has no CACC vehicle:
# the plant does not enter it, see docs/study/saturated/). Outputs: results/study_saturated_real/<controller>/.
set -euo pipefail
cd "$(dirname "$0")/../../.."
common="--net networks/i80.net.xml --demand-scale 1.5 --duration 600 --warmup 300 --seeds 2 --plant real --penetration 1"
out=results/study_saturated_real
carl-sumo study $common --controller policies/ca_td3_real_10.pt --out $out/ca_td3_real_10   # the product
carl-sumo study $common --controller ploeg:h=0.8:kp=0.0445:kd=1 --out $out/ploeg_robust_h08
carl-sumo study $common --controller acc:h=2.5:kp=0.45:kd=1.5 --out $out/acc_robust_h25
carl-sumo study $common --controller ploeg:h=0.8:kp=0.0445:kd=1:aw=1 --out $out/ploeg_robust_h08_aw
carl-sumo study $common --controller policies/ca_td3_real_aw_10.pt --out $out/ca_td3_real_aw_10
carl-sumo study $common --controller ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4 --out $out/ploeg_robust_h08_aw_ha
carl-sumo study $common --controller policies/ca_td3_real_ha_10.pt --out $out/ca_td3_real_ha_10
carl-sumo study $common --controller ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2 --out $out/ploeg_robust_h08_aw_ha_ttc
carl-sumo study $common --controller policies/ca_td3_real_react_10.pt --out $out/ca_td3_real_react_10
carl-sumo study $common --controller policies/ca_td3_real_gap06_10.pt --out $out/ca_td3_real_gap06_10
carl-sumo study $common --controller policies/ca_td3_real_two_10.pt --out $out/ca_td3_real_two_10
# the former product (git show ecbde40:policies/ca_td3_real_truck_10.pt > policies/ca_td3_real_truck_10.pt):
# carl-sumo study $common --controller policies/ca_td3_real_truck_10.pt --out $out/ca_td3_real_truck_10
carl-sumo study $common --controller ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1:wo=5:gn=6:op=2:ht=0.8 --out $out/ploeg_product_base
carl-sumo study $common --controller policies/ca_td3_real_two_open_10.pt --out $out/ca_td3_real_two_open_10
carl-sumo study $common --controller mpf-tuned --out $out/mpf_tuned
