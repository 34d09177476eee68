#!/usr/bin/env bash
# One command from a fresh Debian bookworm checkout to a measured trajectory:
# installs the build dependencies (apt, via sudo when not root), builds the
# release preset, replays the bundled real TUM sequence deterministically and
# prints the replay summary and stillpoint-eval's ATE/RPE line.
#
# usage: daemon/scripts/replay-teddy.sh [SEQUENCE_DIR]
#   SEQUENCE_DIR defaults to ../shared/data/tum_fr3_teddy_200 beside the repository.
# Set SKIP_DEPS=1 to skip the apt step on a machine that already has the packages.
set -euo pipefail

repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
sequence=${1:-$repo/../shared/data/tum_fr3_teddy_200}
cd "$repo"

if [[ ! -f $sequence/rgb.txt ]]; then
  echo "replay-teddy: no TUM sequence at $sequence (expected rgb.txt, depth.txt, rgb/, depth/)" >&2
  exit 1
fi

if [[ ${SKIP_DEPS:-0} != 1 ]]; then
  bash .ci/install-deps
fi
cmake --preset release
cmake --build --preset release -j2

out=build/release/replay-teddy
mkdir -p "$out"
echo
echo "== stillpoint-replay $sequence --camera fr3 --sequential"
build/release/bin/stillpoint-replay "$sequence" --camera fr3 --output "$out/traj.txt" --sequential
if [[ -f $sequence/groundtruth.txt ]]; then
  echo
  echo "== stillpoint-eval (trajectory: $out/traj.txt, plot: $out/traj.png)"
  build/release/bin/stillpoint-eval "$sequence/groundtruth.txt" "$out/traj.txt" --plot "$out/traj.png"
fi
