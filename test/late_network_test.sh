#!/usr/bin/env bash
# stillpointd with LCM on, started in a private network namespace this test
# creates before its network is up (no multicast route: LCM cannot open): the
# daemon must stay up, say "ipc down: lcm" in its status, and once the route
# exists publish poses that an LCM subscriber in the namespace receives.
# Nothing leaves the namespace (its loopback only). Skips (77) when not root,
# without `ip netns`, or without the bundled excerpt.
# usage: late_network_test.sh BIN_DIR DATA_DIR WORK_DIR
set -uo pipefail
bin=$1
data=$2/tum_fr3_teddy_200
work=$3
skip() { echo "SKIP: $*"; exit 77; }
fail() { echo "FAIL: $*"; exit 1; }
[[ $(id -u) -eq 0 ]] || skip "needs root to create a network namespace"
command -v ip >/dev/null || skip "iproute2 (ip) is not installed"
[[ -f $data/rgb.txt ]] || skip "no excerpt at $data"

ns="sp-late-$$-$RANDOM"
cleanup() {
  for p in $(ip netns pids "$ns" 2>/dev/null); do kill -KILL "$p" 2>/dev/null; done
  wait 2>/dev/null
  ip netns del "$ns" 2>/dev/null
}
trap cleanup EXIT
ip netns add "$ns" 2>/dev/null || skip "cannot create a network namespace"
in_ns() { ip netns exec "$ns" "$@"; }
in_ns ip link set lo up || fail "cannot bring up lo"

rm -rf "$work" && mkdir -p "$work"
url="udpm://239.255.76.67:7667?ttl=0"
cat > "$work/d.yaml" <<YAML
camera: fr3
log_level: info
lock_memory: false
status_period_s: 0.5
source: {replay: {path: $data, paced: true, loop: true}}
output: {status: $work/status.txt}
ipc:
  shm: {enabled: true, name: sp_late_$$, capacity: 1024}
  lcm: {enabled: true, url: "$url"}
YAML
ip netns exec "$ns" "$bin/stillpointd" --config "$work/d.yaml" > "$work/d.out" 2> "$work/d.err" &
daemon=$!

# Down first: the daemon runs, and says so.
for _ in $(seq 1 40); do
  grep -q "publishing without lcm" "$work/d.err" && break
  kill -0 $daemon 2>/dev/null || { cat "$work/d.err"; fail "stillpointd exited without a network"; }
  sleep 0.25
done
grep -q "publishing without lcm" "$work/d.err" || fail "no warning that lcm is down"
sleep 2
kill -0 $daemon 2>/dev/null || fail "stillpointd exited without a network"

# Then the network comes: poses arrive within the retry period.
in_ns ip route add 224.0.0.0/4 dev lo || fail "cannot add the multicast route"
timeout 20 ip netns exec "$ns" "$bin/stillpoint-echo" --lcm --url "$url" --count 20 > "$work/echo.out" 2> "$work/echo.err"
rc=$?
kill -TERM $daemon 2>/dev/null
wait $daemon
drc=$?
[[ $rc -eq 0 ]] || { cat "$work/echo.err"; fail "no poses over LCM after the route came up (echo exit $rc)"; }
poses=$(grep -c "^pose" "$work/echo.out")
[[ $poses -ge 20 ]] || fail "only $poses poses received"
grep -q "lcm: up" "$work/d.err" || fail "the daemon never said lcm is up"
[[ $drc -eq 0 ]] || fail "stillpointd exited $drc on SIGTERM"
echo "PASS: lcm down at start, up after the route, $poses poses received"
