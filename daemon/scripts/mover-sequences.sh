#!/usr/bin/env bash
# Makes the generated sequences of docs/results.md: movers composited into the
# real excerpt (stillpoint-synth overlay), each from its preset or its file in
# config/synth/, with the flags that file's header names. The people are the
# astronaut photo cut out along the silhouette COCO finds in it; the real
# walker and the graffiti poster come from Debian's opencv-doc.
#
# usage: daemon/scripts/mover-sequences.sh OUT_DIR [NAME...]
#        daemon/scripts/mover-sequences.sh --list
#   Makes OUT_DIR/NAME for every NAME given (default: all of --list).
#   BIN (environment) holds stillpoint-synth and stillpoint-segment
#   (default build/release/bin); DATA the excerpt (default
#   ../shared/data/tum_fr3_teddy_200 beside the repository); MODELS the
#   segmentation models (default ../shared/models); SYNTH_ARGS more
#   stillpoint-synth flags, e.g. "--max-frames 30".
# exit:  0 every sequence made, 1 one failed or needs what is absent, 2 usage
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)

# name  source  cut-out person  turns to face the camera
table="\
poster-walk      preset:poster-walk                       -      -
mix              preset:mix                               -      -
person-near      teddy_person_near.yaml                   person face
person-huge      teddy_person_huge.yaml                   person face
person-walking   teddy_person_huge_walking.yaml           person face
person-cover     teddy_person_cover.yaml                  person face
behind-bear      teddy_person_behind_bear.yaml            person face
two-people       teddy_two_people.yaml                    person face
stand-walk       teddy_person_stand_walk.yaml             person -
standee-walk     teddy_person_standee.yaml                person -
poster-close     teddy_poster_close.yaml                  -      -
poster-hold      teddy_poster_hold.yaml                   -      -
video-near       teddy_video_walker.yaml                  -      face
video-far        teddy_video_walker_far.yaml              -      face
walker-mid       teddy_video_walker_mid.yaml              -      face"

if [[ ${1:-} == --list ]]; then
  awk '{print $1}' <<<"$table"
  exit 0
fi
if [[ $# -lt 1 || $1 == -* ]]; then
  echo "usage: $0 OUT_DIR [NAME...] | --list" >&2
  exit 2
fi
out=$1
shift
names=("$@")
if [[ ${#names[@]} -eq 0 ]]; then
  mapfile -t names < <(awk '{print $1}' <<<"$table")
fi

bin=${BIN:-$repo/build/release/bin}
data=${DATA:-$repo/../shared/data/tum_fr3_teddy_200}
models=${MODELS:-$repo/../shared/models}
read -r -a synth_args <<<"${SYNTH_ARGS:-}"
opencv_data=/usr/share/doc/opencv-doc/examples/data
for tool in stillpoint-synth stillpoint-segment; do
  if [[ ! -x $bin/$tool ]]; then
    echo "$0: $bin/$tool not found (build first, or set BIN)" >&2
    exit 1
  fi
done
if [[ ! -d $data ]]; then
  echo "$0: the excerpt $data is absent (set DATA)" >&2
  exit 1
fi
mkdir -p "$out"

cutout=$out/cut/astronaut_mask.png
make_cutout() {
  [[ -f $cutout ]] && return 0
  if [[ ! -d $models ]]; then
    echo "$0: the models folder $models is absent (set MODELS): no person cut-out" >&2
    return 1
  fi
  if ! "$bin/stillpoint-segment" --card "$repo/models/coco_yolov5s_seg_320.yaml" --model-dir "$models" \
    --out "$out/cut" "$models/testdata/astronaut.png" >/dev/null 2>"$out/cut.err" || [[ ! -f $cutout ]]; then
    cat "$out/cut.err" >&2
    echo "$0: no person cut-out" >&2
    return 1
  fi
  rm -f "$out/cut.err"
}

failed=0
for name in "${names[@]}"; do
  row=$(awk -v n="$name" '$1 == n' <<<"$table")
  if [[ -z $row ]]; then
    echo "$0: no sequence '$name' (see --list)" >&2
    failed=1
    continue
  fi
  read -r _ source person face <<<"$row"
  args=(overlay "$data" "$out/$name" --camera fr3)
  if [[ $source == preset:* ]]; then
    args+=(--preset "${source#preset:}")
  else
    args+=(--config "$repo/config/synth/$source")
    if grep -q "opencv-doc" "$repo/config/synth/$source" && [[ ! -d $opencv_data ]]; then
      echo "$0: $name needs Debian's opencv-doc ($opencv_data)" >&2
      failed=1
      continue
    fi
  fi
  if [[ $person == person ]]; then
    if ! make_cutout; then
      failed=1
      continue
    fi
    args+=(--cutout "$cutout")
  fi
  [[ $face == face ]] && args+=(--face-camera)
  echo "+ stillpoint-synth ${args[*]} ${synth_args[*]}"
  if ! "$bin/stillpoint-synth" "${args[@]}" "${synth_args[@]}" 2>"$out/$name.err" | tail -n 1; then
    cat "$out/$name.err" >&2
    echo "$0: $name failed" >&2
    failed=1
  fi
  rm -f "$out/$name.err"
done
exit "$failed"
