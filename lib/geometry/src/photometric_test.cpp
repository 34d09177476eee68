// PhotoVote: the photometric test's verdict over the frames a dropped
// feature's patch is tested against; photoDetects: the cluster rule of the
// photometric detection.
#include <gtest/gtest.h>

#include <initializer_list>

#include "stillpoint/geometry/photometric.hpp"

namespace stillpoint::geometry {
namespace {

struct Outcome {
  bool failed = false;
  bool passed = false;
};

// Adds the frames' NCC in order, as the tracker does, stopping at the first
// failure.
Outcome vote(const PhotoVoteRule& g, std::initializer_list<double> ncc) {
  PhotoVote v(g);
  for (double x : ncc) {
    v.add(x);
    if (v.failed()) return {true, false};
  }
  return {false, v.passed()};
}

TEST(PhotoVote, EveryFrameAboveTheLimitPasses) {
  PhotoVoteRule g;
  g.one_ncc = 0;  // the strict rule alone
  EXPECT_TRUE(vote(g, {0.9, 0.7, 0.61}).passed);
  EXPECT_TRUE(vote(g, {0.8}).passed);
  EXPECT_TRUE(vote(g, {0.9, 0.59, 0.9}).failed);
  EXPECT_TRUE(vote(g, {-1}).failed);  // a flat patch (no NCC)
}

TEST(PhotoVote, OneFrameOfThreeMayComeNear) {
  const PhotoVoteRule g;  // defaults: 0.6 all, or one above 0.3 with the others above 0.65
  ASSERT_GT(g.one_ncc, 0);
  // A static patch blurred in one frame.
  Outcome o = vote(g, {0.9, 0.45, 0.8});
  EXPECT_FALSE(o.failed);
  EXPECT_TRUE(o.passed);
  EXPECT_TRUE(vote(g, {0.35, 0.7, 0.66}).passed);
  // Too far off in that frame, two frames short, or a flat patch: fails
  // at once.
  EXPECT_TRUE(vote(g, {0.9, 0.25}).failed);
  EXPECT_TRUE(vote(g, {0.5, 0.55}).failed);
  EXPECT_TRUE(vote(g, {0.9, -1}).failed);
  // The other frames must be above one_others, not only the limit.
  EXPECT_TRUE(vote(g, {0.4, 0.62}).failed);
  // Fewer than three frames tested (a short history): all must pass.
  o = vote(g, {0.9, 0.45});
  EXPECT_FALSE(o.failed);
  EXPECT_FALSE(o.passed);
  EXPECT_FALSE(vote(g, {0.45}).passed);
}

TEST(PhotoDetects, NeedsEnoughTestedPatchesMostOfThemFailing) {
  // 4 tested at least, more than 0.8 of them failing.
  EXPECT_TRUE(photoDetects(4, 4, 0.8, 4));
  EXPECT_TRUE(photoDetects(10, 9, 0.8, 4));
  EXPECT_FALSE(photoDetects(10, 8, 0.8, 4));  // not more than 0.8
  EXPECT_FALSE(photoDetects(3, 3, 0.8, 4));   // too few tested
  EXPECT_FALSE(photoDetects(0, 0, 0.8, 4));
  EXPECT_FALSE(photoDetects(10, 10, 0.0, 4));  // off
}

}  // namespace
}  // namespace stillpoint::geometry
