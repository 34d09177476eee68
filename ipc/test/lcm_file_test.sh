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
# A status whose thread count its bytes cannot hold (-1): the generated decoder
# throws on it, and that must be a clear error, not an abort. The log is the
# probe's with its first status made so (LCM log events: sync word, event
# number, time, channel and data lengths, channel, data; big-endian).
# usage: bad_count CHANNEL OFFSET FORMAT VALUE NAME: a log of the probe's first
# message on CHANNEL with VALUE packed (struct FORMAT) at OFFSET of its data.
bad_count() {
  python3 - "$log" "$work/$5.lcmlog" "$1" "$2" "$3" "$4" <<'PY' || { echo "FAIL: writing the $5 log"; exit 1; }
import struct, sys
data = open(sys.argv[1], "rb").read()
at = 0
while at < len(data):
    sync, number, utime, clen, dlen = struct.unpack_from(">IqqII", data, at)
    assert sync == 0xEDA1DA01, "not an LCM log"
    channel = data[at + 28:at + 28 + clen]
    body = bytearray(data[at + 28 + clen:at + 28 + clen + dlen])
    if channel == sys.argv[3].encode():
        struct.pack_into(sys.argv[5], body, int(sys.argv[4]), int(sys.argv[6]))
        out = struct.pack(">IqqII", sync, 0, utime, clen, len(body)) + channel + bytes(body)
        open(sys.argv[2], "wb").write(out)
        break
    at += 28 + clen + dlen
else:
    sys.exit("no message on " + sys.argv[3] + " in the log")
PY
}
# num_threads, after 8 bytes of fingerprint and 52 of fields.
bad_count STILLPOINT_STATUS 60 ">h" -1 bad_count
"$bin/stillpoint-echo" --lcm --url "file://$work/bad_count.lcmlog?speed=0" --seconds 5 >"$work/bad_count.out" 2>&1
rc=$?
[ "$rc" -eq 1 ] || { echo "FAIL: a status with a bad count gave exit status $rc:"; cat "$work/bad_count.out"; exit 1; }
grep -q "cannot decode a status_t on STILLPOINT_STATUS" "$work/bad_count.out" \
  || { echo "FAIL: unclear error for a bad count:"; cat "$work/bad_count.out"; exit 1; }
echo "bad count reported: $(grep -m1 decode "$work/bad_count.out")"
# Objects counting 20 million in a message of a few hundred bytes: the
# generated decoder would size its array (about 2 GB) before finding the
# bytes short. The subscriber must refuse the count first, naming it; under a
# 1 GiB address-space limit an allocation would fail with another message.
bad_count STILLPOINT_OBJECTS 44 ">i" 20000000 huge_count  # count, after 8 bytes of fingerprint and 36 of fields
(ulimit -v 1048576 && exec "$bin/stillpoint-echo" --lcm --url "file://$work/huge_count.lcmlog?speed=0" --seconds 5) \
  >"$work/huge_count.out" 2>&1
rc=$?
[ "$rc" -eq 1 ] || { echo "FAIL: objects with a huge count gave exit status $rc:"; cat "$work/huge_count.out"; exit 1; }
grep -q "cannot decode an objects_t on STILLPOINT_OBJECTS: its count of 20000000 objects" "$work/huge_count.out" \
  || { echo "FAIL: unclear error for a huge count:"; cat "$work/huge_count.out"; exit 1; }
echo "huge count reported: $(grep -m1 decode "$work/huge_count.out")"
echo "PASS"
