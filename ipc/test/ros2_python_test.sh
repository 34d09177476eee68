#!/usr/bin/env bash
# ROS 2 on the wire without ROS: stillpointd replays the real excerpt at its
# recorded rate with ipc.ros2 on, confined to loopback; a reader stillpoint
# did not write (PyPI cyclonedds, ROS 2 types written independently, ROS 2's
# default reliable QoS) takes rt/stillpoint/pose, /odometry and rt/tf, PyPI
# rosbags decodes every sample as geometry_msgs/msg/PoseStamped,
# nav_msgs/msg/Odometry and tf2_msgs/msg/TFMessage, odometry and tf must carry
# each pose, the status arrives as diagnostic_msgs/msg/DiagnosticArray, and the
# poses are compared with the ground truth. Dynamic objects come as
# visualization_msgs/msg/MarkerArray with every pose, the map as
# sensor_msgs/msg/PointCloud2 every second. Skips (77) without the Python modules or the excerpt.
# usage: ros2_python_test.sh PYTHON BIN_DIR DATA_DIR WORK_DIR LOOPBACK_XML
set -uo pipefail
py=$1 bin=$2 data=$3 work=$4 xml=$5
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
seq=$data/tum_fr3_teddy_200
[[ -d $seq ]] || { echo "SKIP: $seq not found"; exit 77; }
"$py" -c "import cyclonedds.domain, rosbags.typesys" 2>/dev/null ||
  { echo "SKIP: $py lacks cyclonedds or rosbags (pip install cyclonedds rosbags)"; exit 77; }
fail() { echo "FAIL: $*"; exit 1; }
rm -rf "$work" && mkdir -p "$work"
topic="rt/stillpoint/pose_t$$" odom_topic="rt/stillpoint/odometry_t$$" tf_topic="rt/tf_t$$" diag_topic="rt/diagnostics_t$$" \
  objects_topic="rt/stillpoint/dynamic_objects_t$$" cloud_topic="rt/stillpoint/map_cloud_t$$"
cat > "$work/d.yaml" <<YAML
camera: fr3
source: {replay: {path: $seq, paced: true}}
ipc:
  shm: {enabled: false}
  ros2: {enabled: true, config: "file://$xml", pose_topic: "$topic", odometry_topic: "$odom_topic", tf_topic: "$tf_topic",
         diagnostics_topic: "$diag_topic", objects_topic: "$objects_topic", map_cloud_topic: "$cloud_topic",
         map_cloud_period_s: 1.0}
YAML
"$py" "$here/ros2_python_check.py" "file://$xml" "$topic" "$odom_topic" "$tf_topic" "$diag_topic" 184 60 "$work/ros2.txt" "$work/ready" \
  "$objects_topic" "$cloud_topic" > "$work/reader.out" 2>&1 &
reader=$!
for _ in $(seq 100); do [[ -f $work/ready ]] && break; sleep 0.1; done
[[ -f $work/ready ]] || fail "reader did not start: $(cat "$work/reader.out")"
sleep 1  # discovery
"$bin/stillpointd" --config "$work/d.yaml" > "$work/daemon.out" 2>&1 || fail "stillpointd: $(tail -n 3 "$work/daemon.out")"
wait $reader; rc=$?
cat "$work/reader.out"
[[ $rc -eq 0 ]] || fail "the ROS 2 reader missed poses or decoded them differently"
# The reader wrote the poses back in the camera's optical axes, so relative
# errors compare with the ground truth's frames. Header stamps are on the
# system clock (the camera's clock plus a fixed offset): move them back by the
# offset between the first pose and the first colour frame.
first=$(awk '!/^#/ {print $1; exit}' "$seq/rgb.txt")
awk -v first="$first" 'NR == 1 {off = $1 - first} {printf "%.6f %s %s %s %s %s %s %s\n", $1 - off, $2, $3, $4, $5, $6, $7, $8}' \
  "$work/ros2.txt" > "$work/camera-clock.txt"
line=$("$bin/stillpoint-eval" "$seq/groundtruth.txt" "$work/camera-clock.txt") || fail "stillpoint-eval: $line"
echo "ROS 2 poses vs ground truth: $line"
ate=$(sed -n 's/.*ate_rmse_m=\([0-9.]*\).*/\1/p' <<<"$line")
awk -v a="$ate" 'BEGIN {exit !(a <= 0.01)}' || fail "ATE $ate m over 0.01 m"
# A wrong axis convention keeps positions right but turns every relative rotation.
rot=$(sed -n 's/.*rpe_rot_deg_s=\([0-9.]*\).*/\1/p' <<<"$line")
awk -v r="$rot" 'BEGIN {exit !(r <= 2.0)}' || fail "RPE rotation $rot deg/s: the orientations are not the camera's"
echo "PASS"
