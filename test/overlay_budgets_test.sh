#!/usr/bin/env bash
# One of the overlays of docs/results.md, judged as the docs judge a change:
# near the bar one ORB budget decides little (a replay is deterministic, but
# a small change moves a hard sequence either way at any one budget), so the
# overlay is replayed sequentially at each of an odd number of BUDGETs with
# MODULES (masks MASK_DELAY_FRAMES late), and fails when the median ATE
# exceeds MAX_MEDIAN_ATE_M or the median run leaves a frame without a pose.
#
# usage: overlay_budgets_test.sh SOURCE_DIR BIN_DIR DATA_DIR MODELS_DIR OUT_DIR NAME MAX_MEDIAN_ATE_M MODULES
#                                MASK_DELAY_FRAMES BUDGET...
# exit:  0 pass, 1 fail, 2 usage, 77 skipped (excerpt, COCO model or opencv-doc absent)
set -euo pipefail

if [[ $# -lt 10 || $(( ($# - 9) % 2 )) -ne 1 ]]; then
  echo "usage: $0 SOURCE_DIR BIN_DIR DATA_DIR MODELS_DIR OUT_DIR NAME MAX_MEDIAN_ATE_M MODULES MASK_DELAY_FRAMES BUDGET..." >&2
  echo "       (an odd number of budgets)" >&2
  exit 2
fi
source_dir=$1 bin_dir=$2 data_dir=$3 models_dir=$4 out_dir=$5 name=$6 max_ate=$7 modules=$8 mask_delay=$9
shift 9
budgets=("$@")
source "$(dirname "$0")/overlay_inputs.sh"

rm -rf "$out_dir"
mkdir -p "$out_dir"
echo "+ mover-sequences.sh $out_dir/seq $name"
BIN=$bin_dir DATA=$excerpt MODELS=$models_dir bash "$source_dir/daemon/scripts/mover-sequences.sh" "$out_dir/seq" "$name"
sequence=$out_dir/seq/$name

ates=() posed=() frames=
for budget in "${budgets[@]}"; do
  run=$out_dir/$budget
  mkdir -p "$run"
  cat >"$run/slam.yaml" <<YAML
orb:
  num_features: $budget
semantic:
  model_dirs: [$models_dir]
  sequential_latency_frames: $mask_delay
YAML
  echo "+ stillpoint-replay $sequence --sequential --modules $modules (orb.num_features $budget)"
  if ! "$bin_dir/stillpoint-replay" "$sequence" --camera fr3 --sequential --modules "$modules" --config "$run/slam.yaml" \
      --output "$run/traj.txt" >"$run/summary.txt" 2>"$run/log.txt"; then
    cat "$run/log.txt" "$run/summary.txt"
    echo "FAIL: stillpoint-replay exited with an error at $budget features"
    exit 1
  fi
  last=$(tail -n 1 "$run/summary.txt")
  n=$(sed -n 's/^frames=\([0-9][0-9]*\).*/\1/p' <<<"$last")
  tracked=$(sed -n 's/.*\<tracked=\([0-9][0-9]*\).*/\1/p' <<<"$last")
  metrics=$("$bin_dir/stillpoint-eval" "$sequence/groundtruth.txt" "$run/traj.txt")
  ate=$(sed -n 's/^ate_rmse_m=\([^ ]*\) .*/\1/p' <<<"$metrics")
  if [[ -z $n || -z $tracked || -z $ate ]] || ! awk -v a="$ate" 'BEGIN { exit !(a + 0 == a) }'; then
    echo "FAIL: cannot read the run at $budget features: '$last' / '$metrics'"
    exit 1
  fi
  frames=$n
  echo "  $budget features: ATE RMSE $ate m, $tracked of $n frames with a pose"
  ates+=("$ate")
  posed+=("$tracked")
done

middle=$(( ${#budgets[@]} / 2 ))
median_ate=$(printf '%s\n' "${ates[@]}" | sort -g | sed -n "$((middle + 1))p")
median_posed=$(printf '%s\n' "${posed[@]}" | sort -n | sed -n "$((middle + 1))p")
echo "measured: median ATE RMSE $median_ate m (limit $max_ate m), median $median_posed of $frames frames with a pose (limit all)"
status=0
if [[ $median_posed -lt $frames ]]; then
  echo "FAIL: the median run leaves $((frames - median_posed)) frame(s) without a pose"
  status=1
fi
if ! awk -v a="$median_ate" -v m="$max_ate" 'BEGIN { exit !(a <= m) }'; then
  echo "FAIL: median ATE RMSE $median_ate m exceeds $max_ate m"
  status=1
fi
[[ $status -eq 0 ]] && echo "PASS"
exit $status
