#!/usr/bin/env bash
# Cyclone DDS between real processes, confined to loopback by cyclonedds-loopback.xml
# (interface lo, multicast off, peer 127.0.0.1):
#   1. every pose (best-effort) and status (reliable) sample arrives, fields exact;
#   2. a subscriber that joins after the status was published still gets the last one
#      (transient-local), and so does stillpoint-echo --dds.
# usage: dds_loopback_test.sh BIN_DIR WORK_DIR CONFIG_XML
set -uo pipefail
bin=$1
work=$2
cfg="file://$3"
fail() { echo "FAIL: $*"; exit 1; }
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null; done; wait 2>/dev/null; }
trap cleanup EXIT
rm -rf "$work" && mkdir -p "$work"
# Topic names unique to this run: parallel runs on the machine never cross.
tag="_t$$"
dds=(--transport dds --dds-config "$cfg" --domain 0)

echo "== publisher -> subscriber (1000 poses at 1 kHz, 20 statuses)"
"$bin/ipc_probe" sub "${dds[@]}" --suffix "${tag}a" --count 1000 --statuses 20 --objects --ready-file "$work/ready" \
  --timeout 20 >"$work/sub.out" 2>&1 &
sub=$!; pids+=($sub)
"$bin/ipc_probe" pub "${dds[@]}" --suffix "${tag}a" --count 1000 --rate 1000 --status-every 50 --objects \
  --ready-file "$work/ready" --timeout 20 || fail "publisher failed"
wait $sub; rc=$?
cat "$work/sub.out"
[[ $rc -eq 0 ]] || fail "subscriber: samples missing or wrong"

echo "== late joiner gets the last status (transient-local)"
"$bin/ipc_probe" pub "${dds[@]}" --suffix "${tag}b" --count 30 --rate 1000 --status-every 10 \
  --hold-file "$work/release" --timeout 20 >"$work/pub.out" 2>&1 &
pub=$!; pids+=($pub)
for _ in $(seq 400); do grep -q "^pub sent" "$work/pub.out" && break; sleep 0.05; done
grep -q "^pub sent" "$work/pub.out" || fail "publisher did not finish publishing"
"$bin/ipc_probe" sub "${dds[@]}" --suffix "${tag}b" --count 0 --last-status 3 --timeout 10 \
  || fail "late subscriber did not get status #3"

echo "== stillpoint-echo --dds shows it too"
cat >"$work/ipc.yaml" <<YAML
ipc:
  dds: {domain_id: 0, config: "$cfg", pose_topic: stillpoint_pose${tag}b, status_topic: stillpoint_status${tag}b}
YAML
"$bin/stillpoint-echo" --dds --config "$work/ipc.yaml" --seconds 2 >"$work/echo.out" 2>&1 || fail "stillpoint-echo failed"
cat "$work/echo.out"
grep -q "^status uptime_s=1.08 frames=90" "$work/echo.out" || fail "stillpoint-echo did not print the last status"
touch "$work/release"
wait $pub || fail "publisher exited with an error"
echo "PASS"
