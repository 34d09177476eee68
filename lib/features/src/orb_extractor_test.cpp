#include "stillpoint/features/orb_extractor.hpp"

#include <gtest/gtest.h>

#include <cstdio>

#include <opencv2/imgproc.hpp>

#include "stillpoint/features/descriptor.hpp"

namespace stillpoint::features {
namespace {

// Random blobs and rectangles: plenty of corners at several scales.
cv::Mat texturedImage(int width, int height, unsigned seed) {
  cv::Mat image(height, width, CV_8UC1, cv::Scalar(128));
  cv::RNG rng(seed);
  for (int i = 0; i < 600; ++i) {
    const cv::Point p(rng.uniform(0, width), rng.uniform(0, height));
    const int r = rng.uniform(3, 25);
    if (i % 2 == 0)
      cv::circle(image, p, r, cv::Scalar(rng.uniform(0, 255)), cv::FILLED);
    else
      cv::rectangle(image, cv::Rect(p.x, p.y, r * 2, r), cv::Scalar(rng.uniform(0, 255)), cv::FILLED);
  }
  return image;
}

TEST(OrbOptions, PyramidMustFitTheImage) {
  OrbOptions o;  // 8 levels of 1.2: 640x480 -> 179x134 at the top
  EXPECT_TRUE(o.validateFor(640, 480).ok());
  EXPECT_FALSE(o.validateFor(100, 100).ok());
  EXPECT_FALSE(o.validateFor(1, 480).ok());
  o.num_levels = 11;
  o.scale_factor = 2.0;  // each in range, together 1024x smaller
  const Status s = o.validateFor(640, 480);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().find("orb.num_levels 11"), std::string::npos) << s.error();
  o.num_levels = 4;  // 80x60 at the top
  EXPECT_TRUE(o.validateFor(640, 480).ok());
}

TEST(OrbExtractor, FillsTheBudgetSpreadOverImageAndLevels) {
  OrbOptions options;
  OrbExtractor orb(options);
  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  orb.extract(texturedImage(640, 480, 1), &kps, &desc);
  EXPECT_GT(static_cast<int>(kps.size()), options.num_features * 9 / 10);
  EXPECT_LE(static_cast<int>(kps.size()), options.num_features);
  EXPECT_EQ(desc.rows, static_cast<int>(kps.size()));
  EXPECT_EQ(desc.cols, 32);
  std::vector<int> per_level(options.num_levels, 0);
  int quadrant[4] = {0, 0, 0, 0};
  for (const auto& kp : kps) {
    ASSERT_GE(kp.octave, 0);
    ASSERT_LT(kp.octave, options.num_levels);
    per_level[kp.octave]++;
    quadrant[(kp.pt.x > 320) + 2 * (kp.pt.y > 240)]++;
    EXPECT_GE(kp.pt.x, 0);
    EXPECT_LT(kp.pt.x, 640);
  }
  for (int l = 0; l < options.num_levels; ++l) EXPECT_GT(per_level[l], 0) << "level " << l;
  for (int q : quadrant) EXPECT_GT(q, static_cast<int>(kps.size()) / 8);
}

TEST(OrbExtractor, IsDeterministic) {
  OrbExtractor a{OrbOptions{}}, b{OrbOptions{}};
  const cv::Mat image = texturedImage(640, 480, 2);
  std::vector<cv::KeyPoint> ka, kb;
  cv::Mat da, db;
  a.extract(image, &ka, &da);
  b.extract(image, &kb, &db);
  ASSERT_EQ(ka.size(), kb.size());
  EXPECT_EQ(cv::norm(da, db, cv::NORM_HAMMING), 0);
}

// The same scene rotated in-plane: the descriptor at corresponding corners
// must match far better than random pairs do (rotation invariance).
TEST(OrbExtractor, DescriptorsSurviveInPlaneRotation) {
  const cv::Mat image = texturedImage(640, 480, 3);
  const cv::Point2f centre(320, 240);
  const double angle_deg = 40;
  const cv::Mat R = cv::getRotationMatrix2D(centre, angle_deg, 1.0);
  cv::Mat rotated;
  cv::warpAffine(image, rotated, R, image.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(128));

  OrbExtractor orb{OrbOptions{}};
  std::vector<cv::KeyPoint> k1, k2;
  cv::Mat d1, d2;
  orb.extract(image, &k1, &d1);
  orb.extract(rotated, &k2, &d2);
  int good = 0, checked = 0;
  long random_sum = 0, matched_sum = 0;
  for (std::size_t i = 0; i < k1.size(); ++i) {
    const cv::Point2f p = k1[i].pt;
    if (cv::norm(p - centre) > 180) continue;  // stays inside the rotated image
    const cv::Point2f q(static_cast<float>(R.at<double>(0, 0) * p.x + R.at<double>(0, 1) * p.y + R.at<double>(0, 2)),
                        static_cast<float>(R.at<double>(1, 0) * p.x + R.at<double>(1, 1) * p.y + R.at<double>(1, 2)));
    int best = 256;
    for (std::size_t j = 0; j < k2.size(); ++j) {
      if (k2[j].octave != k1[i].octave || cv::norm(k2[j].pt - q) > 2.0) continue;
      best = std::min(best, hammingDistance(d1.ptr<std::uint8_t>(static_cast<int>(i)), d2.ptr<std::uint8_t>(static_cast<int>(j))));
    }
    if (best == 256) continue;
    ++checked;
    good += best < 50;
    matched_sum += best;
    random_sum += hammingDistance(d1.ptr<std::uint8_t>(static_cast<int>(i)),
                                  d2.ptr<std::uint8_t>(static_cast<int>((i * 7919) % k2.size())));
  }
  ASSERT_GT(checked, 100);
  EXPECT_GT(good, checked * 7 / 10) << good << " of " << checked;
  // Corresponding corners are far closer than unrelated ones.
  EXPECT_LT(matched_sum * 3, random_sum) << matched_sum / checked << " vs " << random_sum / checked;
}

// Cells in the sparse region (here the left half, given at 1/8 scale as the
// tracker does) keep one in N of the corners the round robin reaches there, so
// they end up about N times sparser than the other cells, which get the
// budget they leave.
TEST(OrbExtractor, SparseRegionLeavesItsBudgetToTheRest) {
  OrbExtractor orb{OrbOptions{}};
  const cv::Mat image = texturedImage(640, 480, 5);
  const auto halves = [](const std::vector<cv::KeyPoint>& kps) {
    std::pair<int, int> n{0, 0};
    for (const cv::KeyPoint& kp : kps) (kp.pt.x < 320 ? n.first : n.second)++;
    return n;
  };
  std::vector<cv::KeyPoint> plain, thinned, off;
  cv::Mat d_plain, d_thinned, d_off;
  orb.extract(image, &plain, &d_plain);
  cv::Mat sparse = cv::Mat::zeros(60, 80, CV_8UC1);
  sparse.colRange(0, 40).setTo(255);
  orb.extract(image, &thinned, &d_thinned, sparse, 4);
  const auto [left, right] = halves(plain);
  const auto [left4, right4] = halves(thinned);
  std::printf("left/right half: %d/%d plain, %d/%d with the left half sparse (1 in 4)\n", left, right, left4, right4);
  EXPECT_EQ(thinned.size(), plain.size());
  EXPECT_EQ(d_thinned.rows, static_cast<int>(thinned.size()));
  // Cells straddling the border count by their centre.
  EXPECT_LT(left4, left / 2);
  EXPECT_GT(right4, right + (left - left4) * 9 / 10);
  EXPECT_NEAR(4.0 * left4 / right4, 1.0, 0.25);
  // One in one, or no region: the plain extraction.
  orb.extract(image, &off, &d_off, sparse, 1);
  ASSERT_EQ(off.size(), plain.size());
  EXPECT_EQ(cv::norm(d_off, d_plain, cv::NORM_HAMMING), 0);
}

TEST(OrbExtractor, HandlesFlatAndTinyImages) {
  OrbExtractor orb{OrbOptions{}};
  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  orb.extract(cv::Mat(480, 640, CV_8UC1, cv::Scalar(7)), &kps, &desc);
  EXPECT_TRUE(kps.empty());
  EXPECT_EQ(desc.rows, 0);
  orb.extract(texturedImage(40, 30, 4), &kps, &desc);
  EXPECT_EQ(desc.rows, static_cast<int>(kps.size()));
}

TEST(OrbOptions, ValidateNamesField) {
  OrbOptions o;
  EXPECT_TRUE(o.validate().ok());
  o.scale_factor = 0.9;
  ASSERT_FALSE(o.validate().ok());
  EXPECT_NE(o.validate().error().find("scale_factor"), std::string::npos);
}

TEST(Descriptor, HammingAndMedian) {
  std::uint8_t a[32] = {0}, b[32] = {0}, c[32] = {0};
  b[0] = 0xff;  // 8 bits from a
  c[31] = 0x01; // 1 bit from a
  EXPECT_EQ(hammingDistance(a, b), 8);
  EXPECT_EQ(hammingDistance(b, c), 9);
  const std::uint8_t* set[] = {a, b, c};
  EXPECT_EQ(medianDescriptorIndex(set, 3), 0);
}

}  // namespace
}  // namespace stillpoint::features
