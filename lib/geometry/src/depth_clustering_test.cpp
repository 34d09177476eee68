#include "stillpoint/geometry/depth_clustering.hpp"

#include "stillpoint/geometry/clustering_worker.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <map>
#include <set>
#include <thread>

namespace stillpoint::geometry {
namespace {

CameraModel vga() {
  auto cam = cameraPreset("fr3");
  EXPECT_TRUE(cam.ok());
  return *cam;
}

// A back wall at 3 m, a floor-level block at 1.5 m on the left, and a box
// at 0.8 m in the middle: three surfaces at clearly different depths.
cv::Mat threeSurfaces(cv::Rect box = {260, 180, 120, 120}) {
  cv::Mat depth(480, 640, CV_32F, cv::Scalar(3.0f));
  depth(cv::Rect(0, 240, 200, 240)).setTo(1.5f);
  depth(box).setTo(0.8f);
  return depth;
}

// Which clusters the samples inside `region` (full-resolution pixels) fall into.
std::set<int> clustersIn(const DepthClusters& c, cv::Rect region) {
  std::set<int> out;
  for (int r = 0; r < c.labels.rows; ++r)
    for (int col = 0; col < c.labels.cols; ++col) {
      const cv::Point centre(col * c.step + c.step / 2, r * c.step + c.step / 2);
      if (region.contains(centre) && c.labels.at<std::int16_t>(r, col) >= 0)
        out.insert(c.labels.at<std::int16_t>(r, col));
    }
  return out;
}

TEST(DepthClustering, SeparatesSurfacesAtDifferentDepths) {
  const CameraModel cam = vga();
  DepthClusterer clusterer;
  auto c = clusterer.cluster(threeSurfaces(), cam);
  ASSERT_TRUE(c.ok()) << c.error();
  EXPECT_EQ(c->clusters, 24);
  EXPECT_EQ(c->step, 8);
  const std::set<int> box = clustersIn(*c, {260, 180, 120, 120});
  const std::set<int> block = clustersIn(*c, {0, 240, 200, 240});
  std::set<int> wall;
  for (int r = 0; r < c->labels.rows; ++r)
    for (int col = 0; col < c->labels.cols; ++col) {
      const cv::Point p(col * 8 + 4, r * 8 + 4);
      if (!cv::Rect(260, 180, 120, 120).contains(p) && !cv::Rect(0, 240, 200, 240).contains(p))
        wall.insert(c->labels.at<std::int16_t>(r, col));
    }
  ASSERT_FALSE(box.empty());
  // No cluster straddles two surfaces.
  for (int j : box) EXPECT_FALSE(wall.count(j) || block.count(j)) << "cluster " << j;
  for (int j : block) EXPECT_FALSE(wall.count(j)) << "cluster " << j;
  int total = 0;
  for (int s : c->sizes) total += s;
  EXPECT_EQ(total, 80 * 60);
}

TEST(DepthClustering, LabelAtFollowsTheNearestCentre) {
  const CameraModel cam = vga();
  DepthClusterer clusterer;
  auto c = clusterer.cluster(threeSurfaces(), cam);
  ASSERT_TRUE(c.ok());
  const std::set<int> box = clustersIn(*c, {260, 180, 120, 120});
  // A keypoint on the box with box depth lands in a box cluster; at the same
  // pixel with wall depth (a depth-edge case) it does not.
  EXPECT_TRUE(box.count(c->labelAt(cam, 320, 240, 0.8f)));
  EXPECT_FALSE(box.count(c->labelAt(cam, 320, 240, 3.0f)));
  // Without depth, the sample cell decides.
  EXPECT_TRUE(box.count(c->labelAt(cam, 321, 241, 0.0f)));
  EXPECT_EQ(c->labelAt(cam, -5, 10, 0.0f), DepthClusters::kNoLabel);
  const cv::Mat full = c->fullResolutionLabels({640, 480});
  EXPECT_EQ(full.at<std::int16_t>(241, 321), c->labels.at<std::int16_t>(241 / 8, 321 / 8));
}

TEST(DepthClustering, WarmStartReusesCentresAndIsDeterministic) {
  const CameraModel cam = vga();
  DepthClusterer a, b;
  auto a1 = a.cluster(threeSurfaces(), cam);
  auto b1 = b.cluster(threeSurfaces(), cam);
  ASSERT_TRUE(a1 && b1);
  EXPECT_FALSE(a1->warm_started);
  EXPECT_EQ(cv::countNonZero(a1->labels != b1->labels), 0);
  // The box moves a little: warm-started clustering converges in fewer iterations.
  auto a2 = a.cluster(threeSurfaces({270, 180, 120, 120}), cam);
  ASSERT_TRUE(a2.ok());
  EXPECT_TRUE(a2->warm_started);
  DepthClusterer cold;
  auto c2 = cold.cluster(threeSurfaces({270, 180, 120, 120}), cam);
  ASSERT_TRUE(c2.ok());
  EXPECT_LE(a2->iterations, c2->iterations);
}

TEST(DepthClustering, MissingDepthGivesNoClustersAndBadInputAnError) {
  const CameraModel cam = vga();
  DepthClusterer clusterer;
  auto none = clusterer.cluster(cv::Mat::zeros(480, 640, CV_32F), cam);
  ASSERT_TRUE(none.ok());
  EXPECT_EQ(none->clusters, 0);
  EXPECT_EQ(none->labelAt(cam, 10, 10, 1.0f), DepthClusters::kNoLabel);
  // NaN and out-of-range depth count as missing.
  cv::Mat odd(480, 640, CV_32F, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  odd(cv::Rect(0, 0, 64, 48)).setTo(100.0f);
  auto nan = clusterer.cluster(odd, cam);
  ASSERT_TRUE(nan.ok());
  EXPECT_EQ(nan->clusters, 0);

  EXPECT_FALSE(clusterer.cluster(cv::Mat(), cam).ok());
  EXPECT_FALSE(clusterer.cluster(cv::Mat::zeros(240, 320, CV_32F), cam).ok());
  auto wrong_type = clusterer.cluster(cv::Mat::zeros(480, 640, CV_16U), cam);
  ASSERT_FALSE(wrong_type.ok());
  EXPECT_NE(wrong_type.error().find("CV_32FC1"), std::string::npos);
}

TEST(DepthClustering, ScalesWithResolution) {
  ClusteringOptions o;
  EXPECT_EQ(DepthClusterer::clustersFor(o, 640, 480), 24);
  EXPECT_EQ(DepthClusterer::clustersFor(o, 320, 240), 6);
  EXPECT_EQ(DepthClusterer::clustersFor(o, 1280, 960), 96);
  EXPECT_EQ(DepthClusterer::stepFor(o, 320, 240), 4);
  EXPECT_EQ(DepthClusterer::stepFor(o, 1280, 960), 16);
  o.clusters_at_vga = 1;
  EXPECT_FALSE(o.validate());
}

// After a loss the view has changed: the next frame's K-Means must not
// start from centres of the frames before.
TEST(ClusteringWorker, RestartClustersTheNextFrameFromFreshCentres) {
  const CameraModel cam = vga();
  for (const bool thread : {false, true}) {
    ClusteringWorker worker(cam, {}, thread);
    const std::chrono::seconds wait(10);
    worker.submit(0, threeSurfaces());
    ASSERT_TRUE(worker.result(0, wait));
    worker.submit(1, threeSurfaces());
    auto warm = worker.result(1, wait);
    ASSERT_TRUE(warm);
    EXPECT_TRUE(warm->warm_started);
    worker.restart();
    worker.submit(2, threeSurfaces());
    auto fresh = worker.result(2, wait);
    ASSERT_TRUE(fresh);
    EXPECT_FALSE(fresh->warm_started) << (thread ? "threaded" : "inline");
    DepthClusterer cold;
    auto expected = cold.cluster(threeSurfaces(), cam);
    ASSERT_TRUE(expected.ok());
    EXPECT_EQ(cv::countNonZero(fresh->labels != expected->labels), 0);
  }
}

// A frame the tracker does not take (a lost or relocalised one) is still
// clustered by the thread; the next frame's K-Means must start where it
// would have without it, as in a replay without the thread, which clusters
// only the frames tracking takes.
TEST(ClusteringWorker, AFrameNotTakenLeavesTheNextOneAlone) {
  const CameraModel cam = vga();
  // A face filling the view, 0.5 m away: centres far from the room's.
  cv::Mat face(480, 640, CV_32F, cv::Scalar(3.0f));
  face(cv::Rect(40, 20, 560, 440)).setTo(0.5f);
  const cv::Mat later = threeSurfaces({300, 200, 160, 140});
  DepthClusterer replay;
  ASSERT_TRUE(replay.cluster(threeSurfaces(), cam).ok());
  const auto expected = replay.cluster(later, cam);
  ASSERT_TRUE(expected.ok());
  DepthClusterer after_face;
  ASSERT_TRUE(after_face.cluster(threeSurfaces(), cam).ok());
  ASSERT_TRUE(after_face.cluster(face, cam).ok());
  const auto from_face = after_face.cluster(later, cam);
  ASSERT_TRUE(from_face.ok());
  // Otherwise the test could not tell the two starts apart.
  ASSERT_GT(cv::countNonZero(from_face->labels != expected->labels), 0);
  for (const bool thread : {false, true}) {
    SCOPED_TRACE(thread ? "threaded" : "inline");
    ClusteringWorker worker(cam, {}, thread);
    const std::chrono::seconds wait(10);
    worker.submit(0, threeSurfaces());
    ASSERT_TRUE(worker.result(0, wait));
    worker.submit(1, face);
    if (thread) {
      const auto until = std::chrono::steady_clock::now() + wait;
      while (worker.lastClusteredFrame() < 1 && std::chrono::steady_clock::now() < until)
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
      ASSERT_EQ(worker.lastClusteredFrame(), 1);
    }
    worker.submit(2, later);
    const auto clusters = worker.result(2, wait);
    ASSERT_TRUE(clusters);
    EXPECT_TRUE(clusters->warm_started);
    EXPECT_EQ(cv::countNonZero(clusters->labels != expected->labels), 0);
  }
}

}  // namespace
}  // namespace stillpoint::geometry
