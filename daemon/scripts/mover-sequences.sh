#!/usr/bin/env bash
# Makes the generated sequences of docs/results.md: movers composited into the
# real excerpt (stillpoint-synth overlay), each from its preset or its file in
# config/synth/, with the flags that file's header names. The people are
# photos cut out along the silhouette COCO finds in them: the astronaut of
# the models' test data, and the basketball players and the footballer of
# Debian's opencv-doc, which also gives the real walker and the graffiti
# poster.
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

# name  source  photo of the cut-out person  turns to face the camera
table="\
poster-walk      preset:poster-walk                       -           -
mix              preset:mix                               -           -
person-near      teddy_person_near.yaml                   astronaut   face
person-huge      teddy_person_huge.yaml                   astronaut   face
person-walking   teddy_person_huge_walking.yaml           astronaut   face
person-cover     teddy_person_cover.yaml                  astronaut   face
behind-bear      teddy_person_behind_bear.yaml            astronaut   face
two-people       teddy_two_people.yaml                    astronaut   face
stand-walk       teddy_person_stand_walk.yaml             astronaut   -
standee-walk     teddy_person_standee.yaml                astronaut   -
poster-close     teddy_poster_close.yaml                  -           -
poster-hold      teddy_poster_hold.yaml                   -           -
video-near       teddy_video_walker.yaml                  -           face
video-far        teddy_video_walker_far.yaml              -           face
walker-mid       teddy_video_walker_mid.yaml              -           face
player-walk      teddy_player_walk.yaml                   basketball1 face
player-near      teddy_player_near.yaml                   basketball1 face
kicker           teddy_kicker.yaml                        messi5      face"

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

# The cut-out of a photo (astronaut: the models' test data; the others:
# opencv-doc), made once: OUT_DIR/cut/PHOTO_mask.png.
cutout_of() {
  local photo=$1 image
  cutout=$out/cut/${photo}_mask.png
  [[ -f $cutout ]] && return 0
  if [[ ! -d $models ]]; then
    echo "$0: the models folder $models is absent (set MODELS): no person cut-out" >&2
    return 1
  fi
  case $photo in
    astronaut) image=$models/testdata/astronaut.png ;;
    *) for image in "$opencv_data/$photo".*; do break; done ;;
  esac
  if [[ ! -f $image ]]; then
    echo "$0: the photo '$photo' is absent (the models' test data, or Debian's opencv-doc)" >&2
    return 1
  fi
  if ! "$bin/stillpoint-segment" --card "$repo/models/coco_yolov5s_seg_320.yaml" --model-dir "$models" \
    --out "$out/cut" "$image" >/dev/null 2>"$out/cut.err" || [[ ! -f $cutout ]]; then
    cat "$out/cut.err" >&2
    echo "$0: no person cut-out of $photo" >&2
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
  read -r _ source photo face <<<"$row"
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
  if [[ $photo != - ]]; then
    if ! cutout_of "$photo"; then
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
