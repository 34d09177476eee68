#!/usr/bin/env bash
# Publish -> receive latency between two processes for each transport (ipc_latency),
# run inside a private network namespace so LCM's multicast and DDS's traffic never
# leave its loopback. Needs root (ip netns add).
# usage: ipc/tools/latency-bench.sh [BIN_DIR] [COUNT] [RATE_HZ]
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
bin=${1:-$here/../../build/release/bin}
count=${2:-2000}
rate=${3:-200}
[[ $(id -u) -eq 0 ]] || { echo "latency-bench: needs root for ip netns" >&2; exit 1; }
ns="sp-ipc-bench-$$"
trap 'for p in $(ip netns pids "$ns" 2>/dev/null); do kill -KILL "$p"; done; ip netns del "$ns" 2>/dev/null' EXIT
ip netns add "$ns"
ip netns exec "$ns" ip link set lo up
ip netns exec "$ns" ip route add 224.0.0.0/4 dev lo
cfg="file://$here/../test/cyclonedds-loopback.xml"
run() { ip netns exec "$ns" "$bin/ipc_latency" --count "$count" --rate "$rate" "$@"; echo; }
echo "# $(date -u +%FT%TZ) $(nproc) cores, load: $(cut -d' ' -f1-3 /proc/loadavg)"
run --transport shm --busy-poll
run --transport shm
run --transport lcm
run --transport dds --dds-config "$cfg"
