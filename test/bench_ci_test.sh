#!/usr/bin/env bash
# The CI-sized bench: the real excerpt and one generated dynamic sequence,
# every module set, one sequential run each. Fails on a crashed run or a
# malformed report, never on a number. When evo (PyPI) is installed, every
# run's ATE must agree with evo_ape's to 1e-4 m.
# usage: bench_ci_test.sh BENCH SYNTH DATA_DIR WORK_DIR [MAX_FRAMES]
# Skips (77) when DATA_DIR lacks the real excerpt.
set -uo pipefail
bench=$1 synth=$2 data=$3 work=$4 max_frames=${5:-90}
teddy=$data/tum_fr3_teddy_200
[[ -d $teddy ]] || { echo "SKIP: $teddy not found"; exit 77; }
fail() { echo "FAIL: $*"; exit 1; }
rm -rf "$work" && mkdir -p "$work"
"$synth" overlay "$teddy" "$work/poster-walk" --camera fr3 --preset poster-walk --max-frames "$max_frames" \
  > "$work/synth.log" 2>&1 || fail "stillpoint-synth: $(tail -n 3 "$work/synth.log")"
out=$work/out
"$bench" --sequence "$teddy:fr3" --sequence "$work/poster-walk:fr3" --sequence "$work/absent:fr3" \
  --modules none,geometry,semantic,geometry+semantic --runs 1 --sequential --max-frames "$max_frames" \
  --render-every 45 --out "$out" > "$work/bench.out" 2> "$work/bench.err" \
  || fail "stillpoint-bench exited $?: $(tail -n 3 "$work/bench.err")"
report=$out/report.md csv=$out/results.csv
for f in "$report" "$csv"; do [[ -s $f ]] || fail "$f missing or empty"; done
grep -qx '<!-- bench-summary: begin -->' "$report" && grep -qx '<!-- bench-summary: end -->' "$report" \
  || fail "report without the summary markers"
for section in '## Accuracy' '## Pose health' '## What lowered the pose health' \
    '## How well the pose covariance covers the drift' '## Runtime' '## Published figures' '## Plots'; do
  grep -qx "$section.*" "$report" || fail "report without '$section'"
done
grep -Eq '^\| host speed: ORB extraction[^|]*\| at start [0-9]+\.[0-9] ms; at end [0-9]+\.[0-9] ms \|$' "$report" \
  || fail "report without the host speed measured at start and end"
rows=$(awk '/<!-- bench-summary: begin -->/{f=1;next} /<!-- bench-summary: end -->/{f=0} f && /^\| `/' "$report" | wc -l)
[[ $rows -eq 12 ]] || fail "accuracy table has $rows rows, expected 12 (3 sequences x 4 module sets)"
# Every pose has a health level (good, degraded, unreliable: a '-' would be a
# pose the frame log does not have), and every module set has a row.
health_rows=$(awk '/^## Pose health/{f=1;next} /^## /{f=0} f && /^\| [a-z+]+ \| /' "$report")
for m in none geometry semantic geometry+semantic; do
  grep -q "^| $m | " <<< "$health_rows" || fail "pose health table without a row for $m"
done
odd=$(grep -Ev '^\| [a-z+]+ \| (good|degraded|unreliable) \| [0-9]+ \| [0-9.]+ \| [0-9.]+ \| [0-9.]+ \| [0-9.]+ % \|$' <<< "$health_rows")
[[ -z $odd ]] || fail "pose health rows not of a level with its numbers: $odd"
# The same poses by cause: known cause names only, and a module set's poses
# without a cause are exactly its good ones.
cause_rows=$(awk '/^## What lowered the pose health/{f=1;next} /^## /{f=0} f && /^\| [a-z+]+ \| /' "$report")
cause_names='none|few_inliers|view_moving|poor_conditioning|high_reprojection|fallback_evidence|masks_late|recovering'
odd=$(grep -Ev "^\| [a-z+]+ \| ($cause_names) \| [0-9]+ \| [0-9.]+ \| [0-9.]+ \| [0-9.]+ \| [0-9.]+ % \|\$" <<< "$cause_rows")
[[ -z $odd ]] || fail "health cause rows not of a cause with its numbers: $odd"
for m in none geometry semantic geometry+semantic; do
  good=$(awk -F'|' -v m=" $m " '$2 == m && $3 == " good " {print $4 + 0}' <<< "$health_rows")
  none=$(awk -F'|' -v m=" $m " '$2 == m && $3 == " none " {print $4 + 0}' <<< "$cause_rows")
  [[ ${good:-0} -eq ${none:-0} ]] || fail "$m: ${good:-0} good poses but ${none:-0} without a cause"
done
# The covariance's coverage: per level, then all, with shares and medians;
# the levels' poses add up to all's, and every module set has poses.
cover_rows=$(awk '/^## How well the pose covariance/{f=1;next} /^## /{f=0} f && /^\| [a-z+]+ \| /' "$report")
odd=$(grep -Ev '^\| [a-z+]+ \| (good|degraded|unreliable|all) \| [0-9]+ \| [0-9.]+ % \| [0-9.]+ \| [0-9.]+ % \| [0-9.]+ \|$' <<< "$cover_rows")
[[ -z $odd ]] || fail "covariance rows not of a level with its numbers: $odd"
for m in none geometry semantic geometry+semantic; do
  levels=$(awk -F'|' -v m=" $m " '$2 == m && $3 != " all " {n += $4} END {print n + 0}' <<< "$cover_rows")
  all=$(awk -F'|' -v m=" $m " '$2 == m && $3 == " all " {print $4 + 0}' <<< "$cover_rows")
  [[ ${all:-0} -gt 0 && $levels -eq ${all:-0} ]] || fail "$m: covariance rows' poses $levels, all ${all:-none}"
done
# The runtime table's last column: the newest semantic masks' age (median, p90) where the module ran.
runtime_rows=$(awk '/^## Runtime/{f=1;next} /^## /{f=0} f && /^\| `/' "$report")
[[ $(wc -l <<< "$runtime_rows") -eq 12 ]] || fail "runtime table rows: $runtime_rows"
while IFS='|' read -r _ seq modules _ _ _ _ _ _ _ _ age _; do
  age=${age// /}
  if [[ $modules == *semantic* && $seq != *absent* ]]; then
    [[ $age =~ ^([0-9]+\.[0-9]{2}|inf),([0-9]+\.[0-9]{2}|inf)$ ]] || fail "$seq/$modules: masks' age '$age'"
  else
    [[ $age == - ]] || fail "$seq/$modules: masks' age '$age' without the semantic module"
  fi
done <<< "$runtime_rows"
header=$(head -n 1 "$csv")
for col in sequence modules run ate_rmse_m rpe_trans_m_s rpe_rot_deg_s maps ate_one_frame_rmse_m frames \
           frames_with_pose track_ms_median track_ms_p95 trajectory; do
  [[ ",$header," == *",$col,"* ]] || fail "results.csv lacks column $col"
done
ncol=$(awk -F, 'NR == 1 {print NF}' "$csv")
[[ $(awk -F, -v n="$ncol" 'NR > 1 && NF != n' "$csv" | wc -l) -eq 0 ]] || fail "results.csv rows of unequal width"
[[ $(($(wc -l < "$csv") - 1)) -eq 12 ]] || fail "results.csv has $(($(wc -l < "$csv") - 1)) rows, expected 12"
col() { awk -F, -v name="$1" 'NR == 1 {for (i = 1; i <= NF; i++) if ($i == name) c = i; next} {print $c}' "$csv"; }
paste -d' ' <(col sequence) <(col modules) <(col status) <(col frames) <(col frames_with_pose) \
            <(col ate_rmse_m) <(col maps) <(col ate_one_frame_rmse_m) <(col trajectory) > "$work/rows"
checked=0 evo_checked=0
have_evo=0
command -v evo_ape > /dev/null && have_evo=1
while read -r seq modules status frames with_pose ate maps one_frame trajectory; do
  case $seq in
    absent) [[ $status == "missing folder" || $status == missing ]] || fail "$seq/$modules: status '$status'"; continue ;;
  esac
  [[ $status == ok ]] || fail "$seq/$modules: status '$status' (crash or failure)"
  [[ $frames -eq $max_frames || ($seq == poster-walk && $frames -gt 0 && $frames -le $max_frames) ]] \
    || fail "$seq/$modules: $frames frames"
  poses=$(grep -vc '^#' "$out/$trajectory")
  [[ $poses -eq $with_pose ]] || fail "$seq/$modules: frames_with_pose $with_pose but the trajectory has $poses poses"
  [[ $ate =~ ^[0-9.]+$ ]] || fail "$seq/$modules: ATE '$ate'"
  [[ $maps =~ ^[1-9][0-9]*$ ]] || fail "$seq/$modules: maps '$maps'"
  # One map: both ATEs are the same.
  [[ $maps -gt 1 || $one_frame == "$ate" ]] || fail "$seq/$modules: one map, ATE $ate but in one frame $one_frame"
  checked=$((checked + 1))
  if [[ $have_evo -eq 1 ]]; then
    gt=$([[ $seq == poster-walk ]] && echo "$work/poster-walk/groundtruth.txt" || echo "$teddy/groundtruth.txt")
    # evo aligns the whole trajectory at once (it reads '# map' lines as
    # comments): the ATE in one frame.
    evo=$(evo_ape tum "$gt" "$out/$trajectory" --align --t_max_diff 0.02 2>&1 | awk '$1 == "rmse" {print $2}')
    [[ -n $evo ]] || fail "$seq/$modules: evo_ape printed no rmse"
    awk -v a="$one_frame" -v b="$evo" 'BEGIN {d = a - b; if (d < 0) d = -d; exit !(d <= 1e-4)}' \
      || fail "$seq/$modules: bench ATE in one frame $one_frame m, evo_ape $evo m: more than 1e-4 m apart"
    echo "$seq $modules: bench $ate m ($maps maps, in one frame $one_frame m), evo_ape $evo m"
    evo_checked=$((evo_checked + 1))
  fi
done < "$work/rows"
[[ $checked -eq 8 ]] || fail "$checked runs checked, expected 8"
pngs=$(find "$out/plots" -name '*.png' | wc -l)
[[ $pngs -ge 16 ]] || fail "$pngs plots, expected at least 16"
renders=$(find "$out/runs" -path '*render*' -name '*.png' | wc -l)
[[ $renders -ge 8 ]] || fail "$renders rendered frames, expected at least 8"
if [[ $have_evo -eq 1 ]]; then
  echo "PASS: 8 runs, report and results.csv well formed; ATE agrees with evo_ape (evo $(evo pkg --version 2>/dev/null | head -n 1)) on $evo_checked runs"
else
  echo "PASS: 8 runs, report and results.csv well formed (evo_ape not installed: pip install evo to compare ATE)"
fi
