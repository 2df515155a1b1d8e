#!/usr/bin/env bash
# The saturating-demand study of docs/study.md: demand x1.5 (18,750 veh/h offered; the human-only
# road carries about 11,000), 300 s warm-up + 600 s measured, seeds 0 and 1, 2 worker processes.
# p = 0 (humans only) runs once, with idm-external; every CACC controller runs p = 0.5 and 1.
# Outputs go to results/study_saturated/<controller>/; docs/study/saturated/ keeps their tables.
set -euo pipefail
cd "$(dirname "$0")/../../.."
common="--net networks/i80.net.xml --demand-scale 1.5 --duration 600 --warmup 300 --seeds 2"
out=results/study_saturated
carl-sumo study $common --controller idm-external --penetration 0,0.5,1 --out $out/idm_external
carl-sumo study $common --controller sumo-cacc --penetration 0.5,1 --out $out/sumo_cacc
carl-sumo study $common --controller policies/ca_td3_10.pt --penetration 0.5,1 --out $out/ca_td3_10
carl-sumo study $common --controller ploeg-tuned:h=1 --penetration 0.5,1 --out $out/ploeg_tuned_h1
carl-sumo study $common --controller ploeg-tuned:h=0.8 --penetration 0.5,1 --out $out/ploeg_tuned_h08
carl-sumo study $common --controller policies/ca_td3_ploeg_10.pt --penetration 0.5,1 --out $out/ca_td3_ploeg_10
