// A loop's correction on a hand-built map: a ring of keyframes whose poses
// drifted as they were tracked, each sharing 120 points with the next, and a
// loop from the last back to the first. The loop's keyframe must end where
// the loop puts it relative to the first, the drift spread over the ring.
#include "loop_closing.hpp"
#include "map.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cmath>
#include <cstdio>
#include <memory>
#include <utility>
#include <vector>

namespace stillpoint::slam {

class LoopCorrection : public ::testing::Test {
 protected:
  static constexpr int kKeyFrames = 12;
  static constexpr int kShared = 120;  // points a keyframe shares with the next (a strong link)

  void SetUp() override {
    camera_.width = 640;
    camera_.height = 480;
    camera_.fx = camera_.fy = 500;
    camera_.cx = 320;
    camera_.cy = 240;
    camera_.baseline = 0.08;
    for (int i = 0; i < kKeyFrames; ++i) {
      // On a circle of 2 m, looking outwards; the estimate drifts 1 cm and
      // 0.2 degrees more with every keyframe.
      const double a = 2 * M_PI * i / kKeyFrames;
      SE3 T_w_c = SE3::Identity();
      T_w_c.linear() = Eigen::AngleAxisd(a, Vec3::UnitY()).toRotationMatrix();
      T_w_c.translation() = Vec3(2 * std::sin(a), 0, 2 * std::cos(a));
      SE3 drift = SE3::Identity();
      drift.linear() = Eigen::AngleAxisd(i * 0.2 * M_PI / 180, Vec3::UnitY()).toRotationMatrix();
      drift.translation() = Vec3(0.01 * i, 0, 0);
      truth_.push_back(T_w_c.inverse());
      kfs_.push_back(map_.addKeyFrame(keyFrame(i, (drift * T_w_c).inverse())));
    }
    kfs_[0]->origin = true;
    // Features [0, 120) see the points shared with the keyframe before,
    // [120, 240) those shared with the one after. The points lie far outside
    // every view: the correction's search for the older side's points in the
    // group's keyframes finds none, and the loop's fusion alone links the two
    // sides.
    for (int i = 0; i + 1 < kKeyFrames; ++i)
      for (int k = 0; k < kShared; ++k) {
        auto p = map_.createPoint(Vec3(k, 500, 0), kfs_[i]);
        kfs_[i]->addObservation(p, kShared + k);
        kfs_[i + 1]->addObservation(p, k);
        p->updateFromObservations();
      }
    for (KeyFrame* kf : kfs_) kf->updateConnections();
  }

  std::unique_ptr<KeyFrame> keyFrame(std::int64_t id, const SE3& T_c_w) {
    return testing::handMadeKeyFrame(id, 2 * kShared, T_c_w, &camera_);
  }

  // Closes the loop from the last keyframe to the first, fusing the last
  // one's points of the keyframe before it into the first one's points of
  // the keyframe after it (the same surfaces, seen a lap apart).
  void closeLoop() {
    KeyFrame* last = kfs_.back();
    KeyFrame* first = kfs_.front();
    LoopCloser::Loop loop;
    loop.keyframe = last->id;
    loop.candidate = first->id;
    loop.T_kf_candidate = truth_.back() * truth_.front().inverse();
    for (int k = 0; k < kShared; ++k) loop.fused.emplace_back(k, first->frame.points[kShared + k]);
    SlamOptions options;
    LoopCloser closer(options, camera_, &map_);
    closer.correct(loop);
    closed_ = closer.stats().closed;
  }

  CameraModel camera_;
  Map map_;
  std::vector<KeyFrame*> kfs_;
  std::vector<SE3> truth_;  // T_c_w
  int closed_ = 0;
};

namespace {

double translationError(const SE3& a, const SE3& b) { return (a.inverse() * b).translation().norm(); }

TEST_F(LoopCorrection, TheLoopsKeyFrameEndsWhereTheLoopPutsIt) {
  const SE3 loop_relative = truth_.back() * truth_.front().inverse();
  const double drift_m = translationError(kfs_.back()->T_c_w() * kfs_.front()->T_c_w().inverse(), loop_relative);
  ASSERT_GT(drift_m, 0.05);
  closeLoop();
  ASSERT_EQ(closed_, 1);
  // The fusion linked the two sides (the last two keyframes now share the
  // first two's points).
  EXPECT_EQ(kfs_.back()->connections.count(kfs_.front()), 1u);
  // The ring's other links still hold the drift they were tracked with: it
  // spreads over them, and the loop's own side ends close to the loop.
  const double after_m = translationError(kfs_.back()->T_c_w() * kfs_.front()->T_c_w().inverse(), loop_relative);
  std::printf("loop keyframe against the loop: %.4f m before the correction, %.4f m after\n", drift_m, after_m);
  EXPECT_LT(after_m, 0.25 * drift_m) << "drift " << drift_m << " m, after the loop " << after_m << " m";
  // The first keyframe (the map's origin) stays.
  EXPECT_LT(translationError(kfs_.front()->T_c_w(), truth_.front()), 1e-9);
}

}  // namespace
}  // namespace stillpoint::slam
