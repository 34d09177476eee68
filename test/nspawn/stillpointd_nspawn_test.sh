#!/usr/bin/env bash
# stillpointd under a real systemd: boots a Debian bookworm minbase container
# (systemd-nspawn --boot --register=no --keep-unit --private-network) with the
# project's .deb installed by dpkg, the TUM excerpt bind-mounted read-only and
# /etc/stillpoint/stillpointd.yaml replaying it in a loop, then checks from
# outside, through nsenter into the container's namespaces:
#   1. start: the unit goes active (running) only after READY=1 (systemd's own
#      debug log: the READY=1 notification precedes "start -> running");
#      the main process runs as the dynamic user "stillpoint";
#   2. StatusText= carries "<state>, <fps> fps, <n> frames, ..." with fps > 0;
#   3. watchdog: the main process is SIGSTOPped, systemd reports a watchdog
#      timeout, kills it and restarts it (Restart=on-failure, NRestarts + 1),
#      and the new process reaches active (running) again;
#   4. stop: `systemctl stop` returns within shutdown_timeout_s, the main
#      process exited with status 0 (Result=success), the trajectory and status
#      files are written;
#   5. `systemd-analyze security stillpointd.service` inside the container
#      (printed, not judged), then the container powers off cleanly.
#
#   bash test/nspawn/stillpointd_nspawn_test.sh BUILD_DIR DATASET_DIR WORK_DIR
#
# BUILD_DIR: a build configured with -DCMAKE_INSTALL_PREFIX=/usr and built;
# the .deb is made from it with cpack (STILLPOINT_NSPAWN_DEB=PATH.deb uses a
# ready package instead). The root file system is cached in
# STILLPOINT_NSPAWN_CACHE (default /var/cache/stillpoint-nspawn).
# Exit status: 0 pass, 1 fail, 77 skipped (not root, tools missing, no
# dataset, Debian mirror unreachable with nothing cached).
set -euo pipefail
build=${1:?usage: stillpointd_nspawn_test.sh BUILD_DIR DATASET_DIR WORK_DIR}
dataset=${2:?usage: stillpointd_nspawn_test.sh BUILD_DIR DATASET_DIR WORK_DIR}
work=${3:?usage: stillpointd_nspawn_test.sh BUILD_DIR DATASET_DIR WORK_DIR}
cache=${STILLPOINT_NSPAWN_CACHE:-/var/cache/stillpoint-nspawn}
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
source_unit=$here/../../systemd/stillpointd.service
unit=stillpointd.service

t_begin=$(date +%s.%N)
now() { date +%s.%N; }
elapsed() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.2f", b - a }'; }
log() { echo "[$(elapsed "$t_begin") s] $*"; }
skip() { echo "SKIP: $*"; exit 77; }

[[ $(id -u) -eq 0 ]] || skip "needs root (systemd-nspawn, mmdebstrap)"
for tool in systemd-nspawn mmdebstrap nsenter flock cpack dpkg-deb; do
  command -v "$tool" >/dev/null || skip "$tool missing (apt-get install systemd-container mmdebstrap)"
done
[[ -f $dataset/rgb.txt ]] || skip "no TUM sequence at $dataset"
dataset=$(realpath "$dataset")
seq_in_container=/srv/$(basename "$dataset")

rm -rf "$work"
mkdir -p "$work"
root=$work/root
nspawn_pid='' pid1=''

ns() { nsenter -t "$pid1" -a -- "$@"; }
prop() { ns systemctl show -p "$1" --value "$unit"; }
# "ActiveState/SubState/NRestarts/MainPID" (systemctl show prints in its own order).
unit_state() {
  ns systemctl show -p ActiveState -p SubState -p NRestarts -p MainPID "$unit" |
    awk -F= '{ v[$1] = $2 } END { print v["ActiveState"] "/" v["SubState"] "/" v["NRestarts"] "/" v["MainPID"] }'
}
save_journal() {
  [[ -n $pid1 ]] && kill -0 "$pid1" 2>/dev/null || return 0
  ns journalctl -b --no-pager -o short-monotonic >"$work/journal.txt" 2>&1 || true
}
fail() {
  echo "FAIL: $*" >&2
  if save_journal && [[ -s $work/journal.txt ]]; then
    echo "--- last lines of $unit in the container's journal ($work/journal.txt):" >&2
    grep -E 'stillpointd(\[|\.service)' "$work/journal.txt" | grep -vE '(Got|Sent) message type=' | tail -n 40 >&2 || true
  elif [[ -s $work/console.log ]]; then
    echo "--- container console ($work/console.log):" >&2
    tail -n 30 "$work/console.log" >&2
  fi
  exit 1
}
cleanup() {
  local rc=$?
  if [[ -n $nspawn_pid ]] && kill -0 "$nspawn_pid" 2>/dev/null; then
    save_journal
    kill -TERM "$nspawn_pid" 2>/dev/null || true  # nspawn powers the container off
    for _ in $(seq 100); do kill -0 "$nspawn_pid" 2>/dev/null || break; sleep 0.2; done
    kill -KILL "$nspawn_pid" 2>/dev/null || true
    wait "$nspawn_pid" 2>/dev/null || true
  fi
  [[ ${STILLPOINT_NSPAWN_KEEP:-0} == 1 ]] || rm -rf "$root"
  exit "$rc"
}
trap cleanup EXIT

# --- the package -------------------------------------------------------------
if [[ -n ${STILLPOINT_NSPAWN_DEB:-} ]]; then
  deb=$(realpath "$STILLPOINT_NSPAWN_DEB")
else
  [[ -f $build/CPackConfig.cmake ]] || fail "$build/CPackConfig.cmake missing: not a configured build folder"
  cpack --config "$build/CPackConfig.cmake" -B "$work/package" >"$work/cpack.log" 2>&1 ||
    fail "cpack failed (build the programs first: cmake --build $build); log: $work/cpack.log: $(tail -n 5 "$work/cpack.log")"
  deb=$(ls "$work"/package/stillpoint_*.deb)
fi
contents=$(dpkg-deb -c "$deb")
for f in ./usr/bin/stillpointd ./usr/lib/systemd/system/stillpointd.service ./etc/stillpoint/stillpointd.yaml; do
  grep -q " $f\$" <<<"$contents" ||
    fail "$(basename "$deb") lacks ${f#.} (configure with -DCMAKE_INSTALL_PREFIX=/usr)"
done
log "package: $(basename "$deb")"

# --- the root file system ----------------------------------------------------
rc=0
tarball=$(bash "$here/make-rootfs.sh" "$cache" "$deb") || rc=$?
[[ $rc -eq 77 ]] && skip "the Debian mirror is unreachable and no root is cached in $cache"
[[ $rc -eq 0 ]] || fail "make-rootfs.sh failed (exit $rc)"
mkdir -p "$root"
tar -C "$root" -xf "$tarball"
cp "$deb" "$root/root/stillpoint.deb"
# The real install: dpkg inside the container (no network: the Depends are in the root).
systemd-nspawn --quiet -D "$root" --register=no --keep-unit --private-network \
  dpkg -i /root/stillpoint.deb >"$work/dpkg.log" 2>&1 || fail "dpkg -i in the container failed: $(tail -n 10 "$work/dpkg.log")"
rm "$root/root/stillpoint.deb"
cmp -s "$root/lib/systemd/system/$unit" "$source_unit" ||
  fail "/lib/systemd/system/$unit in the container differs from systemd/$unit"
log "root: $(basename "$tarball"), package installed"

cp "$root/etc/stillpoint/stillpointd.yaml" "$root/etc/stillpoint/stillpointd.yaml.shipped"
cat >"$root/etc/stillpoint/stillpointd.yaml" <<EOF
# test/nspawn: the bind-mounted TUM excerpt at the recorded rate, looping.
camera: fr3
log_level: info
shutdown_timeout_s: 5
status_period_s: 1
source:
  type: replay
  replay: {path: $seq_in_container, paced: true, loop: true}
slam:
  options_file: /etc/stillpoint/slam.yaml
output:
  trajectory: /var/lib/stillpoint/trajectory.txt
  status: /var/lib/stillpoint/status.txt
EOF

# --- boot ----------------------------------------------------------------------
# CAP_IPC_LOCK is not in systemd-nspawn's default bounding set; without it
# systemd silently drops it from the unit's AmbientCapabilities=. Granted here
# so the container matches a robot's host for what the unit asks.
systemd-nspawn -D "$root" --boot --register=no --keep-unit --private-network --capability=CAP_IPC_LOCK \
  --machine=stillpoint-nspawn --bind-ro="$dataset:$seq_in_container" --console=read-only \
  >"$work/console.log" 2>&1 </dev/null &
nspawn_pid=$!
# The container's PID 1 is the child of systemd-nspawn that is PID 1 in its own namespace.
for _ in $(seq 150); do
  kill -0 "$nspawn_pid" 2>/dev/null || fail "systemd-nspawn exited during boot: $(tail -n 10 "$work/console.log")"
  for st in /proc/[0-9]*/status; do
    grep -qx "PPid:[[:space:]]*$nspawn_pid" "$st" 2>/dev/null &&
      grep -qE '^NSpid:.*[[:space:]]1$' "$st" 2>/dev/null && pid1=$(basename "$(dirname "$st")")
  done
  [[ -n $pid1 ]] && break
  sleep 0.2
done
[[ -n $pid1 ]] || fail "no container PID 1 under systemd-nspawn ($nspawn_pid) after 30 s"
boot_state=$(timeout 90 nsenter -t "$pid1" -a -- systemctl is-system-running --wait 2>/dev/null || true)
case $boot_state in
  running) ;;
  degraded) log "boot: degraded; failed units: $(ns systemctl --failed --no-legend --plain | awk '{print $1}' | xargs)" ;;
  *) fail "container did not finish booting within 90 s (state '$boot_state')" ;;
esac
log "booted: container PID 1 is host PID $pid1, system $boot_state"

# --- 1. start: active only after READY=1 -----------------------------------
ns systemctl log-level debug  # PID 1 then logs each notification it receives
[[ $(prop ActiveState) == inactive ]] || fail "$unit is $(prop ActiveState) before it was started (the package must not start it)"
# Enabled as a robot would have it ([Install] WantedBy=multi-user.target); this
# also keeps the unit loaded after its stop, so its exit properties stay readable.
ns systemctl enable --quiet "$unit" || fail "systemctl enable $unit failed"
[[ $(ns systemctl is-enabled "$unit") == enabled ]] || fail "$unit is not enabled after systemctl enable"
t_start=$(now)
ns systemctl start --no-block "$unit"
states=() last='' t_running=''
while true; do
  st=$(unit_state)
  st=${st%/*/*}  # ActiveState/SubState
  [[ $st != "$last" ]] && states+=("$st@$(elapsed "$t_start")s") && last=$st
  [[ $st == active/running ]] && { t_running=$(elapsed "$t_start"); break; }
  [[ $st == failed/* ]] && fail "$unit failed to start (states: ${states[*]})"
  (($(awk -v e="$(elapsed "$t_start")" 'BEGIN { print (e > 70) }'))) && fail "$unit not active/running 70 s after start (states: ${states[*]})"
  sleep 0.05
done
ns journalctl -u "$unit" --no-pager -o short-monotonic >"$work/unit-journal.txt"
ready_at=$(grep -n 'Got notification message from PID [0-9]* (READY=1' "$work/unit-journal.txt" | head -1 | cut -d: -f1)
running_at=$(grep -n 'Changed start -> running' "$work/unit-journal.txt" | head -1 | cut -d: -f1)
[[ -n $ready_at ]] || fail "systemd logged no READY=1 notification from $unit"
[[ -n $running_at ]] || fail "systemd logged no 'start -> running' for $unit"
((ready_at < running_at)) || fail "$unit went running (journal line $running_at) before READY=1 (line $ready_at)"
exec_us=$(prop ExecMainStartTimestampMonotonic) active_us=$(prop ActiveEnterTimestampMonotonic)
ready_s=$(awk -v a="$exec_us" -v b="$active_us" 'BEGIN { printf "%.3f", (b - a) / 1e6 }')
main_pid=$(prop MainPID)
uid=$(ns awk '/^Uid:/ { print $2 }' "/proc/$main_pid/status")
user=$(ns getent passwd "$uid" | cut -d: -f1)
[[ $user == stillpoint ]] || fail "main process runs as uid $uid ('$user'), not the dynamic user stillpoint"
# AmbientCapabilities=CAP_SYS_NICE CAP_IPC_LOCK: bits 23 and 14, nothing else.
cap_amb=$(ns awk '/^CapAmb:/ { print $2 }' "/proc/$main_pid/status")
[[ $cap_amb == 0000000000804000 ]] || fail "main process CapAmb=$cap_amb (want 0000000000804000: CAP_SYS_NICE, CAP_IPC_LOCK)"
log "start: states ${states[*]}; READY=1 then running; start -> running ${t_running} s seen from outside, exec -> active ${ready_s} s (systemd); user $user (uid $uid), CapAmb=$cap_amb"

# --- 2. StatusText -------------------------------------------------------------
# The line goes on after `dropped` (map, keyframes, points, then optional parts).
status_re='^([a-z_ ,]+), ([0-9.]+) fps, ([0-9]+) frames, ([0-9]+) lost, ([0-9]+) dropped, map ([0-9]+) of ([0-9]+), ([0-9]+) keyframes ([0-9]+) points(, .*)?$'
wait_status() {  # wait_status MIN_FRAMES TIMEOUT_S: a StatusText with fps > 0 and >= MIN_FRAMES frames
  local deadline=$((SECONDS + $2)) text
  while ((SECONDS < deadline)); do
    text=$(prop StatusText)
    if [[ $text =~ $status_re ]] && [[ ${BASH_REMATCH[2]} != 0.0 ]] && ((BASH_REMATCH[3] >= $1)); then
      echo "$text"
      return 0
    fi
    sleep 0.25
  done
  echo "$text"
  return 1
}
status=$(wait_status 30 30) || fail "StatusText never showed fps > 0 and 30 frames within 30 s; last: '$status'"
log "status: StatusText='$status'"

# --- 3. watchdog -------------------------------------------------------------
restarts_before=$(prop NRestarts)
watchdog_usec=$(prop WatchdogUSec)
t_sigstop=$(now)
ns /bin/bash -c "kill -STOP $main_pid"  # minbase has no procps: the bash builtin
states=() last='' t_restarted=''
while true; do
  st=$(unit_state)
  [[ $st != "$last" ]] && states+=("$st@$(elapsed "$t_sigstop")s") && last=$st
  IFS=/ read -r active sub restarts pid <<<"$st"
  if [[ $active/$sub == active/running && $restarts -gt $restarts_before && $pid != "$main_pid" ]]; then
    t_restarted=$(elapsed "$t_sigstop")
    break
  fi
  (($(awk -v e="$(elapsed "$t_sigstop")" 'BEGIN { print (e > 90) }'))) &&
    fail "no watchdog restart within 90 s of SIGSTOP (states as ActiveState/SubState/NRestarts/MainPID: ${states[*]})"
  sleep 0.1
done
ns journalctl -u "$unit" --no-pager -o short-monotonic >"$work/unit-journal.txt"
grep -q "Watchdog timeout" "$work/unit-journal.txt" || fail "restarted, but systemd logged no watchdog timeout"
grep -q "Failed with result 'watchdog'" "$work/unit-journal.txt" || fail "systemd logged no \"Failed with result 'watchdog'\""
main_exit=$(grep -o 'Main process exited, [^.]*' "$work/unit-journal.txt" | tail -1)
# The restarted process, too, goes running only after its READY=1.
after=$(grep -n 'Scheduled restart job' "$work/unit-journal.txt" | tail -1 | cut -d: -f1)
[[ -n $after ]] || fail "systemd logged no 'Scheduled restart job' for $unit"
ready_at=$(awk -v a="$after" 'NR > a && /Got notification message from PID [0-9]+ \(READY=1/ { print NR; exit }' "$work/unit-journal.txt")
running_at=$(awk -v a="$after" 'NR > a && /Changed start -> running/ { print NR; exit }' "$work/unit-journal.txt")
[[ -n $ready_at && -n $running_at ]] && ((ready_at < running_at)) ||
  fail "after the restart: READY=1 (journal line '${ready_at}') must precede start -> running (line '${running_at}')"
main_pid=$pid
log "watchdog: SIGSTOP -> restarted and running in ${t_restarted} s (WatchdogUSec=$watchdog_usec, NRestarts $restarts_before -> $restarts; $main_exit; states ActiveState/SubState/NRestarts/MainPID: ${states[*]})"
status=$(wait_status 30 30) || fail "after the restart StatusText never showed fps > 0 and 30 frames; last: '$status'"
log "status after restart: '$status'"

# --- 4. clean stop -------------------------------------------------------------
t_stop=$(now)
ns systemctl stop "$unit"
stop_s=$(elapsed "$t_stop")
result=$(prop Result) code=$(prop ExecMainCode) exit_status=$(prop ExecMainStatus) active=$(prop ActiveState)
[[ $active == inactive ]] || fail "after systemctl stop $unit is $active"
[[ $code == 1 && $exit_status == 0 ]] || fail "main process ended with code=$code status=$exit_status (want exited, 0)"
[[ $result == success ]] || fail "Result=$result after stop (want success)"
ns journalctl -u "$unit" --no-pager -o short-monotonic >"$work/unit-journal.txt"
stop_log=$(awk '/Stopping stillpointd.service/ { n = NR } { line[NR] = $0 } END { for (i = n; i <= NR; ++i) print line[i] }' "$work/unit-journal.txt")
grep -q 'Main process exited, code=exited, status=0/SUCCESS' <<<"$stop_log" ||
  fail "journal after 'Stopping': no 'Main process exited, code=exited, status=0/SUCCESS'"
grep -q 'Deactivated successfully' <<<"$stop_log" || fail "journal after 'Stopping': no 'Deactivated successfully'"
! grep -qE "Failed with result|State 'stop-sigterm' timed out|Killing process" <<<"$stop_log" ||
  fail "unclean stop: $(grep -E "Failed with result|timed out|Killing process" <<<"$stop_log" | head -3)"
(($(awk -v s="$stop_s" 'BEGIN { print (s < 5) }'))) || fail "systemctl stop took $stop_s s (bound: shutdown_timeout_s 5 s)"
state_dir=$root/var/lib/private/stillpoint
[[ -s $state_dir/trajectory.txt ]] || fail "no trajectory in /var/lib/stillpoint/trajectory.txt"
poses=$(awk 'NF == 8 && $1 + 0 > 0' "$state_dir/trajectory.txt" | wc -l)
((poses >= 10)) || fail "trajectory has $poses poses (want >= 10)"
grep -qx 'exit_reason=signal' "$state_dir/status.txt" || fail "status file: $(cat "$state_dir/status.txt" 2>&1 | head -3)"
shutdown_ms=$(sed -n 's/^shutdown_ms=//p' "$state_dir/status.txt")
log "stop: systemctl stop returned in ${stop_s} s; exit status 0, Result=success; daemon's own stop ${shutdown_ms} ms; trajectory $poses poses"

# --- 5. security score, power off ---------------------------------------------
ns systemd-analyze security --no-pager "$unit" >"$work/security.txt" 2>&1 || true
score=$(grep -o 'Overall exposure level for .*' "$work/security.txt" | LC_ALL=C tr -cd '[:print:]' || true)
score=${score% }
[[ -n $score ]] || score="no score (see $work/security.txt)"
log "security: $score"
save_journal
t_off=$(now)
ns systemctl poweroff --no-block
rc=0
for _ in $(seq 300); do kill -0 "$nspawn_pid" 2>/dev/null || break; sleep 0.2; done
kill -0 "$nspawn_pid" 2>/dev/null && fail "container still running 60 s after poweroff"
wait "$nspawn_pid" || rc=$?
nspawn_pid=''
((rc == 0)) || fail "systemd-nspawn exited with $rc after poweroff"
log "poweroff: container gone after $(elapsed "$t_off") s"
echo "PASS: ready ${ready_s} s, watchdog restart ${t_restarted} s after SIGSTOP (NRestarts $restarts), stop ${stop_s} s, $score"
