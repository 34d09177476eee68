#!/usr/bin/env bash
# Prints, per module set, the per-run medians a timing script collected, their
# median and its ratio to the first set's. Shared by timing-ratio.sh and
# daemon-measure.sh (timing).
#
# usage: run-medians.sh WORK_DIR LABEL SET...
#   WORK_DIR holds one file per set, "<set with , as +>.ms", one number per run.
set -euo pipefail
work=$1 label=$2
shift 2
base=
for s in "$@"; do
  touch "$work/${s//,/+}.ms"  # no run finished: said below
  sort -n "$work/${s//,/+}.ms" | awk -v name="$s" -v base="$base" -v label="$label" -v out="$work/median" '
    {a[NR] = $1}
    END {
      if (NR == 0) { printf "%-18s no run finished\n", name; exit }
      m = (a[int((NR + 1) / 2)] + a[int(NR / 2) + 1]) / 2
      printf "%-18s %s per run:", name, label
      for (i = 1; i <= NR; ++i) printf " %.2f", a[i]
      printf "  median %.2f", m
      if (base != "") printf "  ratio %.2f", m / base
      printf "\n"
      print m > out
    }'
  [[ -n $base || ! -s $work/median ]] || base=$(cat "$work/median")
done
