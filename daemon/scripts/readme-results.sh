#!/usr/bin/env bash
# Copies the accuracy table of a stillpoint-bench report (the lines between
# "<!-- bench-summary: begin -->" and "<!-- bench-summary: end -->") into
# README.md between the same markers. With --check it changes nothing and
# fails when the README's table differs from the report's.
#
# usage: daemon/scripts/readme-results.sh [--check] [REPORT] [README]
#   REPORT defaults to docs/bench/report.md, README to README.md.
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
check=0
if [[ ${1:-} == --check ]]; then check=1; shift; fi
report=${1:-$repo/docs/bench/report.md}
readme=${2:-$repo/README.md}
begin='<!-- bench-summary: begin -->'
end='<!-- bench-summary: end -->'

block() {  # the marked block of $1, markers included; fails when absent or unterminated
  awk -v b="$begin" -v e="$end" '
    $0 == b { inside = 1; found++ }
    inside { print }
    $0 == e && inside { inside = 0; closed++ }
    END { if (found != 1 || closed != 1) exit 1 }' "$1"
}

table=$(block "$report") || { echo "readme-results: $report has no single bench-summary block" >&2; exit 1; }
current=$(block "$readme") || { echo "readme-results: $readme has no single bench-summary block" >&2; exit 1; }
if [[ $check -eq 1 ]]; then
  if [[ "$table" == "$current" ]]; then
    echo "readme-results: $readme matches $report"
    exit 0
  fi
  echo "readme-results: $readme's results table differs from $report (run daemon/scripts/readme-results.sh):" >&2
  diff <(echo "$current") <(echo "$table") >&2 || true
  exit 1
fi
tmp=$(mktemp)
trap 'rm -f "$tmp"' EXIT
awk -v b="$begin" -v e="$end" -v table_file=<(echo "$table") '
  $0 == b { while ((getline line < table_file) > 0) print line; skip = 1; next }
  skip && $0 == e { skip = 0; next }
  !skip { print }' "$readme" > "$tmp"
cat "$tmp" > "$readme"
echo "readme-results: $readme updated from $report"
