#!/usr/bin/env bash
# LCM between real processes inside a private network namespace this test creates
# (only its own loopback exists there, so no packet can reach a real interface):
#   1. publisher -> subscriber over udpm: every pose and status arrives, fields exact;
#   2. lcm-logger records our channels, lcm-logplayer replays them into a subscriber,
#      and the same recording reads back through our file:// subscriber.
# Skips (exit 77) when not root or when `ip netns` is unavailable.
# usage: lcm_netns_test.sh BIN_DIR WORK_DIR [LCM_TOOLS_DIR]
set -uo pipefail
bin=$1
work=$2
lcm_tools=${3:-/usr/bin}
skip() { echo "SKIP: $*"; exit 77; }
fail() { echo "FAIL: $*"; exit 1; }

[[ $(id -u) -eq 0 ]] || skip "needs root to create a network namespace (ip netns add)"
command -v ip >/dev/null || skip "iproute2 (ip) is not installed"
[[ -x $lcm_tools/lcm-logger && -x $lcm_tools/lcm-logplayer ]] || fail "lcm-logger/lcm-logplayer missing in $lcm_tools (liblcm-bin)"

ns="sp-ipc-lcm-$$-$RANDOM"
pids=()
cleanup() {
  # Everything still running inside our namespace, then our own background jobs.
  for p in $(ip netns pids "$ns" 2>/dev/null); do kill -KILL "$p" 2>/dev/null; done
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null; done
  wait 2>/dev/null
  ip netns del "$ns" 2>/dev/null
}
trap cleanup EXIT
ip netns add "$ns" 2>/dev/null || skip "cannot create a network namespace (ip netns add failed; container without CAP_SYS_ADMIN?)"
in_ns() { ip netns exec "$ns" "$@"; }
in_ns ip link set lo up || fail "cannot bring up lo in $ns"
in_ns ip route add 224.0.0.0/4 dev lo || fail "cannot add the multicast route in $ns"

rm -rf "$work" && mkdir -p "$work"
url="udpm://239.255.76.67:7667?ttl=0"
count=1000

echo "== live publisher -> subscriber ($count poses at 1 kHz, 20 statuses) in namespace $ns"
in_ns "$bin/ipc_probe" sub --transport lcm --url "$url" --suffix _LIVE --count $count --statuses 20 \
  --ready-file "$work/ready" --timeout 20 >"$work/sub.out" 2>&1 &
sub=$!; pids+=($sub)
in_ns "$bin/ipc_probe" pub --transport lcm --url "$url" --suffix _LIVE --count $count --rate 1000 \
  --status-every 50 --ready-file "$work/ready" --timeout 20 || fail "publisher failed"
wait $sub; rc=$?
cat "$work/sub.out"
[[ $rc -eq 0 ]] || fail "live subscriber: messages missing or wrong"

echo "== lcm-logger recording, lcm-logplayer replay"
log="$work/rec.lcmlog"
# `ip netns exec` forks: record the logger's own pid to signal it, not ip's.
in_ns sh -c 'echo $$ >"$1"; exec "$3/lcm-logger" -q -f -c "STILLPOINT_.*_REC" --flush-interval=10 "$2"' sh \
  "$work/logger.pid" "$log" "$lcm_tools" &
pids+=($!)
for _ in $(seq 100); do [[ -s $work/logger.pid ]] && break; sleep 0.01; done
logger=$(cat "$work/logger.pid")
sleep 0.5  # the logger must have joined the group before we publish
in_ns "$bin/ipc_probe" pub --transport lcm --url "$url" --suffix _REC --count 300 --rate 1000 --status-every 30 \
  --timeout 20 || fail "publisher (recording) failed"
# lcm-logger flushes its file and notices SIGTERM only when a message arrives, so keep a
# filler stream going on a channel it records but our subscribers ignore
# (STILLPOINT_POSE_FLUSH_REC) until it has exited cleanly.
in_ns "$bin/ipc_probe" pub --transport lcm --url "$url" --suffix _FLUSH_REC --count 500 --rate 100 \
  --timeout 20 >/dev/null 2>&1 &
filler=$!; pids+=($filler)
sleep 0.3
kill -TERM $logger
for _ in $(seq 100); do kill -0 $logger 2>/dev/null || break; sleep 0.05; done
kill -0 $logger 2>/dev/null && fail "lcm-logger did not exit on SIGTERM"
kill $filler 2>/dev/null; wait $filler 2>/dev/null
[[ -s $log ]] || fail "lcm-logger wrote nothing"

echo "== the recording through our file:// subscriber"
"$bin/ipc_probe" sub --transport lcm --url "file://$log?speed=0" --suffix _REC --count 300 --statuses 10 \
  --timeout 20 || fail "file:// read of the lcm-logger recording"
echo "== lcm-logplayer replays it to a live subscriber"
in_ns "$bin/ipc_probe" sub --transport lcm --url "$url" --suffix _REC --count 300 --statuses 10 \
  --ready-file "$work/ready2" --timeout 20 >"$work/replay.out" 2>&1 &
sub=$!; pids+=($sub)
for _ in $(seq 200); do [[ -e $work/ready2 ]] && break; sleep 0.05; done
in_ns "$lcm_tools/lcm-logplayer" -s 1 "$log" >/dev/null || fail "lcm-logplayer failed"
wait $sub; rc=$?
cat "$work/replay.out"
[[ $rc -eq 0 ]] || fail "replayed log: messages missing or wrong"

echo "PASS"
