#!/usr/bin/env bash
# A real walking person: opencv-doc's vtest.avi walker, cut out frame by
# frame, composited into the real fr3 excerpt (`video-near` and `video-far` in
# docs/results.md). Deterministic replay; fails when fewer than
# MIN_POSED_PERCENT of the frames have a pose or the ATE RMSE over them exceeds
# MAX_ATE_M.
#
# near: 0.8 m from the camera (config/synth/teddy_video_walker.yaml), with the
#   geometry module. It covers over 85 % of the image in frames 42-47 while
#   the camera moves on: those frames have no pose, and the map started on the
#   static view the walker leaves must carry the frames after it.
# far: 2.2 m away (teddy_video_walker_far.yaml), with the semantic module
#   alone (COCO from MODELS_DIR), each keyframe's mask applied
#   MASK_DELAY_FRAMES late and keyframes at least KEYFRAME_SPACING frames apart,
#   as a live run on 2 cores makes them: the features of the walker that no
#   segmentation has seen yet must not steer the pose.
#
# usage: video_walker_test.sh REPLAY EVAL SYNTH SOURCE_DIR DATA_DIR OUT_DIR MAX_ATE_M MIN_POSED_PERCENT
#                             [far MODELS_DIR MASK_DELAY_FRAMES KEYFRAME_SPACING]
# exit:  0 pass, 1 fail, 77 skipped (excerpt, opencv-doc's vtest.avi or the model absent)
set -euo pipefail

if [[ $# -ne 8 && $# -ne 12 ]]; then
  echo "usage: $0 REPLAY EVAL SYNTH SOURCE_DIR DATA_DIR OUT_DIR MAX_ATE_M MIN_POSED_PERCENT" \
    "[far MODELS_DIR MASK_DELAY_FRAMES KEYFRAME_SPACING]" >&2
  exit 1
fi
replay=$1 eval=$2 synth=$3 source_dir=$4 data_dir=$5 out_dir=$6 max_ate=$7 min_posed=$8
walk=${9:-near}
excerpt=$data_dir/tum_fr3_teddy_200
needed=("$excerpt/rgb.txt")
case $walk in
  near)
    config=$source_dir/config/synth/teddy_video_walker.yaml
    ;;
  far)
    config=$source_dir/config/synth/teddy_video_walker_far.yaml
    models_dir=${10} mask_delay=${11} spacing=${12}
    needed+=("$models_dir/coco_yolov5s_seg_320.onnx")
    ;;
  *)
    echo "unknown walk '$walk' (far, or none for near)" >&2
    exit 1
    ;;
esac
video=$(sed -n 's/^ *video: *//p' "$config")
needed+=("$video")

for f in "${needed[@]}"; do
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

replay_args=(--modules geometry)
if [[ $walk == far ]]; then
  cat >"$out_dir/slam.yaml" <<YAML
semantic:
  model_dirs: [$models_dir]
  sequential_latency_frames: $mask_delay
YAML
  replay_args=(--modules semantic --config "$out_dir/slam.yaml" --keyframe-spacing "$spacing")
fi
MIN_POSED_PERCENT=$min_posed bash "$(dirname "$0")/replay_accuracy_test.sh" "$replay" "$eval" "$sequence" fr3 \
  "$out_dir/replay" "$max_ate" "${replay_args[@]}"
