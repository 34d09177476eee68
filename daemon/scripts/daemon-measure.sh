#!/usr/bin/env bash
# Measurements of stillpointd (numbers in docs/results.md):
#   latency  - paced 30 Hz replay of the real excerpt as a live camera (drop-oldest
#              queue of capacity $QUEUE, default 2): dropped frames, pose latency (frame
#              in -> pose handed to the publisher) median / p99 / max, from the status file.
#              EXTRA adds YAML to the config, e.g. all modules on:
#              EXTRA='modules: {semantic: true, semantic_model_dirs: [../shared/models]}'
#   shutdown - N starts/stops: SIGTERM $WARMUP s (default 5) after the ring appears, time until the process
#              has exited (measured outside) and the daemon's own shutdown_ms
#   timing   - tracking time (SlamSystem::track, ORB included) with the dynamic-object modules
#              on against off, as the service runs: paced 30 Hz replay, the thread placement of
#              config/stillpointd.yaml (tracking SCHED_FIFO on core 1; needs root or CAP_SYS_NICE,
#              else the daemon warns and keeps normal scheduling). N rounds (default 5) of the
#              module sets in SETS (default "none geometry semantic geometry,semantic"),
#              interleaved; per-set medians of the runs' track_ms_median and the ratio to the
#              first set. Semantic runs take their models from STILLPOINT_MODEL_DIR (default
#              ../shared/models). THREADS='threads: {...}' replaces the placement.
#   rss      - looped paced replay for S seconds, VmRSS every 10 s with the map's keyframes and
#              points (from the daemon's STATUS= line, read from a NOTIFY_SOCKET of our own),
#              least-squares slope, and what the daemon held at the stop (status file)
# usage: daemon-measure.sh STILLPOINTD SEQUENCE_DIR latency|shutdown [N]|timing [N]|rss [SECONDS]
set -euo pipefail
bin=$1 seq=$2 what=$3
work=$(mktemp -d /tmp/stillpointd-measure.XXXXXX)
trap 'rm -rf "$work"' EXIT
ring=sp_measure_$$
cfg() {  # paced loop as_live
  cat > "$work/d.yaml" <<YAML
camera: fr3
log_level: warn
source: {queue_capacity: ${QUEUE:-2}, replay: {path: $seq, paced: $1, loop: $2, as_live: $3}}
output: {status: $work/status.txt, trajectory: "${traj:-}"}
ipc: {shm: {name: $ring}}
${EXTRA:-}
YAML
}
case $what in
  latency)
    traj=$work/traj.txt  # only here: a trajectory file makes the daemon keep every pose
    cfg true false true
    "$bin" --config "$work/d.yaml"
    grep -E '^(frames_|latency_|publisher_|semantic_)' "$work/status.txt"
    # The daemon's own trajectory against the ground truth (stillpoint-eval beside it).
    eval=$(dirname "$bin")/stillpoint-eval
    if [[ -x $eval && -f $seq/groundtruth.txt ]]; then "$eval" "$seq/groundtruth.txt" "$work/traj.txt"; fi
    ;;
  shutdown)
    n=${4:-20}
    cfg true true false
    for i in $(seq "$n"); do
      rm -f "$work/status.txt" "/dev/shm/$ring"  # the ring outlives a run: wait for this run's
      "$bin" --config "$work/d.yaml" 2> "$work/err.txt" &
      pid=$!
      # Wait for tracking to run (ring present and a few poses in), then stop.
      for _ in $(seq 200); do [[ -e /dev/shm/$ring ]] && break; sleep 0.05; done
      sleep "${WARMUP:-5}"
      t0=$(date +%s%N)
      kill -TERM $pid
      rc=0
      wait $pid || rc=$?
      t1=$(date +%s%N)
      (( rc == 0 )) || { echo "run $i: exit status $rc:"; tail -3 "$work/err.txt"; }
      echo "run $i: exit_ms=$(( (t1 - t0) / 1000000 )) $(grep -E '^(shutdown_ms|frames_processed)' "$work/status.txt" | tr '\n' ' ')"
    done
    ;;
  timing)
    rounds=${4:-5}
    read -r -a sets <<< "${SETS:-none geometry semantic geometry,semantic}"
    repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
    models=${STILLPOINT_MODEL_DIR:-$repo/../shared/models}
    placement=${THREADS:-$(sed -n '/^threads:/,/^$/p' "$repo/config/stillpointd.yaml")}
    for ((r = 1; r <= rounds; ++r)); do
      for s in "${sets[@]}"; do
        geometry=false semantic=false
        [[ ,$s, == *,geometry,* ]] && geometry=true
        [[ ,$s, == *,semantic,* ]] && semantic=true
        EXTRA="modules: {geometry: $geometry, semantic: $semantic, semantic_model_dirs: [$models]}
$placement"
        cfg true false false
        rm -f "$work/status.txt"
        "$bin" --config "$work/d.yaml" 2> "$work/err.txt" || { echo "$s: exit status $?:"; tail -3 "$work/err.txt"; }
        grep -q 'priority' "$work/err.txt" && { echo "$s: placement not applied:"; grep priority "$work/err.txt" | head -2; }
        [[ -f $work/status.txt ]] && sed -n 's/^track_ms_median=//p' "$work/status.txt" >> "$work/${s//,/+}.ms"
      done
    done
    "$repo/daemon/scripts/run-medians.sh" "$work" "track_ms_median" "${sets[@]}"
    ;;
  rss)
    secs=${4:-600}
    cfg true true false
    python3 -u -c '
import socket, sys
s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
s.bind(sys.argv[1])
while True:
    for line in s.recv(4096).decode().splitlines():
        if line.startswith("STATUS="): print(line[7:])
' "$work/notify.sock" > "$work/notify.txt" &
    listener=$!
    for _ in $(seq 50); do [[ -S $work/notify.sock ]] && break; sleep 0.1; done
    NOTIFY_SOCKET=$work/notify.sock "$bin" --config "$work/d.yaml" &
    pid=$!
    start=$(date +%s)
    while (( $(date +%s) - start < secs )); do
      sleep 10
      map=$(grep -o '[0-9]* keyframes [0-9]* points' "$work/notify.txt" | tail -1 || true)
      echo "$(( $(date +%s) - start )) $(awk '/VmRSS/ {print $2}' /proc/$pid/status) ${map:-map ? keyframes ? points}"
    done | tee "$work/rss.txt"
    kill -TERM $pid; wait $pid || true
    kill $listener; wait $listener 2>/dev/null || true
    awk '{n++; sx+=$1; sy+=$2; sxx+=$1*$1; sxy+=$1*$2} END {s=(n*sxy-sx*sy)/(n*sxx-sx*sx); printf "rss slope %.2f kB/min over %d samples (first %d kB, last %d kB)\n", s*60, n, first, $2} NR==1 {first=$2}' "$work/rss.txt"
    grep -E '^(frames_processed|frames_lost|map_|keyframes_in_memory|points_in_memory|trajectory_records)' "$work/status.txt"
    ;;
  *) echo "usage: $0 STILLPOINTD SEQUENCE_DIR latency|shutdown [N]|timing [N]|rss [SECONDS]" >&2; exit 2 ;;
esac
rm -f /dev/shm/$ring /dev/shm/$ring.lock
