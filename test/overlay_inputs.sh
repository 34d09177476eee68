# Sourced by the tests that make the overlays of docs/results.md: exits 77
# (skipped) unless the excerpt, the COCO model and Debian's opencv-doc (its
# footage and photos) are there. Needs $data_dir and $models_dir; sets
# $excerpt.
excerpt=$data_dir/tum_fr3_teddy_200
for needed in "$excerpt" "$models_dir/coco_yolov5s_seg_320.onnx" /usr/share/doc/opencv-doc/examples/data; do
  if [[ ! -e $needed ]]; then
    echo "SKIP: $needed is absent"
    exit 77
  fi
done
