#!/usr/bin/env bash
# Tracking time with the dynamic-object modules on against off, judged on more
# than one run: replays a sequence paced at its recorded rate (as a camera would
# deliver it, threads as in a live run) ROUNDS times per module set, interleaving
# the sets so a slow spell of the host hits all of them, and prints each set's
# per-run median tracking time (ORB included), the median over runs, and its
# ratio to 'none'. Wall-clock numbers on a shared host move by 30 % from run to
# run; compare only numbers from one invocation.
#
# usage: daemon/scripts/timing-ratio.sh [SEQUENCE_DIR] [ROUNDS] [SETS...]
#   SEQUENCE_DIR defaults to ../shared/data/tum_fr3_teddy_200, ROUNDS to 5, SETS to
#   none geometry semantic geometry,semantic. Semantic runs need the COCO model:
#   STILLPOINT_MODEL_DIR=../shared/models.
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
sequence=${1:-$repo/../shared/data/tum_fr3_teddy_200}
rounds=${2:-5}
shift $(( $# > 2 ? 2 : $# ))
sets=("$@")
(( ${#sets[@]} )) || sets=(none geometry semantic geometry,semantic)
replay=${REPLAY:-$repo/build/release/bin/stillpoint-replay}
[[ -x $replay ]] || { echo "timing-ratio: build first ($replay missing)" >&2; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

for ((r = 1; r <= rounds; ++r)); do
  for s in "${sets[@]}"; do
    "$replay" "$sequence" --camera fr3 --paced --modules "$s" --output "$work/traj.txt" 2>/dev/null |
      sed -n 's/.*track_ms_median=\([0-9.]*\).*/\1/p' | tail -n 1 >> "$work/${s//,/+}.ms"
  done
done
"$repo/daemon/scripts/run-medians.sh" "$work" "tracking median [ms]" "${sets[@]}"
