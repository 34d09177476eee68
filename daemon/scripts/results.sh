#!/usr/bin/env bash
# The accuracy table of docs/results.md, reproduced: generates the dynamic
# sequences, replays each (and the real excerpt) sequentially over a sweep of
# ORB budgets with the geometry module on and off, and prints a Markdown
# table with the mean and median ATE and the share of frames with a pose.
#
# usage: daemon/scripts/results.sh [WORK_DIR]
#   WORK_DIR (default: a temporary folder) keeps the sequences and runs.
#   BUDGETS (environment) replaces the twelve budgets 800..1350.
#   SEQUENCES (environment) picks rows, e.g. "teddy poster-walk".
# About 15 minutes on two cores.
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
bin=${BIN:-$repo/build/release/bin}
teddy=$repo/../shared/data/tum_fr3_teddy_200
[[ -x $bin/stillpoint-replay && -x $bin/stillpoint-synth ]] || { echo "results: build first ($bin)" >&2; exit 1; }
[[ -d $teddy ]] || { echo "results: $teddy missing" >&2; exit 1; }
work=${1:-$(mktemp -d)}
mkdir -p "$work/seq" "$work/runs"
budgets=${BUDGETS:-$(seq -s ' ' 800 50 1350)}
sequences=${SEQUENCES:-teddy poster-walk mix room-xyz room-rpy room-halfsphere}

path_of() {
  case $1 in
    teddy) echo "$teddy" ;;
    *) echo "$work/seq/$1" ;;
  esac
}
generate() {
  local name=$1 out=$work/seq/$1
  [[ -d $out ]] && return 0
  case $name in
    teddy) ;;
    poster-walk | mix) "$bin/stillpoint-synth" overlay "$teddy" "$out" --camera fr3 --preset "$name" > /dev/null ;;
    room-*) "$bin/stillpoint-synth" room "$out" --preset room-walker --motion "${name#room-}" > /dev/null ;;
  esac
}
for s in $sequences; do generate "$s"; done

# One replay: sequence, modules, budget -> "<ate> <frames> <tracked>" in a file.
run() {
  local s=$1 m=$2 n=$3 dir=$work/runs/$1.$2.$3
  mkdir -p "$dir"
  printf 'orb:\n  num_features: %s\n' "$n" > "$dir/c.yaml"
  "$bin/stillpoint-replay" "$(path_of "$s")" --camera fr3 --sequential --modules "$m" --config "$dir/c.yaml" \
      --output "$dir/traj.txt" > "$dir/out.txt" 2> "$dir/err.txt" || true
  local ate frames tracked
  ate=$(sed -n 's/.*ate_rmse_m=\([0-9.]*\).*/\1/p' "$dir/out.txt" | head -n 1)
  frames=$(sed -n 's/^frames=\([0-9]*\) tracked=\([0-9]*\).*/\1/p' "$dir/out.txt" | tail -n 1)
  tracked=$(sed -n 's/^frames=\([0-9]*\) tracked=\([0-9]*\).*/\2/p' "$dir/out.txt" | tail -n 1)
  echo "${ate:-nan} ${frames:-0} ${tracked:-0}" > "$dir/result"
}
export -f run path_of
export bin work teddy
for s in $sequences; do
  for m in geometry none; do
    for n in $budgets; do echo "$s $m $n"; done
  done
done | xargs -P 2 -L 1 bash -c 'run "$@"' _

echo "| sequence | modules | runs | ATE mean [m] | ATE median [m] | frames with a pose |"
echo "|---|---|---|---|---|---|"
for s in $sequences; do
  for m in geometry none; do
    cat "$work"/runs/"$s.$m".*/result | sort -n | awk -v s="$s" -v m="$m" '
      {a[NR] = $1; sum += $1; frames += $2; tracked += $3}
      END {
        med = (a[int((NR + 1) / 2)] + a[int(NR / 2) + 1]) / 2
        printf "| %s | %s | %d | %.4f | %.4f | %d / %d (%.1f %%) |\n", s, m, NR, sum / NR, med, tracked, frames,
               frames ? 100 * tracked / frames : 0
      }'
  done
done
echo "work folder: $work" >&2
