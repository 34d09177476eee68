#!/usr/bin/env bash
# Real-sequence regression: replays a TUM sequence deterministically, evaluates
# the trajectory with stillpoint-eval and fails when the absolute trajectory
# error exceeds MAX_ATE_M or any frame was lost (with MIN_POSED_PERCENT set in
# the environment: when fewer than that share of the frames have a pose).
# Prints what it measured.
#
# usage: replay_accuracy_test.sh REPLAY EVAL SEQUENCE_DIR CAMERA OUT_DIR MAX_ATE_M [REPLAY_ARG...]
# exit:  0 pass, 1 fail, 77 skipped (sequence absent)
set -euo pipefail

if [[ $# -lt 6 ]]; then
  echo "usage: $0 REPLAY EVAL SEQUENCE_DIR CAMERA OUT_DIR MAX_ATE_M [REPLAY_ARG...]" >&2
  exit 1
fi
replay=$1 eval=$2 sequence=$3 camera=$4 out_dir=$5 max_ate=$6
shift 6

if [[ ! -f $sequence/rgb.txt || ! -f $sequence/groundtruth.txt ]]; then
  echo "SKIP: sequence $sequence not found (set STILLPOINT_DATA_DIR to the folder holding it)"
  exit 77
fi

mkdir -p "$out_dir"
traj=$out_dir/traj.txt
summary=$out_dir/replay_summary.txt
rm -f "$traj" "$summary"

echo "+ $replay $sequence --camera $camera --output $traj --sequential $*"
rc=0
"$replay" "$sequence" --camera "$camera" --output "$traj" --sequential "$@" >"$summary" || rc=$?
cat "$summary"
if [[ $rc -ne 0 ]]; then
  echo "FAIL: stillpoint-replay exited with status $rc"
  exit 1
fi

# Last line: frames=<n> tracked=<n> lost=<n> keyframes=<n> ...
last=$(tail -n 1 "$summary")
lost=$(sed -n 's/.*\<lost=\([0-9][0-9]*\).*/\1/p' <<<"$last")
frames=$(sed -n 's/^frames=\([0-9][0-9]*\).*/\1/p' <<<"$last")
tracked=$(sed -n 's/.*\<tracked=\([0-9][0-9]*\).*/\1/p' <<<"$last")
if [[ -z $lost || -z $frames || -z $tracked ]]; then
  echo "FAIL: cannot read frames=/tracked=/lost= from the replay's last line: '$last'"
  exit 1
fi

echo "+ $eval $sequence/groundtruth.txt $traj"
rc=0
metrics=$("$eval" "$sequence/groundtruth.txt" "$traj") || rc=$?
if [[ $rc -ne 0 ]]; then
  echo "FAIL: stillpoint-eval exited with status $rc"
  exit 1
fi
echo "$metrics"
ate=$(sed -n 's/^ate_rmse_m=\([^ ]*\) .*/\1/p' <<<"$metrics")
if [[ -z $ate ]]; then
  echo "FAIL: cannot read ate_rmse_m= from stillpoint-eval output"
  exit 1
fi

status=0
if [[ -n ${MIN_POSED_PERCENT:-} ]]; then
  echo "measured: ATE RMSE $ate m (limit $max_ate m), $tracked of $frames frames with a pose (limit $MIN_POSED_PERCENT %)"
  if [[ $((tracked * 100)) -lt $((MIN_POSED_PERCENT * frames)) ]]; then
    echo "FAIL: $tracked of $frames frames with a pose, under $MIN_POSED_PERCENT %"
    status=1
  fi
else
  echo "measured: ATE RMSE $ate m (limit $max_ate m), $lost of $frames frames lost (limit 0)"
  if [[ $lost -gt 0 ]]; then
    echo "FAIL: $lost frame(s) lost"
    status=1
  fi
fi
# awk treats nan as a string that fails the numeric test below, so it fails too.
if ! awk -v a="$ate" -v m="$max_ate" 'BEGIN { exit !(a + 0 == a && a <= m) }'; then
  echo "FAIL: ATE RMSE $ate m exceeds $max_ate m"
  status=1
fi
[[ $status -eq 0 ]] && echo "PASS"
exit $status
