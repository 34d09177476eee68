#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>

#include "stillpoint/ipc/options.hpp"
#include "stillpoint/ipc/ros2_frames.hpp"

namespace stillpoint::ipc {

TEST(IpcOptions, DefaultsAreValidAndKeepLcmOnThisHost) {
  IpcOptions o;
  EXPECT_TRUE(o.validate().ok());
  EXPECT_EQ(o.lcm.url, "udpm://239.255.76.67:7667?ttl=0");
  EXPECT_TRUE(o.shm.enabled);
  EXPECT_FALSE(o.lcm.enabled);
  EXPECT_FALSE(o.dds.enabled);
}

TEST(IpcOptions, ParsesEveryField) {
  const auto node = YAML::Load(R"(
queue_capacity: 16
shm: {enabled: false, name: my_ring, capacity: 256}
lcm: {enabled: true, url: "udpm://239.255.76.67:7700?ttl=0", pose_channel: P, status_channel: S}
dds: {enabled: true, domain_id: 7, config: "<CycloneDDS/>", pose_topic: pt, status_topic: st}
)");
  auto o = parseIpcOptions(node);
  ASSERT_TRUE(o.ok()) << o.error();
  EXPECT_EQ(o->queue_capacity, 16u);
  EXPECT_FALSE(o->shm.enabled);
  EXPECT_EQ(o->shm.name, "my_ring");
  EXPECT_EQ(o->shm.capacity, 256u);
  EXPECT_EQ(o->lcm.url, "udpm://239.255.76.67:7700?ttl=0");
  EXPECT_EQ(o->lcm.pose_channel, "P");
  EXPECT_EQ(o->dds.domain_id, 7u);
  EXPECT_EQ(o->dds.config, "<CycloneDDS/>");
  EXPECT_EQ(o->dds.status_topic, "st");
}

TEST(IpcOptions, ErrorsNameTheField) {
  struct Case {
    const char* yaml;
    const char* field;
  };
  const Case cases[] = {
      {"shm: {capacity: 1000}", "ipc.shm.capacity"},
      {"shm: {name: 'a/b'}", "ipc.shm.name"},
      {"lcm: {urll: x}", "ipc.lcm.urll"},
      {"dds: {domain_id: notanumber}", "ipc.dds.domain_id"},
      {"dds: {domain_id: 231}", "ipc.dds.domain_id"},
      {"queue_capacity: 0", "ipc.queue_capacity"},
      {"bogus: 1", "ipc.bogus"},
      {"lcm: {pose_channel: X, status_channel: X}", "ipc.lcm.pose_channel"},
      {"shm: {name: a, name: b}", "duplicate field 'ipc.shm.name'"},
      {"? [a, b]\n: 1", "plain names"},
      {"shm: {? [a, b] : 1}", "'ipc.shm.' must be plain names"},
      {"ros2: {odometry_topic: stillpoint/odometry}", "ipc.ros2.odometry_topic"},
      {"ros2: {tf_topic: tf}", "ipc.ros2.tf_topic"},
      {"ros2: {diagnostics_topic: diagnostics}", "ipc.ros2.diagnostics_topic"},
      {"ros2: {child_frame_id: map}", "ipc.ros2.child_frame_id"},
  };
  for (const auto& c : cases) {
    auto o = parseIpcOptions(YAML::Load(c.yaml));
    ASSERT_FALSE(o.ok()) << c.yaml;
    EXPECT_NE(o.error().find(c.field), std::string::npos) << c.yaml << " -> " << o.error();
  }
}

TEST(IpcOptions, LoadsTheIpcSectionOfAFile) {
  const std::string path = testing::TempDir() + "ipc_options_test.yaml";
  std::ofstream(path) << "tracking: {whatever: 1}\nipc:\n  shm:\n    name: from_file\n";
  auto o = loadIpcOptions(path);
  ASSERT_TRUE(o.ok()) << o.error();
  EXPECT_EQ(o->shm.name, "from_file");
  std::remove(path.c_str());
  auto missing = loadIpcOptions(path);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().find(path), std::string::npos);
}

}  // namespace stillpoint::ipc

namespace stillpoint::ipc {

// config/ipc.yaml documents every option with its default: keep the two in step.
TEST(IpcOptions, ShippedConfigEqualsTheDefaults) {
  auto o = loadIpcOptions(std::string(STILLPOINT_SOURCE_DIR) + "/config/ipc.yaml");
  ASSERT_TRUE(o.ok()) << o.error();
  const IpcOptions d;
  EXPECT_EQ(o->queue_capacity, d.queue_capacity);
  EXPECT_EQ(o->shm.enabled, d.shm.enabled);
  EXPECT_EQ(o->shm.name, d.shm.name);
  EXPECT_EQ(o->shm.capacity, d.shm.capacity);
  EXPECT_EQ(o->lcm.enabled, d.lcm.enabled);
  EXPECT_EQ(o->lcm.url, d.lcm.url);
  EXPECT_EQ(o->lcm.pose_channel, d.lcm.pose_channel);
  EXPECT_EQ(o->lcm.status_channel, d.lcm.status_channel);
  EXPECT_EQ(o->dds.enabled, d.dds.enabled);
  EXPECT_EQ(o->dds.domain_id, d.dds.domain_id);
  EXPECT_EQ(o->dds.config, d.dds.config);
  EXPECT_EQ(o->dds.pose_topic, d.dds.pose_topic);
  EXPECT_EQ(o->dds.status_topic, d.dds.status_topic);
}

}  // namespace stillpoint::ipc

namespace stillpoint::ipc {
namespace {

// A camera on a robot, 0.5 m up and pitched down 30 degrees: the robot drives
// 1 m forward. In the first camera's optical frame the camera moved by the
// world's x axis seen from it, (0, -sin 30, cos 30); the robot's base_link
// must come out 1 m along the map's x, level, with no rotation.
TEST(Ros2Frames, APitchedCameraOnADrivingRobotGivesTheBaseItsOwnMotion) {
  const double half = 0.5 * 30.0 * M_PI / 180.0;
  const Eigen::Isometry3d X = opticalInChild({0.2, 0.0, 0.5, 0.0, std::sin(half), 0.0, std::cos(half)});
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(0, -0.5, std::sqrt(3.0) / 2);
  const Eigen::Isometry3d base = childInMap(X, T);
  EXPECT_TRUE(base.translation().isApprox(Eigen::Vector3d(1, 0, 0), 1e-12)) << base.translation().transpose();
  EXPECT_TRUE(base.linear().isApprox(Eigen::Matrix3d::Identity(), 1e-12));
  // The first pose is the map's origin, whatever the mounting.
  EXPECT_TRUE(childInMap(X, Eigen::Isometry3d::Identity()).isApprox(Eigen::Isometry3d::Identity(), 1e-12));
  // The camera's own body frame (identity extrinsic): optical z forward is x.
  const Eigen::Isometry3d camera = childInMap(opticalInChild({0, 0, 0, 0, 0, 0, 1}), T);
  EXPECT_TRUE(camera.translation().isApprox(Eigen::Vector3d(std::sqrt(3.0) / 2, 0, 0.5), 1e-12));
}

// The odometry's covariance follows the pose into the ROS frames: poses drawn
// with a known covariance (stillpoint's order: centre, then rotation about the
// map's axes) and carried through childInMap spread as childCovarianceInMap says.
TEST(Ros2Frames, TheCovarianceFollowsThePoseIntoTheRosFrames) {
  const double half = 0.5 * 30.0 * M_PI / 180.0;
  const Eigen::Isometry3d X = opticalInChild({0.2, 0.1, 0.5, 0.0, std::sin(half), 0.0, std::cos(half)});
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d(0.2, 1, 0.3).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.4, -0.5, 2.0);
  Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Zero();
  A.diagonal() << 0.01, 0.02, 0.005, 0.02, 0.01, 0.03;
  A(0, 4) = 0.004;  // a position error that comes with a rotation error
  const Eigen::Matrix<double, 6, 6> covariance = A * A.transpose();
  const Eigen::Matrix<double, 6, 6> expected = childCovarianceInMap(X, T, covariance);
  const Eigen::Isometry3d P = childInMap(X, T);
  std::mt19937 rng(5);
  std::normal_distribution<double> unit(0.0, 1.0);
  Eigen::Matrix<double, 6, 6> spread = Eigen::Matrix<double, 6, 6>::Zero();
  const int draws = 20000;
  for (int k = 0; k < draws; ++k) {
    Eigen::Matrix<double, 6, 1> n;
    for (int i = 0; i < 6; ++i) n(i) = unit(rng);
    const Eigen::Matrix<double, 6, 1> e = A * n;
    Eigen::Isometry3d Te = T;
    Te.translation() += e.head<3>();
    Te.linear() = Eigen::AngleAxisd(e.tail<3>().norm(), e.tail<3>().normalized()).toRotationMatrix() * T.linear();
    const Eigen::Isometry3d Pe = childInMap(X, Te);
    Eigen::Matrix<double, 6, 1> d;
    d.head<3>() = Pe.translation() - P.translation();
    const Eigen::AngleAxisd turn(Pe.linear() * P.linear().transpose());
    d.tail<3>() = turn.angle() * turn.axis();
    spread += d * d.transpose() / draws;
  }
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c)
      EXPECT_NEAR(spread(r, c), expected(r, c), 0.05 * std::sqrt(expected(r, r) * expected(c, c)) + 1e-7)
          << "(" << r << ", " << c << ")";
}

TEST(Ros2Frames, ABadExtrinsicIsRefused) {
  IpcOptions o;
  o.ros2.camera_extrinsic = {0, 0, 0, 0, 0, 0, 2};
  EXPECT_FALSE(o.validate());
  o.ros2.camera_extrinsic = {0, 0, std::nan(""), 0, 0, 0, 1};
  EXPECT_FALSE(o.validate());
  auto parsed = parseIpcOptions(YAML::Load("ros2: {camera_extrinsic: [1, 2, 3]}"));
  ASSERT_FALSE(parsed);
  EXPECT_NE(parsed.error().find("camera_extrinsic"), std::string::npos) << parsed.error();
}

}  // namespace
}  // namespace stillpoint::ipc
