#!/usr/bin/env bash
# Ships a pre-registered round (protocols in docs/training.md): for each model, the run among
# the round's fresh seeds with the best validation score (`carl-sumo rank`, from the policy files'
# metadata only) becomes the shipped file <stem>.pt, and the file shipped until now goes back to
# <stem>_seed<K>.pt (K read from its metadata). The rankings go to policies/round<ROUND>_ranking.md.
# Run once, after the round's training; it refuses to run twice.
# Usage: bash policies/ship_best.sh ROUND "SEED SEED ..."
set -euo pipefail
cd "$(dirname "$0")/.."
ROUND=$1 SEEDS=$2
STEMS="ca_td3_10 ca_ddpg_10 td3_1 ddpg_1 maddpg_10"
seed_of() {  # the seed a policy file was trained with
  python -c "import sys; from carl_sumo.policy import read_policy_payload as r; print(r(sys.argv[1])['metadata']['seed'])" "$1"
}
for stem in $STEMS; do
  current=$(seed_of "policies/$stem.pt")
  for s in $SEEDS; do
    if [ "$current" = "$s" ]; then
      echo "policies/$stem.pt is seed $s: round $ROUND is already shipped" >&2; exit 2
    fi
    [ -e "policies/${stem}_seed$s.pt" ] || { echo "policies/${stem}_seed$s.pt is missing: run policies/train_round$ROUND.sh first" >&2; exit 2; }
  done
  if [ -e "policies/${stem}_seed$current.pt" ]; then
    echo "policies/${stem}_seed$current.pt exists beside policies/$stem.pt (seed $current): resolve that first" >&2; exit 2
  fi
done
for stem in $STEMS; do  # the new runs are committed as they are, shipped or not
  for s in $SEEDS; do git add "policies/${stem}_seed$s.pt" "policies/${stem}_seed$s.csv"; done
done
move() {  # FROM_STEM TO_STEM: the policy, its learning curve and its checkpoint
  for ext in pt csv; do git mv "policies/$1.$ext" "policies/$2.$ext"; done
  if [ -e "policies/$1.ckpt" ]; then mv "policies/$1.ckpt" "policies/$2.ckpt"; fi
}
first=${SEEDS%% *} last=${SEEDS##* }
ranking=policies/round${ROUND}_ranking.md
{
  echo "# Round $ROUND: the runs of seeds $first-$last ranked by validation score"
  echo
  echo "Written by \`bash policies/ship_round$ROUND.sh\` (\`carl-sumo rank --select margin\`); the first"
  echo "row of each table is the shipped run."
} > "$ranking"
for stem in $STEMS; do
  files=$(for s in $SEEDS; do echo "policies/${stem}_seed$s.pt"; done)
  best=$(carl-sumo rank $files --best-only)
  current=$(seed_of "policies/$stem.pt")
  { echo; echo "## \`$stem\`"; echo; carl-sumo rank $files; } >> "$ranking"
  move "$stem" "${stem}_seed$current"
  move "$(basename "$best" .pt)" "$stem"
  echo "$stem: shipped $(basename "$best") (now $stem.pt); seed $current is now ${stem}_seed$current.pt"
done
git add "$ranking"
