#!/usr/bin/env bash
# stillpoint-echo: usage errors (exit 2), a missing ring (exit 1, says so), files that
# are not a ring of ours at the ring's path (exit 1 at once, naming the path), poses read
# from a ring that a separate publisher process fills, and that publisher killed (exit 1,
# "writer gone", instead of waiting forever).
# usage: echo_cli_test.sh BIN_DIR
set -uo pipefail
bin=$1
echo_=$bin/stillpoint-echo
fail() { echo "FAIL: $*"; exit 1; }
work=$(mktemp -d)
suffix="_echo$$"
pub=
hostile=/dev/shm/sp_hostile$suffix
cleanup() {
  [[ -n $pub ]] && kill -9 "$pub" 2>/dev/null; wait 2>/dev/null; rm -rf "$work"
  rm -f "/dev/shm/sp_probe$suffix" "/dev/shm/sp_probe$suffix.lock" "$hostile"
}
trap cleanup EXIT

expect() {  # expected_exit expected_stderr_text args...
  local want=$1 text=$2; shift 2
  timeout 10 "$echo_" "$@" >"$work/out" 2>"$work/err"; local rc=$?
  [[ $rc -ne 124 ]] || fail "stillpoint-echo $* still running after 10 s"
  [[ $rc -eq $want ]] || { cat "$work/err"; fail "stillpoint-echo $* exited $rc, expected $want"; }
  grep -qF -- "$text" "$work/err" || { cat "$work/err"; fail "stillpoint-echo $*: stderr lacks '$text'"; }
}
expect 2 "choose a transport" 
expect 2 "choose one of" --shm --lcm
expect 2 "unknown argument '--bogus'" --shm --bogus
expect 2 "bad number 'abc' for --count" --shm --count abc
expect 2 "--domain out of range" --dds --domain 999
expect 2 "--seconds needs a value" --shm --seconds
expect 1 "no pose ring of that name" --shm --name "sp_missing_$$"
expect 1 "ipc.shm.name must be" --shm --name "../x"
expect 1 "cannot be opened" --shm --config "$work/nonexistent.yaml"
expect 1 "not of the form provider://" --lcm --url "239.255.76.67:7667"
mkfifo "$hostile"
expect 1 "$hostile is a FIFO" --shm --name "sp_hostile$suffix"
rm -f "$hostile"; ln -s /dev/null "$hostile"
expect 1 "$hostile is a symbolic link" --shm --name "sp_hostile$suffix"
rm -f "$hostile"
echo "usage and error cases: ok"

"$bin/ipc_probe" pub --transport shm --suffix "$suffix" --count 2000 --rate 200 --timeout 30 >/dev/null 2>&1 &
pub=$!
for _ in $(seq 100); do [[ -e /dev/shm/sp_probe$suffix ]] && break; sleep 0.05; done
timeout 20 "$echo_" --shm --name "sp_probe$suffix" --count 5 >"$work/out" 2>"$work/err" \
  || { cat "$work/err"; fail "stillpoint-echo --shm failed"; }
cat "$work/out"
[[ $(grep -c '^pose frame=' "$work/out") -ge 5 ]] || fail "expected 5 pose lines"
grep -q 'map=c0ffee' "$work/out" || fail "pose line lacks the map id"
expect 1 "is owned by uid $(id -u), not by uid 65534" --shm --name "sp_probe$suffix" --owner 65534
timeout 20 "$echo_" --shm --name "sp_probe$suffix" --owner "$(id -un)" --count 1 >/dev/null 2>"$work/err" \
  || { cat "$work/err"; fail "stillpoint-echo --owner $(id -un) failed"; }

# The publisher killed while stillpoint-echo reads: the ring still says "running", but
# its writer's lock is gone with the process.
timeout 20 "$echo_" --shm --name "sp_probe$suffix" >"$work/out" 2>"$work/err" &
reader=$!
for _ in $(seq 200); do grep -q '^pose frame=' "$work/out" 2>/dev/null && break; sleep 0.05; done
grep -q '^pose frame=' "$work/out" || fail "stillpoint-echo printed no pose before the kill"
kill -9 "$pub"; wait "$pub" 2>/dev/null; pub=
wait "$reader"; rc=$?
cat "$work/err"
[[ $rc -ne 124 ]] || fail "stillpoint-echo still waiting 20 s after its writer was killed"
[[ $rc -eq 1 ]] || fail "stillpoint-echo exited $rc after its writer was killed, expected 1"
grep -q "writer gone" "$work/err" || fail "stillpoint-echo did not say the writer is gone"
# Started on the dead ring: says so at once.
expect 1 "writer gone" --shm --name "sp_probe$suffix"
echo "PASS"
