#!/usr/bin/env bash
# Ships the seventh round (protocol in docs/training.md, "Seventh round"): for each model, the run
# among seeds 5-9 with the best validation score (`carl-sumo rank`, from the policy files'
# metadata only) becomes the shipped file <stem>.pt; the sixth round's seed-0 file becomes
# <stem>_seed0.pt. The rankings go to policies/round7_ranking.md. Run once, after
# policies/train_round7.sh; it refuses to run twice.
set -euo pipefail
cd "$(dirname "$0")/.."
STEMS="ca_td3_10 ca_ddpg_10 td3_1 ddpg_1 maddpg_10"
for stem in $STEMS; do
  if [ -e "policies/${stem}_seed0.pt" ]; then
    echo "policies/${stem}_seed0.pt exists: the seventh round is already shipped" >&2; exit 2
  fi
  for s in 5 6 7 8 9; do
    [ -e "policies/${stem}_seed$s.pt" ] || { echo "policies/${stem}_seed$s.pt is missing: run policies/train_round7.sh first" >&2; exit 2; }
  done
done
for stem in $STEMS; do  # the new runs are committed as they are, shipped or not
  for s in 5 6 7 8 9; do git add "policies/${stem}_seed$s.pt" "policies/${stem}_seed$s.csv"; done
done
move() {  # FROM_STEM TO_STEM: the policy, its learning curve and its checkpoint
  for ext in pt csv; do git mv "policies/$1.$ext" "policies/$2.$ext"; done
  if [ -e "policies/$1.ckpt" ]; then mv "policies/$1.ckpt" "policies/$2.ckpt"; fi
}
{
  echo "# Seventh round: the runs of seeds 5-9 ranked by validation score"
  echo
  echo "Written by \`bash policies/ship_round7.sh\` (\`carl-sumo rank --select margin\`); the first"
  echo "row of each table is the shipped run."
} > policies/round7_ranking.md
for stem in $STEMS; do
  files=$(for s in 5 6 7 8 9; do echo "policies/${stem}_seed$s.pt"; done)
  best=$(carl-sumo rank $files --best-only)
  { echo; echo "## \`$stem\`"; echo; carl-sumo rank $files; } >> policies/round7_ranking.md
  move "$stem" "${stem}_seed0"
  move "$(basename "$best" .pt)" "$stem"
  echo "$stem: shipped $(basename "$best") (now $stem.pt); seed 0 is now ${stem}_seed0.pt"
done
git add policies/round7_ranking.md
