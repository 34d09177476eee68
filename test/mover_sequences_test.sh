#!/usr/bin/env bash
# daemon/scripts/mover-sequences.sh makes every sequence a config/synth file's
# header names, with the flags that header gives: a person cut-out of the
# photo it names where it says --cutout, turned to face the camera exactly
# where it says --face-camera (a standee that turns would not stand still).
# Each sequence is made 2 frames long.
#
# usage: mover_sequences_test.sh SOURCE_DIR BIN_DIR DATA_DIR MODELS_DIR OUT_DIR
# exit:  0 pass, 1 fail, 77 skipped (excerpt, COCO model or opencv-doc absent)
set -euo pipefail

if [[ $# -ne 5 ]]; then
  echo "usage: $0 SOURCE_DIR BIN_DIR DATA_DIR MODELS_DIR OUT_DIR" >&2
  exit 2
fi
source_dir=$1 bin_dir=$2 data_dir=$3 models_dir=$4 out_dir=$5
source "$(dirname "$0")/overlay_inputs.sh"

rm -rf "$out_dir"
echo "+ mover-sequences.sh $out_dir (2 frames each)"
BIN=$bin_dir DATA=$excerpt MODELS=$models_dir SYNTH_ARGS="--max-frames 2" \
  bash "$source_dir/daemon/scripts/mover-sequences.sh" "$out_dir" >"$out_dir.log" 2>&1 || {
  cat "$out_dir.log"
  echo "FAIL: mover-sequences.sh failed"
  exit 1
}

fail=0
headers=0
for config in "$source_dir"/config/synth/teddy_*.yaml; do
  # The header's command: "stillpoint-synth overlay ... /tmp/seq/NAME ..." and
  # its continuation line.
  command=$(grep -A1 "stillpoint-synth overlay" "$config" | tr -d '#\\\n' || true)
  name=$(grep -o '/tmp/seq/[a-z-]*' <<<"$command" | head -n 1 | sed 's|/tmp/seq/||' || true)
  [[ -z $name ]] && continue
  headers=$((headers + 1))
  placed=$out_dir/$name/movers.yaml
  if [[ ! -f $placed ]]; then
    echo "FAIL: $(basename "$config") names $name, which the script did not make"
    fail=1
    continue
  fi
  frames=$(grep -vc '^#' "$out_dir/$name/rgb.txt" || true)
  [[ $frames -eq 2 ]] || { echo "FAIL: $name has $frames frames, expected 2"; fail=1; }
  grep -q "config/synth/$(basename "$config")" "$out_dir.log" ||
    { echo "FAIL: $name was not made from $(basename "$config")"; fail=1; }
  # The cut-out of the photo the header names.
  photo=$(grep -o '/tmp/cut/[a-z0-9]*_mask.png' <<<"$command" | sed 's|/tmp/cut/||; s|_mask.png||' || true)
  if [[ -n $photo ]] && ! grep -q "/$name --camera fr3 .*--cutout [^ ]*/cut/${photo}_mask.png" "$out_dir.log"; then
    echo "FAIL: $name was not cut out of the photo its header names ($photo)"
    fail=1
  fi
  for flag in cutout face_camera; do
    option=--${flag//_/-}
    said=0 made=0
    grep -q -- "$option" <<<"$command" && said=1
    grep -q "^ *$flag:" "$placed" && made=1
    if [[ $said -ne $made ]]; then
      echo "FAIL: $name: the header of $(basename "$config") $([[ $said -eq 1 ]] && echo gives || echo does not give) $option, the sequence $([[ $made -eq 1 ]] && echo has || echo lacks) it"
      fail=1
    fi
  done
done
echo "$headers config headers checked"
[[ $headers -ge 10 ]] || { echo "FAIL: only $headers config headers name a sequence"; fail=1; }
[[ $fail -eq 0 ]] && echo PASS
exit "$fail"
