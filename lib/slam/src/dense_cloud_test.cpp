#include "dense_cloud.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>

namespace stillpoint::slam {
namespace {

CameraModel camera() {
  CameraModel c;
  c.width = 640;
  c.height = 480;
  c.fx = c.fy = 525;
  c.cx = 319.5;
  c.cy = 239.5;
  return c;
}

// What a camera at (x, 0, 0) looking along +z sees of a wall at z = 3 (the
// same depth from any x); with a person, a box at depth 1.5 m over the middle
// of the image.
DenseView wallView(bool person, bool person_marked) {
  cv::Mat depth(480, 640, CV_32F, cv::Scalar(3.0f)), bgr(480, 640, CV_8UC3, cv::Scalar(40, 80, 160));
  cv::Mat moving;
  if (person) {
    depth(cv::Rect(280, 160, 80, 200)).setTo(1.5f);
    bgr(cv::Rect(280, 160, 80, 200)).setTo(cv::Scalar(0, 200, 0));
    if (person_marked) {
      moving = cv::Mat::zeros(480, 640, CV_8U);
      moving(cv::Rect(280, 160, 80, 200)).setTo(1);
    }
  }
  return makeDenseView(depth, bgr, moving);
}

SE3 at(double x) {
  SE3 T_c_w = SE3::Identity();
  T_c_w.translation() = Vec3(-x, 0, 0);
  return T_c_w;
}

std::size_t nearerThan(const DenseCloud& cloud, float z) {
  std::size_t n = 0;
  for (const ColouredPoint& p : cloud.points) n += p.z < z;
  return n;
}

TEST(DenseCloud, AMoverOtherViewsSawThroughLeavesNoGhost) {
  std::vector<PosedView> views;
  // The person stands there in the first view only; five later views see the wall.
  views.push_back({std::make_shared<DenseView>(wallView(true, false)), at(0.0)});
  for (double x : {-0.2, -0.1, 0.0, 0.1, 0.2}) views.push_back({std::make_shared<DenseView>(wallView(false, false)), at(x)});

  DenseCloudOptions keep;
  keep.carve = false;
  const DenseCloud ghosted = fuseDenseCloud(views, camera(), keep);
  EXPECT_GT(nearerThan(ghosted, 2.5f), 500u);  // without carving the person stays

  const DenseCloud carved = fuseDenseCloud(views, camera());
  EXPECT_EQ(nearerThan(carved, 2.5f), 0u);
  EXPECT_GT(carved.carved, 500u);
  // The wall stays, in its colour.
  std::size_t wall = 0;
  for (const ColouredPoint& p : carved.points)
    if (std::abs(p.z - 3.0f) < 0.05f) {
      ++wall;
      EXPECT_EQ(p.r, 160);
    }
  EXPECT_GT(wall, 10000u);
}

TEST(DenseCloud, MarkedPixelsAndStaticObjectsSeenFromOneSide) {
  // Marked as moving: left out, even with nothing to carve it.
  std::vector<PosedView> marked{{std::make_shared<DenseView>(wallView(true, true)), at(0.0)}};
  EXPECT_EQ(nearerThan(fuseDenseCloud(marked, camera()), 2.5f), 0u);
  // A static box every view sees stays: agreeing views outnumber none.
  std::vector<PosedView> still;
  for (double x : {-0.1, 0.0, 0.1}) still.push_back({std::make_shared<DenseView>(wallView(true, false)), at(x)});
  const DenseCloud cloud = fuseDenseCloud(still, camera());
  EXPECT_GT(nearerThan(cloud, 2.5f), 500u);
}

TEST(DenseCloud, WritesABinaryPly) {
  const auto path = std::filesystem::temp_directory_path() / "stillpoint_dense_cloud_test.ply";
  const std::vector<ColouredPoint> points{{1, 2, 3, 10, 20, 30}, {4, 5, 6, 40, 50, 60}};
  ASSERT_TRUE(writePly(path.string(), points, "test").ok());
  std::ifstream in(path, std::ios::binary);
  const std::string bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  const std::size_t end = bytes.find("end_header\n");
  ASSERT_NE(end, std::string::npos);
  EXPECT_NE(bytes.find("element vertex 2\n"), std::string::npos);
  EXPECT_EQ(bytes.size() - end - 11, 2u * 15u);
  std::filesystem::remove(path);
  EXPECT_FALSE(writePly("/nonexistent/dir/x.ply", points, "test").ok());
}

}  // namespace
}  // namespace stillpoint::slam
