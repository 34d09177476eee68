"""A ROS 2-typed reader that is not stillpoint's: PyPI cyclonedds with the
ROS 2 message types written here from their .msg definitions, reliable
readers (ROS 2's default QoS) on the pose, odometry and tf topics, and every
sample decoded again by PyPI rosbags as geometry_msgs/msg/PoseStamped,
nav_msgs/msg/Odometry and tf2_msgs/msg/TFMessage. The odometry and tf samples
must carry the pose of the PoseStamped with the same stamp. Writes the poses
as a TUM trajectory (header stamps) for the ATE.

The status comes as diagnostic_msgs/msg/DiagnosticArray on the diagnostics topic,
the dynamic objects as visualization_msgs/msg/MarkerArray (one per pose, opening
with a DELETEALL, then a CUBE and a TEXT_VIEW_FACING per object) and the static
map as sensor_msgs/msg/PointCloud2 (x, y, z float32 around the trajectory).

usage: ros2_python_check.py CONFIG_URI POSE_TOPIC ODOMETRY_TOPIC TF_TOPIC DIAGNOSTICS_TOPIC MIN_SAMPLES TIMEOUT_S
                            OUT_TRAJ READY_FILE OBJECTS_TOPIC MAP_CLOUD_TOPIC
"""
import math
import os
import struct
import sys
import time
from dataclasses import dataclass

from cyclonedds.core import Qos, Policy
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, int32, sequence, uint8, uint32, float32, float64
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration
from rosbags.typesys import Stores, get_typestore


@dataclass
class Time_(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header_(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time_
    frame_id: str


@dataclass
class Point_(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion_(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Pose_(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point_
    orientation: Quaternion_


@dataclass
class PoseStamped_(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header_
    pose: Pose_


@dataclass
class Vector3_(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@dataclass
class PoseWithCovariance_(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose_
    covariance: array[float64, 36]


@dataclass
class Twist_(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3_
    angular: Vector3_


@dataclass
class TwistWithCovariance_(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist_
    covariance: array[float64, 36]


@dataclass
class Odometry_(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header_
    child_frame_id: str
    pose: PoseWithCovariance_
    twist: TwistWithCovariance_


@dataclass
class Transform_(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3_
    rotation: Quaternion_


@dataclass
class TransformStamped_(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header_
    child_frame_id: str
    transform: Transform_


@dataclass
class TFMessage_(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped_]


@dataclass
class KeyValue_(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@dataclass
class DiagnosticStatus_(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: uint8
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue_]


@dataclass
class DiagnosticArray_(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header_
    status: sequence[DiagnosticStatus_]


@dataclass
class Duration_(IdlStruct, typename="builtin_interfaces::msg::dds_::Duration_"):
    sec: int32
    nanosec: uint32


@dataclass
class ColorRGBA_(IdlStruct, typename="std_msgs::msg::dds_::ColorRGBA_"):
    r: float32
    g: float32
    b: float32
    a: float32


@dataclass
class CompressedImage_(IdlStruct, typename="sensor_msgs::msg::dds_::CompressedImage_"):
    header: Header_
    format: str
    data: sequence[uint8]


@dataclass
class UVCoordinate_(IdlStruct, typename="visualization_msgs::msg::dds_::UVCoordinate_"):
    u: float32
    v: float32


@dataclass
class MeshFile_(IdlStruct, typename="visualization_msgs::msg::dds_::MeshFile_"):
    filename: str
    data: sequence[uint8]


@dataclass
class Marker_(IdlStruct, typename="visualization_msgs::msg::dds_::Marker_"):
    header: Header_
    ns: str
    id: int32
    type: int32
    action: int32
    pose: Pose_
    scale: Vector3_
    color: ColorRGBA_
    lifetime: Duration_
    frame_locked: bool
    points: sequence[Point_]
    colors: sequence[ColorRGBA_]
    texture_resource: str
    texture: CompressedImage_
    uv_coordinates: sequence[UVCoordinate_]
    text: str
    mesh_resource: str
    mesh_file: MeshFile_
    mesh_use_embedded_materials: bool


@dataclass
class MarkerArray_(IdlStruct, typename="visualization_msgs::msg::dds_::MarkerArray_"):
    markers: sequence[Marker_]


@dataclass
class PointField_(IdlStruct, typename="sensor_msgs::msg::dds_::PointField_"):
    name: str
    offset: uint32
    datatype: uint8
    count: uint32


@dataclass
class PointCloud2_(IdlStruct, typename="sensor_msgs::msg::dds_::PointCloud2_"):
    header: Header_
    height: uint32
    width: uint32
    fields: sequence[PointField_]
    is_bigendian: bool
    point_step: uint32
    row_step: uint32
    data: sequence[uint8]
    is_dense: bool


def check_markers(msg):
    """A DELETEALL, then per object a box and its label in the map frame."""
    m = msg.markers
    if len(m) < 1 or m[0].action != 3 or len(m) % 2 != 1:
        return False
    for box, text in zip(m[1::2], m[2::2]):
        if (box.type != 1 or text.type != 9 or box.id != text.id or box.header.frame_id != "map"
                or min(box.scale.x, box.scale.y, box.scale.z) < 0.05 or not text.text
                or not all(math.isfinite(v) for v in (box.pose.position.x, box.pose.position.y, box.pose.position.z))):
            return False
    return True


def check_cloud(msg):
    """x, y, z float32, little-endian, every point finite and within 20 m (a depth camera's range) of the map's origin."""
    names = [(f.name, f.offset, f.datatype, f.count) for f in msg.fields]
    if (names != [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1)] or msg.is_bigendian or msg.point_step != 12
            or msg.height != 1 or msg.width < 100 or len(msg.data) != 12 * msg.width or msg.header.frame_id != "map"):
        print(f"ros2 reader: malformed PointCloud2: fields {names}, {msg.height}x{msg.width}, {len(msg.data)} bytes")
        return False
    for k in range(msg.width):
        x, y, z = struct.unpack_from("<fff", bytes(msg.data[12 * k:12 * k + 12]))
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)) or x * x + y * y + z * z > 400:
            print(f"ros2 reader: PointCloud2 point {k} of {msg.width} at ({x}, {y}, {z})")
            return False
    return True


def main():
    config, topic, odom_topic, tf_topic, diag_topic, min_samples, timeout_s, out_path, ready = sys.argv[1:10]
    objects_topic, cloud_topic = sys.argv[10:12]
    min_samples, timeout_s = int(min_samples), float(timeout_s)
    domain = Domain(0, config)
    participant = DomainParticipant(0)
    qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.History.KeepLast(100))
    reader = DataReader(participant, Topic(participant, topic, PoseStamped_), qos=qos)
    odom_reader = DataReader(participant, Topic(participant, odom_topic, Odometry_), qos=qos)
    tf_reader = DataReader(participant, Topic(participant, tf_topic, TFMessage_), qos=qos)
    diag_reader = DataReader(participant, Topic(participant, diag_topic, DiagnosticArray_), qos=qos)
    objects_reader = DataReader(participant, Topic(participant, objects_topic, MarkerArray_), qos=qos)
    cloud_reader = DataReader(participant, Topic(participant, cloud_topic, PointCloud2_), qos=qos)
    odometry, transforms, diagnostics = {}, {}, []
    marker_arrays, markers_bad, clouds, clouds_bad, cloud_points = 0, 0, 0, 0, 0
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    open(ready, "w").close()
    poses, bad = [], 0
    deadline = time.time() + timeout_s
    quiet_since = time.time()
    while time.time() < deadline:
        got = reader.take(N=64)
        if got:
            quiet_since = time.time()
        for sample in got:
            if not isinstance(sample, PoseStamped_):
                continue  # the writer going away (an invalid sample: no data)
            raw = sample.serialize()  # CDR with its encapsulation header, as on the wire
            msg = typestore.deserialize_cdr(raw, "geometry_msgs/msg/PoseStamped")
            q = msg.pose.orientation
            ok = (msg.header.frame_id == sample.header.frame_id == "map"
                  and abs(math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w) - 1) < 1e-6
                  and msg.pose.position.x == sample.pose.position.x
                  and msg.header.stamp.nanosec == sample.header.stamp.nanosec)
            bad += not ok
            poses.append(msg)
        for sample in odom_reader.take(N=64):
            if isinstance(sample, Odometry_):
                msg = typestore.deserialize_cdr(sample.serialize(), "nav_msgs/msg/Odometry")
                odometry[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = msg
        for sample in tf_reader.take(N=64):
            if isinstance(sample, TFMessage_):
                msg = typestore.deserialize_cdr(sample.serialize(), "tf2_msgs/msg/TFMessage")
                for t in msg.transforms:
                    transforms[(t.header.stamp.sec, t.header.stamp.nanosec)] = t
        for sample in objects_reader.take(N=64):
            if isinstance(sample, MarkerArray_):
                msg = typestore.deserialize_cdr(sample.serialize(), "visualization_msgs/msg/MarkerArray")
                marker_arrays += 1
                markers_bad += not check_markers(msg)
        for sample in cloud_reader.take(N=4):
            if isinstance(sample, PointCloud2_):
                msg = typestore.deserialize_cdr(sample.serialize(), "sensor_msgs/msg/PointCloud2")
                clouds += 1
                clouds_bad += not check_cloud(msg)
                cloud_points = max(cloud_points, msg.width)
        for sample in diag_reader.take(N=16):
            if isinstance(sample, DiagnosticArray_):
                diagnostics.append(typestore.deserialize_cdr(sample.serialize(), "diagnostic_msgs/msg/DiagnosticArray"))
        if len(poses) >= min_samples and time.time() - quiet_since > 2.0:
            break
        time.sleep(0.01)
    # Back to the camera's optical axes (REP-103 x forward, y left, z up from
    # optical z forward, x right, y down: p_ros = C p_opt, R_ros = C R_opt C^T),
    # so that relative errors compare with the ground truth's optical frames.
    C = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]
    def matmul(a, b):
        return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    Ct = [[C[j][i] for j in range(3)] for i in range(3)]
    with open(out_path, "w") as f:
        for m in poses:
            p, q = m.pose.position, m.pose.orientation
            x, y, z, w = q.x, q.y, q.z, q.w
            R = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
            Ro = matmul(matmul(Ct, R), C)
            po = [sum(Ct[i][k] * v for k, v in enumerate((p.x, p.y, p.z))) for i in range(3)]
            qw = math.sqrt(max(0.0, 1 + Ro[0][0] + Ro[1][1] + Ro[2][2])) / 2
            qx = math.copysign(math.sqrt(max(0.0, 1 + Ro[0][0] - Ro[1][1] - Ro[2][2])) / 2, Ro[2][1] - Ro[1][2])
            qy = math.copysign(math.sqrt(max(0.0, 1 - Ro[0][0] + Ro[1][1] - Ro[2][2])) / 2, Ro[0][2] - Ro[2][0])
            qz = math.copysign(math.sqrt(max(0.0, 1 - Ro[0][0] - Ro[1][1] + Ro[2][2])) / 2, Ro[1][0] - Ro[0][1])
            f.write(f"{m.header.stamp.sec}.{m.header.stamp.nanosec:09d} {po[0]} {po[1]} {po[2]} {qx} {qy} {qz} {qw}\n")
    # Odometry and tf: one per pose, the same pose. The odometry's covariance is
    # a pose's, not a variance or another unit: symmetric, positive definite
    # (Cholesky), position standard deviations between 0.1 mm and 1 m, rotation
    # ones under 1 rad. How wide it is follows the pose's evidence
    # (docs/pose-health.md): on a CPU starved by other work a few poses of the
    # excerpt can be wide (an unreliable one gains 5 cm per axis); the median
    # one is under 5 cm.
    def covariance_problem(c):
        a = [[c[6 * i + j] for j in range(6)] for i in range(6)]
        if any(abs(a[i][j] - a[j][i]) > 1e-9 * (abs(a[i][i]) + abs(a[j][j])) for i in range(6) for j in range(6)):
            return "not symmetric"
        low = [[0.0] * 6 for _ in range(6)]
        for i in range(6):
            for j in range(i + 1):
                v = a[i][j] - sum(low[i][k] * low[j][k] for k in range(j))
                if i == j:
                    if not v > 0:
                        return "not positive definite"
                    low[i][i] = math.sqrt(v)
                else:
                    low[i][j] = v / low[j][j]
        sigmas = [math.sqrt(a[k][k]) for k in range(6)]
        if not (all(1e-4 < s < 1.0 for s in sigmas[:3]) and all(s < 1.0 for s in sigmas[3:])):
            return "standard deviations " + ", ".join(f"{s:.3g}" for s in sigmas)
        return None
    position_sigmas = []
    odom_bad = tf_bad = 0
    for m in poses:
        key = (m.header.stamp.sec, m.header.stamp.nanosec)
        o, t = odometry.get(key), transforms.get(key)
        p, q = m.pose.position, m.pose.orientation
        if (o is None or o.header.frame_id != "map" or o.child_frame_id != "camera_link"
                or (o.pose.pose.position.x, o.pose.pose.position.y, o.pose.pose.position.z) != (p.x, p.y, p.z)
                or (o.pose.pose.orientation.w, o.pose.pose.orientation.x) != (q.w, q.x)
                or o.twist.covariance[0] != -1.0):
            odom_bad += 1
            print(f"ros2 reader: odometry at {key[0]}.{key[1]:09d}: " + ("missing" if o is None else "not the pose"))
            continue
        problem = covariance_problem(o.pose.covariance)
        position_sigmas.append(max(math.sqrt(o.pose.covariance[7 * k]) for k in range(3)))
        if problem:
            odom_bad += 1
            print(f"ros2 reader: odometry at {key[0]}.{key[1]:09d}: covariance {problem}")
        if (t is None or t.header.frame_id != "map" or t.child_frame_id != "camera_link"
                or (t.transform.translation.x, t.transform.translation.y, t.transform.translation.z) != (p.x, p.y, p.z)
                or (t.transform.rotation.w, t.transform.rotation.z) != (q.w, q.z)):
            tf_bad += 1
    print(f"ros2 reader: {len(poses)} PoseStamped samples, {bad} that rosbags decoded differently or malformed; "
          f"{len(odometry)} Odometry, {odom_bad} missing or not the pose; {len(transforms)} tf, {tf_bad} missing or "
          f"not the pose")
    position_sigmas.sort()
    median_sigma = position_sigmas[len(position_sigmas) // 2] if position_sigmas else math.inf
    print(f"ros2 reader: odometry position standard deviation: median {median_sigma:.4f} m, "
          f"{sum(s >= 0.05 for s in position_sigmas)} of {len(position_sigmas)} poses at 5 cm or more")
    # Diagnostics: one status "stillpoint" per status message, its fields as values (what
    # lowered the pose health named unless it is good or lost); while the excerpt plays,
    # tracking with a good pose is OK.
    diag_bad, tracking_ok = 0, 0
    for d in diagnostics:
        s = d.status[0] if len(d.status) == 1 else None
        values = {kv.key: kv.value for kv in s.values} if s else {}
        if s is None or s.name != "stillpoint" or s.level not in (0, 1) or "tracking_state" not in values \
                or "pose_health" not in values or "tracking.loop_rate_hz" not in values \
                or "semantic_mask_age_s" not in values \
                or (values.get("pose_health_causes") == "none") != (values["pose_health"] in ("good", "lost")):
            diag_bad += 1
            continue
        tracking_ok += s.level == 0 and values["tracking_state"] == "ok" and values["pose_health"] == "good"
    print(f"ros2 reader: {len(diagnostics)} DiagnosticArray, {diag_bad} malformed, {tracking_ok} OK with a good pose")
    print(f"ros2 reader: {marker_arrays} MarkerArray, {markers_bad} malformed; {clouds} PointCloud2 "
          f"(up to {cloud_points} points), {clouds_bad} malformed")
    del domain
    diag_ok = len(diagnostics) >= 3 and diag_bad == 0 and tracking_ok >= 2
    objects_ok = marker_arrays >= min_samples and markers_bad == 0
    cloud_ok = clouds >= 2 and clouds_bad == 0
    return 0 if (len(poses) >= min_samples and bad == 0 and odom_bad == 0 and median_sigma < 0.05
                 and tf_bad == 0 and diag_ok and objects_ok
                 and cloud_ok) else 1


if __name__ == "__main__":
    sys.exit(main())
