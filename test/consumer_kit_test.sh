#!/usr/bin/env bash
# The consumer kit's plain-Python reader (ipc/examples/read_poses.py) reads the
# poses stillpointd writes to the shared-memory ring while it replays the real
# excerpt: every line has a state and a health, and tracked frames a pose; with
# --objects it reads the dynamic-objects ring beside it, one line per frame; a
# writer restarted under it is followed to its new ring.
# Skips (77) without python3 or the excerpt.
# usage: consumer_kit_test.sh BIN_DIR SOURCE_DIR DATA_DIR WORK_DIR
set -uo pipefail
bin=$1 src=$2 data=$3/tum_fr3_teddy_200 work=$4
fail() { echo "FAIL: $*"; exit 1; }
command -v python3 >/dev/null || { echo "SKIP: no python3"; exit 77; }
[[ -f $data/rgb.txt ]] || { echo "SKIP: no excerpt at $data"; exit 77; }
rm -rf "$work" && mkdir -p "$work"
ring="sp_kit_$$"
cat > "$work/d.yaml" <<YAML
camera: fr3
lock_memory: false
source: {replay: {path: $data, paced: true}}
ipc: {shm: {enabled: true, name: $ring, capacity: 1024}}
YAML
"$bin/stillpointd" --config "$work/d.yaml" > "$work/d.out" 2> "$work/d.err" &
daemon=$!
trap 'kill $daemon 2>/dev/null; wait 2>/dev/null' EXIT
for _ in $(seq 1 100); do [[ -e /dev/shm/$ring ]] && break; sleep 0.1; done
[[ -e /dev/shm/$ring ]] || { cat "$work/d.err"; fail "no ring /dev/shm/$ring"; }
python3 "$src/ipc/examples/read_poses.py" --name "$ring" --objects --count 60 --timeout 20 > "$work/objects.txt" \
  2> "$work/objects.err" &
objects=$!
python3 "$src/ipc/examples/read_poses.py" --name "$ring" --count 60 --timeout 20 > "$work/poses.txt" 2> "$work/py.err" ||
  { cat "$work/py.err"; fail "read_poses.py failed"; }
wait $objects || { cat "$work/objects.err"; fail "read_poses.py --objects failed"; }
object_lines=$(grep -c "^frame=[0-9]* t=[0-9.]* map=0 objects=[0-9]*" "$work/objects.txt")
[[ $object_lines -eq 60 ]] || { head "$work/objects.txt"; fail "$object_lines frames of objects, expected 60"; }
lines=$(wc -l < "$work/poses.txt")
with_pose=$(grep -c "state=ok health=[a-z]* map=0 p=\[" "$work/poses.txt")
[[ $lines -eq 60 ]] || fail "$lines lines, expected 60"
[[ $with_pose -ge 50 ]] || { head "$work/poses.txt"; fail "only $with_pose of 60 poses tracked with a pose"; }
# Every pose with its covariance's standard deviations, none of them zero.
with_sigma=$(grep -cE "state=ok health=[a-z]* map=0 p=\[.* sigma_m=\[0\.0*[1-9][0-9]* 0\.0*[1-9][0-9]* 0\.0*[1-9][0-9]*\]" "$work/poses.txt")
[[ $with_sigma -eq $with_pose ]] || { head "$work/poses.txt"; fail "$with_sigma of $with_pose poses with a covariance"; }
# Frames arrive in order.
awk '{ split($1, a, "="); if (NR > 1 && a[2] <= last) exit 1; last = a[2] }' "$work/poses.txt" || fail "frames out of order"
# A restarted writer (a new ring at the name): the reader goes on with it.
probe_ring="sp_probe_kit$$"
"$bin/ipc_probe" pub --transport shm --suffix "_kit$$" --count 200 --rate 200 > /dev/null 2>&1 &
first=$!
for _ in $(seq 1 100); do [[ -e /dev/shm/$probe_ring ]] && break; sleep 0.02; done
python3 "$src/ipc/examples/read_poses.py" --name "$probe_ring" --count 250 --timeout 10 > "$work/restart.txt" \
  2> "$work/restart.err" &
reader=$!
wait $first
"$bin/ipc_probe" pub --transport shm --suffix "_kit$$" --count 200 --rate 200 > /dev/null 2>&1 ||
  fail "the second probe failed"
wait $reader || { cat "$work/restart.err"; fail "read_poses.py did not go on after the writer restarted"; }
grep -q "the writer restarted" "$work/restart.err" || { cat "$work/restart.err"; fail "no restart reported"; }
[[ $(grep -c "^frame=1 " "$work/restart.txt") -eq 1 ]] || fail "the new ring was not read from its first record"
rm -f "/dev/shm/$probe_ring" "/dev/shm/$probe_ring.lock"
echo "PASS: $lines poses read by the Python example, $with_pose tracked; $object_lines frames of objects;" \
  "a restarted writer followed"
