#!/usr/bin/env bash
# Shared-memory ring under stress, real processes: a writer at 20 kHz, five readers
# (C99 and C++ builds of the header-only reader), some started before the writer, one
# late; the writer is killed (SIGKILL) and a new one takes over the ring. Every reader
# must see no torn and no out-of-order record; the early readers must see the restart.
# usage: shm_stress_test.sh BIN_DIR
set -uo pipefail
bin=$1
ring="sp_stress_$$"
fail() { echo "FAIL: $*"; exit 1; }
work=$(mktemp -d)
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null; done; wait 2>/dev/null
  rm -rf "$work"; rm -f "/dev/shm/$ring" "/dev/shm/$ring.lock"
}
trap cleanup EXIT
rm -f "/dev/shm/$ring"

readers=()
start_reader() {  # name exe seconds args...
  local name=$1; shift
  "$@" >"$work/$name.out" 2>&1 &
  pids+=($!); readers+=("$name:$!")
}
# Started before any writer exists: they wait for the ring, then must follow the restart.
start_reader early_c "$bin/shm_reader_c" "$ring" 4 --expect-restarts 1
start_reader early_cxx "$bin/shm_reader_cxx" "$ring" 4 --from-oldest --expect-restarts 1
start_reader early_c2 "$bin/shm_reader_c" "$ring" 4 --expect-restarts 1
sleep 0.1

"$bin/ipc_probe" shm-writer "$ring" 20000 100 >"$work/writer1.out" 2>&1 &
writer=$!; pids+=($writer)
sleep 0.7
start_reader late_cxx "$bin/shm_reader_cxx" "$ring" 2.6 --from-oldest --expect-restarts 1
start_reader short_c "$bin/shm_reader_c" "$ring" 0.5   # stops while the writer runs
sleep 0.9
kill -9 $writer; wait $writer 2>/dev/null   # crash: the ring still says "running"
"$bin/ipc_probe" shm-writer "$ring" 20000 1.5 >"$work/writer2.out" 2>&1 || { cat "$work/writer2.out"; fail "restarted writer failed"; }
cat "$work/writer2.out"

ok=1
for entry in "${readers[@]}"; do
  name=${entry%%:*}; pid=${entry##*:}
  wait "$pid"; rc=$?
  echo "$name: $(cat "$work/$name.out")"
  [[ $rc -eq 0 ]] || { echo "  ^ failed (exit $rc)"; ok=0; }
done
[[ $ok -eq 1 ]] || fail "a reader saw a torn or out-of-order record, no record, or missed the restart"
echo "PASS"
