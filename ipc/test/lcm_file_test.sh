#!/usr/bin/env bash
# LCM file:// log provider (no network): one process writes a log through our LCM
# transport, another reads it back with our subscriber; every field must survive.
# usage: lcm_file_test.sh BIN_DIR WORK_DIR
set -uo pipefail
bin=$1
work=$2
rm -rf "$work" && mkdir -p "$work"
log="$work/probe.lcmlog"
"$bin/ipc_probe" pub --transport lcm --url "file://$log?mode=w" --count 500 --rate 20000 --status-every 25 --objects \
  || { echo "FAIL: writing the log"; exit 1; }
"$bin/ipc_probe" sub --transport lcm --url "file://$log?speed=0" --count 500 --statuses 20 --objects --timeout 10 \
  || { echo "FAIL: reading the log back"; exit 1; }
# Another schema on our channel must be a clear error, not garbage: swap the channels so
# status messages arrive where a pose is expected.
cat >"$work/swapped.yaml" <<'YAML'
ipc:
  lcm: {pose_channel: STILLPOINT_STATUS, status_channel: STILLPOINT_POSE}
YAML
if "$bin/stillpoint-echo" --lcm --config "$work/swapped.yaml" --url "file://$log?speed=0" --seconds 5 \
     >"$work/swapped.out" 2>&1; then
  echo "FAIL: stillpoint-echo accepted status messages as poses"; cat "$work/swapped.out"; exit 1
fi
grep -Eq "cannot decode a (pose_t on STILLPOINT_STATUS|status_t on STILLPOINT_POSE)" "$work/swapped.out" \
  || { echo "FAIL: unclear error for a schema mismatch:"; cat "$work/swapped.out"; exit 1; }
echo "schema mismatch reported: $(grep -m1 decode "$work/swapped.out")"
echo "PASS"
