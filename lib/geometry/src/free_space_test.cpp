// The geometry cues on hand-made frames: free space, the moved surface grown
// from it, the photometric test of a patch, and the shared rules.
#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "stillpoint/geometry/free_space.hpp"
#include "stillpoint/geometry/photometric.hpp"
#include "stillpoint/geometry/rules.hpp"

namespace stillpoint::geometry {
namespace {

CameraModel camera() {
  CameraModel c;
  c.width = 160;
  c.height = 120;
  c.fx = c.fy = 150;
  c.cx = 80;
  c.cy = 60;
  return c;
}

// Clusters of `depth` by hand: a sample every `step` pixels, cluster 1 where
// `box` covers the sample, 0 elsewhere.
DepthClusters clustersOf(const cv::Mat& depth, int step, const cv::Rect& box) {
  DepthClusters d;
  d.clusters = 2;
  d.step = step;
  d.depth = depth;
  d.labels = cv::Mat(depth.rows / step, depth.cols / step, CV_16S, cv::Scalar(0));
  d.sizes = {0, 0};
  for (int r = 0; r < d.labels.rows; ++r)
    for (int c = 0; c < d.labels.cols; ++c) {
      const int label = box.contains(cv::Point(c * step + step / 2, r * step + step / 2)) ? 1 : 0;
      d.labels.at<std::int16_t>(r, c) = static_cast<std::int16_t>(label);
      ++d.sizes[label];
    }
  d.centres = {Vec3(0, 0, 2), Vec3(0, 0, 1)};
  return d;
}

TEST(FreeSpace, SamplesInFrontOfTheSeenSurfaceViolate) {
  const CameraModel cam = camera();
  const cv::Mat wall(cam.height, cam.width, CV_32F, cv::Scalar(2.0f));
  cv::Mat now = wall.clone();
  const cv::Rect box(40, 30, 40, 40);
  now(box).setTo(1.0f);  // something moved into the space the seen frame had empty
  const DepthClusters clusters = clustersOf(now, 8, box);
  const FreeSpace free = freeSpaceViolations(clusters, wall, SE3::Identity(), cam, {});
  ASSERT_EQ(free.share.size(), 2u);
  EXPECT_FLOAT_EQ(free.share[1], 1.0f);
  EXPECT_FLOAT_EQ(free.share[0], 0.0f);
  EXPECT_GT(free.violations[1], 0);
  EXPECT_EQ(free.violations[0], 0);
  EXPECT_EQ(cv::countNonZero(free.violated), free.violations[1]);
}

TEST(FreeSpace, NothingSeenTestsNothing) {
  const CameraModel cam = camera();
  const cv::Mat now(cam.height, cam.width, CV_32F, cv::Scalar(1.0f));
  const FreeSpace free = freeSpaceViolations(clustersOf(now, 8, cv::Rect(0, 0, 10, 10)), cv::Mat(), SE3::Identity(),
                                             cam, {});
  EXPECT_EQ(free.share, std::vector<float>({-1.0f, -1.0f}));
  EXPECT_EQ(free.violations, std::vector<int>({0, 0}));
  EXPECT_EQ(cv::countNonZero(free.violated), 0);
}

TEST(FreeSpace, DepthNoiseWithinTheToleranceIsNoViolation) {
  const CameraModel cam = camera();
  const cv::Mat wall(cam.height, cam.width, CV_32F, cv::Scalar(2.0f));
  const cv::Mat now(cam.height, cam.width, CV_32F, cv::Scalar(1.95f));  // 5 cm nearer, tolerance 3 + 8 cm
  const FreeSpace free = freeSpaceViolations(clustersOf(now, 8, cv::Rect()), wall, SE3::Identity(), cam, {});
  EXPECT_FLOAT_EQ(free.share[0], 0.0f);
  const FreeSpace strict = freeSpaceViolations(clustersOf(now, 8, cv::Rect()), wall, SE3::Identity(), cam, {0.01, 0});
  EXPECT_FLOAT_EQ(strict.share[0], 1.0f);
}

// A box standing on a floor plane: the moved surface grows from one violating
// sample over the box's face, and stops at the depth jump to the background.
TEST(MovedSurface, GrowsOverItsSurfaceAndStopsAtADepthJump) {
  const CameraModel cam = camera();
  cv::Mat now(cam.height, cam.width, CV_32F, cv::Scalar(3.0f));
  const cv::Rect box(40, 32, 48, 40);
  now(box).setTo(1.0f);
  const DepthClusters clusters = clustersOf(now, 8, box);
  FreeSpace free = freeSpaceViolations(clusters, now, SE3::Identity(), cam, {});  // nothing moved
  ASSERT_EQ(cv::countNonZero(free.violated), 0);
  const cv::Point seed(8, 6);  // a sample inside the box
  ASSERT_TRUE(box.contains(cv::Point(seed.x * 8 + 4, seed.y * 8 + 4)));
  free.violated.at<std::uint8_t>(seed) = 1;
  const cv::Mat moved = growMovedSurface(clusters, free, {});
  int in_box = 0, outside = 0, box_samples = 0;
  for (int r = 0; r < moved.rows; ++r)
    for (int c = 0; c < moved.cols; ++c) {
      const bool inside = box.contains(cv::Point(c * 8 + 4, r * 8 + 4));
      box_samples += inside;
      (inside ? in_box : outside) += moved.at<std::uint8_t>(r, c) != 0;
    }
  EXPECT_EQ(outside, 0);
  // The box's rim samples have no normal (a neighbour across the jump): the
  // growth reaches the inner samples.
  EXPECT_GE(in_box, box_samples / 3);
  EXPECT_TRUE(growMovedSurface(clusters, FreeSpace{}, {}).empty());
}

// A textured image for the photometric test.
cv::Mat texture(int rows, int cols, int seed) {
  cv::Mat coarse(rows / 4, cols / 4, CV_8U), out;
  cv::RNG rng(seed);
  rng.fill(coarse, cv::RNG::UNIFORM, 0, 255);
  cv::resize(coarse, out, cv::Size(cols, rows), 0, 0, cv::INTER_NEAREST);
  return out;
}

TEST(PhotoAgreement, TheStaticHypothesisExplainsAnUnmovedPatch) {
  const CameraModel cam = camera();
  const cv::Mat gray = texture(cam.height, cam.width, 1);
  const cv::Mat depth(cam.height, cam.width, CV_32F, cv::Scalar(2.0f));
  const SeenView seen{&gray, &depth, SE3::Identity()};
  PhotoAgreement a;
  ASSERT_TRUE(photoAgreement({cv::Point2f(80, 60), 2.0f}, gray, depth, seen, cam, {}, &a));
  EXPECT_DOUBLE_EQ(a.depth_share, 1.0);
  EXPECT_GT(a.ncc, 0.99);
}

TEST(PhotoAgreement, AMovedTextureDoesNotMatch) {
  const CameraModel cam = camera();
  const cv::Mat now = texture(cam.height, cam.width, 1);
  // The texture moved 12 px along its surface since (a poster sliding sideways).
  cv::Mat before(now.size(), now.type(), cv::Scalar(0));
  now(cv::Rect(12, 0, cam.width - 12, cam.height)).copyTo(before(cv::Rect(0, 0, cam.width - 12, cam.height)));
  const cv::Mat depth(cam.height, cam.width, CV_32F, cv::Scalar(2.0f));
  const SeenView seen{&before, &depth, SE3::Identity()};
  PhotoAgreement a;
  ASSERT_TRUE(photoAgreement({cv::Point2f(80, 60), 2.0f}, now, depth, seen, cam, {}, &a));
  EXPECT_DOUBLE_EQ(a.depth_share, 1.0);
  EXPECT_LT(a.ncc, 0.6);
}

TEST(PhotoAgreement, DepthThatDisagreesFailsBeforeTheIntensities) {
  const CameraModel cam = camera();
  const cv::Mat gray = texture(cam.height, cam.width, 1);
  const cv::Mat now(cam.height, cam.width, CV_32F, cv::Scalar(1.0f));
  const cv::Mat before(cam.height, cam.width, CV_32F, cv::Scalar(2.0f));
  const SeenView seen{&gray, &before, SE3::Identity()};
  PhotoAgreement a;
  ASSERT_TRUE(photoAgreement({cv::Point2f(80, 60), 1.0f}, gray, now, seen, cam, {}, &a));
  EXPECT_LT(a.depth_share, 0.9);
  EXPECT_EQ(a.ncc, -1);
}

TEST(PhotoAgreement, APatchLeavingEitherImageIsUntestable) {
  const CameraModel cam = camera();
  const cv::Mat gray = texture(cam.height, cam.width, 1);
  const cv::Mat depth(cam.height, cam.width, CV_32F, cv::Scalar(2.0f));
  PhotoAgreement a;
  // At the border of the current image.
  EXPECT_FALSE(photoAgreement({cv::Point2f(2, 60), 2.0f}, gray, depth, {&gray, &depth, SE3::Identity()}, cam, {}, &a));
  // Warped out of the seen image: the seen camera 2 m to the left.
  SE3 T = SE3::Identity();
  T.translation() = Vec3(2.0, 0, 0);
  EXPECT_FALSE(photoAgreement({cv::Point2f(80, 60), 2.0f}, gray, depth, {&gray, &depth, T}, cam, {}, &a));
  // No seen image kept.
  EXPECT_FALSE(photoAgreement({cv::Point2f(80, 60), 2.0f}, gray, depth, {}, cam, {}, &a));
}

TEST(Rules, MostOfTheView) {
  EXPECT_TRUE(mostOfViewDynamic(7, 10, 0.6));
  EXPECT_FALSE(mostOfViewDynamic(6, 10, 0.6));  // not more than the share
  EXPECT_FALSE(mostOfViewDynamic(0, 0, 0.6));
}

TEST(Rules, SameSurfaceIsTenCentimetresAndFivePercent) {
  EXPECT_TRUE(sameSurface(2.19f, 2.0f));   // within 0.1 + 0.1
  EXPECT_FALSE(sameSurface(2.21f, 2.0f));
  EXPECT_TRUE(sameSurface(0.95f, 1.0f));
  EXPECT_FALSE(sameSurface(0.8f, 1.0f));
}

}  // namespace
}  // namespace stillpoint::geometry
