#!/usr/bin/env bash
# A real walking person that covers the view: opencv-doc's vtest.avi walker,
# cut out frame by frame, composited 0.8 m from the camera into the real fr3
# excerpt (config/synth/teddy_video_walker.yaml, `video-near` in
# docs/results.md). It covers over 85 % of the image in frames 42-47 while the
# camera moves on: those frames have no pose, and the map started on the
# static view the walker leaves must carry the frames after it. Deterministic
# replay with the geometry module; fails when fewer than MIN_POSED_PERCENT of
# the frames have a pose or the ATE RMSE over them exceeds MAX_ATE_M.
#
# usage: video_walker_test.sh REPLAY EVAL SYNTH SOURCE_DIR DATA_DIR OUT_DIR MAX_ATE_M MIN_POSED_PERCENT
# exit:  0 pass, 1 fail, 77 skipped (excerpt or opencv-doc's vtest.avi absent)
set -euo pipefail

if [[ $# -ne 8 ]]; then
  echo "usage: $0 REPLAY EVAL SYNTH SOURCE_DIR DATA_DIR OUT_DIR MAX_ATE_M MIN_POSED_PERCENT" >&2
  exit 1
fi
replay=$1 eval=$2 synth=$3 source_dir=$4 data_dir=$5 out_dir=$6 max_ate=$7 min_posed=$8
excerpt=$data_dir/tum_fr3_teddy_200
config=$source_dir/config/synth/teddy_video_walker.yaml
video=$(sed -n 's/^ *video: *//p' "$config")

for f in "$excerpt/rgb.txt" "$video"; do
  if [[ ! -f $f ]]; then
    echo "SKIP: $f not found"
    exit 77
  fi
done

rm -rf "$out_dir"
mkdir -p "$out_dir"
sequence=$out_dir/sequence
echo "+ $synth overlay $excerpt $sequence --camera fr3 --config $config --face-camera"
"$synth" overlay "$excerpt" "$sequence" --camera fr3 --config "$config" --face-camera >"$out_dir/synth.txt"

MIN_POSED_PERCENT=$min_posed bash "$(dirname "$0")/replay_accuracy_test.sh" "$replay" "$eval" "$sequence" fr3 \
  "$out_dir/replay" "$max_ate" --modules geometry
