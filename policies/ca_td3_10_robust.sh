#!/usr/bin/env bash
# Paper configuration fine-tuned for impaired V2V: CA-TD3 on IDM, 10 followers, seed K warm-started
# from the nominal policy's seed K (--init), its critics trained alone for 2,000 steps, then
# every training episode with its own delay, loss and sensor noise (--comm-randomize); validated
# also under impairments (--val-impaired), the warm start being the first candidate; a vehicle that
# hears no neighbour drives on IDM alone (--comm-fallback base). Seeds 0-4.
# Usage: bash policies/ca_td3_10_robust.sh   (DATA=PATH for another NGSIM event table)
source "$(dirname "$0")/recipe.sh"
train_seeds ca_td3_10_robust "0 1 2 3 4" --algo ca-td3 --vehicles 10 --steps 6000 --critic-burn-in 2000 $COMMON $PAPER --comm-randomize --val-impaired --comm-fallback base --init 'policies/seeds/ca_td3_10_seed{seed}.pt'
