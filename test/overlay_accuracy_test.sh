#!/usr/bin/env bash
# One of the overlays of docs/results.md, made by
# daemon/scripts/mover-sequences.sh as the tables are, replayed sequentially
# with MODULES (masks MASK_DELAY_FRAMES late, as a live run's segmentation
# comes; semantic.sequential_latency_frames) at FEATURES ORB features; fails
# above MAX_ATE_M or on any lost frame (replay_accuracy_test.sh).
#
# usage: overlay_accuracy_test.sh SOURCE_DIR BIN_DIR DATA_DIR MODELS_DIR OUT_DIR NAME MAX_ATE_M MODULES
#                                 FEATURES MASK_DELAY_FRAMES
# exit:  0 pass, 1 fail, 77 skipped (excerpt, COCO model or opencv-doc absent)
set -euo pipefail

if [[ $# -ne 10 ]]; then
  echo "usage: $0 SOURCE_DIR BIN_DIR DATA_DIR MODELS_DIR OUT_DIR NAME MAX_ATE_M MODULES FEATURES MASK_DELAY_FRAMES" >&2
  exit 2
fi
source_dir=$1 bin_dir=$2 data_dir=$3 models_dir=$4 out_dir=$5 name=$6 max_ate=$7 modules=$8 features=$9
mask_delay=${10}
source "$(dirname "$0")/overlay_inputs.sh"

rm -rf "$out_dir"
mkdir -p "$out_dir"
echo "+ mover-sequences.sh $out_dir/seq $name"
BIN=$bin_dir DATA=$excerpt MODELS=$models_dir bash "$source_dir/daemon/scripts/mover-sequences.sh" "$out_dir/seq" "$name"
cat >"$out_dir/slam.yaml" <<YAML
orb:
  num_features: $features
semantic:
  model_dirs: [$models_dir]
  sequential_latency_frames: $mask_delay
YAML
bash "$(dirname "$0")/replay_accuracy_test.sh" "$bin_dir/stillpoint-replay" "$bin_dir/stillpoint-eval" "$out_dir/seq/$name" fr3 \
  "$out_dir/replay" "$max_ate" --modules "$modules" --config "$out_dir/slam.yaml"
