// The motion model's projection search reports how distinctive each match is
// (best over second-best Hamming distance in the search window), and can
// reject ambiguous matches.
#include "dynamic_detector.hpp"
#include "matcher.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <memory>
#include <utility>
#include <vector>

namespace stillpoint::slam {
namespace {

const CameraModel& camera() {
  static const CameraModel c = testing::vgaCamera();
  return c;
}

// A frame with keypoints at `pixels` (level 0, no depth) and descriptors
// whose first `ones[i]` bits are set.
Frame frameWith(const std::vector<cv::Point2f>& pixels, const std::vector<int>& ones) {
  Frame f;
  f.camera = &camera();
  f.levels = &testing::oneLevel();
  for (const cv::Point2f& p : pixels) f.keys.emplace_back(p, 7.0f, 0.0f, 0.0f, 0);
  f.un = pixels;
  f.depth.assign(pixels.size(), -1.0f);
  f.u_right.assign(pixels.size(), -1.0f);
  f.descriptors = cv::Mat::zeros(static_cast<int>(pixels.size()), 32, CV_8U);
  for (std::size_t i = 0; i < ones.size(); ++i)
    for (int b = 0; b < ones[i]; ++b) f.descriptors.at<std::uint8_t>(static_cast<int>(i), b / 8) |= 1 << (b % 8);
  f.grid.build(f.un, camera().width, camera().height);
  f.dynamic.assign(pixels.size(), kNotDynamic);
  f.clearMatches();
  return f;
}

// Last frame: three points seen at (100, 100), (300, 200) and (500, 300),
// all with the all-zero descriptor, at 2 m.
Frame lastFrame() {
  Frame last = frameWith({{100, 100}, {300, 200}, {500, 300}}, {0, 0, 0});
  for (int i = 0; i < last.size(); ++i) {
    const Vec3 p = camera().unproject(Vec2(last.un[i].x, last.un[i].y), 2.0);
    last.points[i] = std::make_shared<MapPoint>(i, p, nullptr);
  }
  return last;
}

TEST(SearchByProjection, ReportsHowDistinctiveEachMatchIs) {
  const Frame last = lastFrame();
  // Point 0: its match (5 bits off) and a far worse one (60 bits). Point 1:
  // two near-identical keypoints (10 and 11 bits off). Point 2: one keypoint
  // alone in its window, 40 bits off.
  Frame current = frameWith({{101, 100}, {103, 101}, {300, 201}, {302, 199}, {500, 301}}, {5, 60, 10, 11, 40});
  std::vector<float> ratio(current.size(), -1.0f);
  EXPECT_EQ(searchByProjection(&current, last, 7.0f, &ratio), 3);
  ASSERT_EQ(current.points[0], last.points[0]);
  ASSERT_EQ(current.points[2], last.points[1]);
  ASSERT_EQ(current.points[4], last.points[2]);
  EXPECT_NEAR(ratio[0], 5.0f / 60.0f, 1e-6);
  EXPECT_NEAR(ratio[2], 10.0f / 11.0f, 1e-6);
  // A lone candidate is measured against the distance of a good match.
  EXPECT_NEAR(ratio[4], 40.0f / kMatchThresholdLow, 1e-6);
  EXPECT_EQ(ratio[1], -1.0f);  // unmatched keypoints are left alone
  EXPECT_EQ(ratio[3], -1.0f);
}

TEST(SearchByProjection, MaxRatioRejectsAmbiguousMatches) {
  const Frame last = lastFrame();
  Frame current = frameWith({{101, 100}, {103, 101}, {300, 201}, {302, 199}, {500, 301}}, {5, 60, 10, 11, 40});
  std::vector<float> ratio(current.size(), 0.0f);
  EXPECT_EQ(searchByProjection(&current, last, 7.0f, &ratio, 0.85f), 2);
  EXPECT_EQ(current.points[0], last.points[0]);
  EXPECT_EQ(current.points[2], nullptr);
  EXPECT_EQ(current.points[3], nullptr);
  EXPECT_EQ(current.points[4], last.points[2]);
  // Without the limit the same search keeps all three.
  current.clearMatches();
  EXPECT_EQ(searchByProjection(&current, last, 7.0f), 3);
  EXPECT_EQ(current.points[2], last.points[1]);
}

// Window-free matching by descriptor meets only the frame's keypoints within
// two pyramid levels of the other's, and among equally good ones keeps the
// first by index (it scans per-level candidate lists kept in index order).
TEST(MatchByDescriptor, MeetsKeypointsWithinTwoLevelsFirstByIndex) {
  Frame other = frameWith({{320, 240}}, {0});
  other.depth[0] = 2.0f;
  // All three carry the same descriptor: keypoint 0 three levels up,
  // keypoints 1 and 2 two levels up and on the same level.
  Frame current = frameWith({{100, 100}, {300, 200}, {500, 300}}, {0, 0, 0});
  current.keys[0].octave = 3;
  current.keys[1].octave = 2;
  current.keys[2].octave = 0;
  auto matches = matchByDescriptor(current, other, 0.8f, false, false);
  ASSERT_EQ(matches.size(), 1u);
  EXPECT_EQ(matches[0], std::make_pair(1, 0));
  // With keypoint 1 out of reach too (three levels), keypoint 2 is the one.
  current.keys[1].octave = 3;
  matches = matchByDescriptor(current, other, 0.8f, false, false);
  ASSERT_EQ(matches.size(), 1u);
  EXPECT_EQ(matches[0], std::make_pair(2, 0));
  // And from the other's side: at level 5 it reaches levels 3-7 only.
  other.keys[0].octave = 5;
  matches = matchByDescriptor(current, other, 0.8f, false, false);
  ASSERT_EQ(matches.size(), 1u);
  EXPECT_EQ(matches[0], std::make_pair(0, 0));
}

// The ratio test weighs the nearest candidate against the runner-up whether
// that comes before or after it in index order (10 bits against 12 fails at
// 0.7, against 20 passes), and matching only some keypoints agrees.
TEST(MatchByDescriptor, RatioTestMeetsTheRunnerUpOnEitherSide) {
  Frame other = frameWith({{320, 240}}, {0});
  other.depth[0] = 2.0f;
  for (const std::vector<int>& ones : {std::vector<int>{12, 10}, {10, 12}, {20, 10}, {10, 20}}) {
    const Frame current = frameWith({{100, 100}, {300, 200}}, ones);
    const int nearest = ones[0] < ones[1] ? 0 : 1;
    const bool passes = std::max(ones[0], ones[1]) == 20;
    const auto whole = matchByDescriptor(current, other, 0.7f, false, true);
    ASSERT_EQ(whole.size(), passes ? 1u : 0u) << ones[0] << " " << ones[1];
    if (passes) {
      EXPECT_EQ(whole[0], std::make_pair(nearest, 0));
    }
    EXPECT_EQ(matchSomeByDescriptor(current, other, 0.7f, {0, 1}), whole) << ones[0] << " " << ones[1];
  }
}

// Two frames for matching some keypoints against the whole matching.
// Descriptors are random, half of `current`'s copied from `other`'s with a few
// bits flipped, and some copied twice (ties); some of `current`'s keypoints
// lie nearer to a second keypoint of `other` than to the one copied to them
// (the mutual check decides).
std::pair<Frame, Frame> randomFramePair() {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> byte(0, 255), level(0, 7), bit(0, 255);
  const auto randomFrame = [&](int n) {
    std::vector<cv::Point2f> pixels;
    for (int i = 0; i < n; ++i) pixels.emplace_back(static_cast<float>(10 + i % 60 * 10), static_cast<float>(10 + i / 60 * 10));
    Frame f = frameWith(pixels, std::vector<int>(n, 0));
    for (int i = 0; i < n; ++i) {
      f.keys[i].octave = level(rng);
      for (int b = 0; b < 32; ++b) f.descriptors.at<std::uint8_t>(i, b) = static_cast<std::uint8_t>(byte(rng));
    }
    return f;
  };
  Frame other = randomFrame(300);
  for (int i = 0; i < other.size(); ++i) other.depth[i] = i % 7 == 0 ? -1.0f : 2.0f;  // some without depth
  Frame current = randomFrame(400);
  for (int j = 0; j < current.size(); j += 2) {
    const int i = (j * 7) % other.size();
    other.descriptors.row(i).copyTo(current.descriptors.row(j));
    for (int flips = j % 12; flips > 0; --flips) {
      const int b = bit(rng);
      current.descriptors.at<std::uint8_t>(j, b / 8) ^= static_cast<std::uint8_t>(1 << (b % 8));
    }
    current.keys[j].octave = std::clamp(other.keys[i].octave + j % 5 - 2, 0, 7);
  }
  for (int j = 1; j < 40; j += 4) current.descriptors.row(j - 1).copyTo(current.descriptors.row(j));  // ties
  for (int j = 100; j < 200; j += 4) {
    const int i2 = (j * 11 + 5) % other.size();
    current.descriptors.row(j).copyTo(other.descriptors.row(i2));
    other.descriptors.at<std::uint8_t>(i2, 0) ^= 1;
    other.depth[i2] = 2.0f;
    other.keys[i2].octave = current.keys[j].octave;
  }
  return {std::move(current), std::move(other)};
}

// Matching only some of the frame's keypoints finds exactly the matches the
// whole frame's mutual matching finds for them: the same reach, ratio test,
// mutual check and ties.
TEST(MatchSomeByDescriptor, FindsTheWholeMatchingsMatchesOfItsFeatures) {
  const auto [current, other] = randomFramePair();
  std::vector<int> some;
  for (int j = 0; j < current.size(); ++j)
    if (j % 3 != 1) some.push_back(j);
  const auto whole = matchByDescriptor(current, other, 0.7f, false, true);
  std::vector<std::pair<int, int>> expected;
  for (const auto& m : whole)
    if (m.first % 3 != 1) expected.push_back(m);
  ASSERT_GT(expected.size(), 40u);
  EXPECT_EQ(matchSomeByDescriptor(current, other, 0.7f, some), expected);
}

// The same from the other frame's side: the whole matching's matches whose
// keypoint of the other frame is listed. Unlisted keypoints still take the
// frame keypoints nearest to them: the second keypoints planted nearer are
// left unlisted, and their frame keypoints must not be matched; and a listed
// keypoint that ties an earlier unlisted one for a frame keypoint loses it.
TEST(MatchFromSomeByDescriptor, FindsTheWholeMatchingsMatchesFromItsFeatures) {
  auto [current, other] = randomFramePair();
  std::vector<char> planted(other.size(), 0);
  for (int j = 100; j < 200; j += 4) planted[(j * 11 + 5) % other.size()] = 1;
  for (int i = 32; i < 120; i += 3) {  // listed (i % 3 == 2), tied by unlisted i - 1
    if (planted[i] || planted[i - 1]) continue;
    other.descriptors.row(i).copyTo(other.descriptors.row(i - 1));
    other.keys[i - 1].octave = other.keys[i].octave;
    other.depth[i - 1] = other.depth[i];
  }
  std::vector<int> from;
  for (int i = 0; i < other.size(); ++i)
    if (i % 3 != 1 && !planted[i]) from.push_back(i);
  const auto whole = matchByDescriptor(current, other, 0.7f, false, true);
  std::vector<std::pair<int, int>> expected;
  for (const auto& m : whole)
    if (m.second % 3 != 1 && !planted[m.second]) expected.push_back(m);
  ASSERT_GT(expected.size(), 40u);
  EXPECT_EQ(matchFromSomeByDescriptor(current, other, 0.7f, from), expected);
}

// The geometry module's helper thread matches the frame to the oldest anchor
// while stage 1 runs. A new map, a relocalisation in another map or a merge
// forgets the anchors in the middle of a frame: the match must not outlive
// them (it read freed memory, and a threaded replay crashed).
TEST(DynamicDetector, ForgettingTheHistoryEndsTheHelpersAnchorMatch) {
  auto [current, other] = randomFramePair();
  DynamicDetector detector(camera(), testing::oneLevel(), SlamOptions{}, nullptr, true);
  detector.startFrame(other, false, false);
  detector.endFrame(other, true, {});  // the anchor
  detector.startFrame(current, true, true);
  EXPECT_TRUE(detector.anchorMatchPending());
  detector.forgetHistory();
  EXPECT_FALSE(detector.anchorMatchPending());
  detector.endFrame(current, false, {});
}

}  // namespace
}  // namespace stillpoint::slam
