#!/usr/bin/env bash
# A camera covered on its way back to where it started, with a mover in view:
# the `poster-walk` overlay of the real fr3 excerpt played forwards and then
# backwards, black with no depth for 2 s on both ways. The first cover starts
# a new map; after the second the camera is where the first map was made and
# must go on in it, not in a third map started with the walking poster in
# view. Deterministic replay with the geometry module; fails when a frame with
# depth has no pose or the ATE RMSE (each map aligned on its own) exceeds
# MAX_ATE_M.
#
# usage: covered_way_back_test.sh REPLAY EVAL SYNTH DATA_DIR OUT_DIR MAX_ATE_M
# exit:  0 pass, 1 fail, 77 skipped (excerpt absent)
set -euo pipefail

if [[ $# -ne 6 ]]; then
  echo "usage: $0 REPLAY EVAL SYNTH DATA_DIR OUT_DIR MAX_ATE_M" >&2
  exit 1
fi
replay=$1 eval=$2 synth=$3 data_dir=$4 out_dir=$5 max_ate=$6
excerpt=$data_dir/tum_fr3_teddy_200

if [[ ! -f $excerpt/rgb.txt ]]; then
  echo "SKIP: $excerpt not found"
  exit 77
fi

rm -rf "$out_dir"
mkdir -p "$out_dir"
echo "+ $synth overlay $excerpt $out_dir/poster-walk --camera fr3 --preset poster-walk"
"$synth" overlay "$excerpt" "$out_dir/poster-walk" --camera fr3 --preset poster-walk >"$out_dir/synth.txt"
sequence=$out_dir/covered-way-back
echo "+ $synth edit $out_dir/poster-walk $sequence --there-and-back --cover 2:2 --camera fr3"
"$synth" edit "$out_dir/poster-walk" "$sequence" --there-and-back --cover 2:2 --camera fr3 >>"$out_dir/synth.txt"

bash "$(dirname "$0")/replay_accuracy_test.sh" "$replay" "$eval" "$sequence" fr3 "$out_dir/replay" "$max_ate" \
  --modules geometry --log-level info
