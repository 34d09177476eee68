#!/usr/bin/env bash
# Accuracy of a change, judged on more than one run: replays a sequence in
# sequential (deterministic) mode with several ORB feature budgets, two at a
# time, and prints each ATE with their mean and median. Single runs of a
# feature-based SLAM move by +-0.003 m on small changes; compare sweeps.
#
# usage: daemon/scripts/ate-sweep.sh [SEQUENCE_DIR] [EXTRA_YAML]
#   SEQUENCE_DIR defaults to ../shared/data/tum_fr3_teddy_200 beside the repository;
#   EXTRA_YAML is appended to each run's config, e.g. $'mapping:\n  ba_max_keyframes: 30\n'.
#   ORB_EXTRA (environment) holds more `orb:` keys, as indented lines, e.g. $'  num_levels: 3\n'
#   (an `orb:` block in EXTRA_YAML would clash with the sweep's own).
#   BUDGETS (environment) replaces the six feature budgets, e.g. "1400 1450 1500 1550 1600 1650".
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
sequence=${1:-$repo/../shared/data/tum_fr3_teddy_200}
extra=${2:-}
orb_extra=${ORB_EXTRA:-}
replay=${REPLAY:-$repo/build/release/bin/stillpoint-replay}
[[ -x $replay ]] || { echo "ate-sweep: build first ($replay missing)" >&2; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

run() {
  local n=$1
  printf 'orb:\n  num_features: %s\n%s%s' "$n" "$orb_extra" "$extra" > "$work/$n.yaml"
  "$replay" "$sequence" --camera fr3 --sequential --config "$work/$n.yaml" --output "$work/$n.txt" 2>/dev/null \
    > "$work/$n.out" || true
  sed -n 's/.*ate_rmse_m=\([0-9.]*\).*/\1/p' "$work/$n.out" | head -n 1 > "$work/$n.ate"
  sed -n 's/.* lost=\([0-9]*\).*/\1/p' "$work/$n.out" | tail -n 1 > "$work/$n.lost"
}
export -f run
export replay sequence extra orb_extra work
budgets=${BUDGETS:-900 950 1000 1050 1100 1150}
printf '%s\n' $budgets | xargs -P 2 -I{} bash -c 'run {}'
cat "$work"/*.ate | sort -n | awk '{a[NR] = $1; s += $1}
  END {
    if (NR == 0) { print "ate-sweep: no run produced an ATE" > "/dev/stderr"; exit 1 }
    printf "ATE [m]:"; for (i = 1; i <= NR; ++i) printf " %.4f", a[i]
    printf "  mean %.4f  median %.4f  (%d runs)", s / NR, (a[int((NR + 1) / 2)] + a[int(NR / 2) + 1]) / 2, NR
  }'
# Lost frames are left out of the ATE: a run that lost half the sequence can
# score well on the rest, so the sweep reports them.
cat "$work"/*.lost | awk '{s += $1} END {printf "  lost frames %d\n", s}'
