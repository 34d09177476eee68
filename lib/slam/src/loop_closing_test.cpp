// A loop's correction on a hand-built map: a ring of keyframes whose poses
// drifted as they were tracked, each sharing 120 points with the next, and a
// loop from the last back to the first. The loop's keyframe must end where
// the loop puts it relative to the first, the drift spread over the ring.
//
// A crossing on a hand-built map: one wall mapped twice, by an older group of
// keyframes and, seconds later, a newer one whose world drifted; a frame
// tracked on the older group must close the loop that puts the newer group
// back on the older one, and a frame the newer group does not see must not.
#include "loop_closing.hpp"
#include "map.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <random>
#include <utility>
#include <vector>

namespace stillpoint::slam {
class LoopCorrection : public ::testing::Test {
 protected:
  static constexpr int kKeyFrames = 12;
  static constexpr int kShared = 120;  // points a keyframe shares with the next (a strong link)

  void SetUp() override {
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

  CameraModel camera_ = testing::vgaCamera();
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

// The wall: 400 points 3-5 m in front of the origin, each with its own
// random descriptor (so each is matched to itself alone).
class Crossing : public ::testing::Test {
 protected:
  // As if a global BA had run over every keyframe the map holds now.
  void coveredByAGlobalBa(LoopCloser* closer) const { closer->global_ba_covers_ = map_.nextKeyFrameId(); }

  static constexpr int kPoints = 400;
  static constexpr int kPerSide = 5;

  void SetUp() override {
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> x(-2.5, 2.5), y(-1.8, 1.8), z(3, 5);
    std::uniform_int_distribution<int> byte(0, 255);
    descriptors_ = cv::Mat(kPoints, 32, CV_8U);
    for (int i = 0; i < kPoints; ++i) {
      wall_.emplace_back(x(rng), y(rng), z(rng));
      for (int b = 0; b < 32; ++b) descriptors_.at<std::uint8_t>(i, b) = static_cast<std::uint8_t>(byte(rng));
    }
    drift_ = newerWorld();
    for (int k = 0; k < kPerSide; ++k) older_.push_back(addKeyFrame(k, 0.1 * k, cameraAt(-0.2 + 0.1 * k, 0), SE3::Identity()));
    for (int k = 0; k < kPerSide; ++k)
      newer_.push_back(addKeyFrame(kPerSide + k, 10 + 0.1 * k, cameraAt(-0.15 + 0.1 * k, 0.05), drift_));
    older_[0]->origin = true;
    // One spanning tree: the newer group hangs on the older through the way
    // between them, whose drift the link holds.
    for (int k = 1; k < 2 * kPerSide; ++k) {
      KeyFrame* kf = k < kPerSide ? older_[k] : newer_[k - kPerSide];
      KeyFrame* parent = k < kPerSide ? older_[k - 1] : (k == kPerSide ? older_.back() : newer_[k - kPerSide - 1]);
      kf->parent = parent;
      parent->children.push_back(kf);
    }
    for (KeyFrame* kf : older_) kf->updateConnections();
    for (KeyFrame* kf : newer_) kf->updateConnections();
  }

  // The newer group's world: 6 cm and 2 degrees off.
  virtual SE3 newerWorld() const {
    SE3 world = SE3::Identity();
    world.linear() = Eigen::AngleAxisd(2 * M_PI / 180, Vec3::UnitY()).toRotationMatrix();
    world.translation() = Vec3(0.05, -0.02, 0.03);
    return world;
  }

  static SE3 cameraAt(double x, double y) {
    SE3 T_w_c = SE3::Identity();
    T_w_c.translation() = Vec3(x, y, 0);
    return T_w_c.inverse();
  }

  // A frame at true pose T_c_w that sees the wall points in `which` (all when
  // empty), in a world `world` (a point p of the wall is at world * p there).
  Frame frameAt(std::int64_t id, double t, const SE3& T_c_w, const SE3& world, std::vector<int>* seen,
                const std::vector<int>& which = {}) const {
    Frame f;
    f.id = id;
    f.stamp = Timestamp::fromSeconds(1000 + t);
    f.camera = &camera_;
    f.levels = &testing::oneLevel();
    f.T_c_w = renormalized(T_c_w * world.inverse());
    std::vector<int> ids;
    for (int i = 0; i < kPoints; ++i) {
      if (!which.empty() && !std::binary_search(which.begin(), which.end(), i)) continue;
      const Vec3 pc = T_c_w * wall_[i];
      const Vec2 uv = camera_.project(pc);
      if (uv.x() < 10 || uv.y() < 10 || uv.x() > camera_.width - 10 || uv.y() > camera_.height - 10) continue;
      ids.push_back(i);
      cv::KeyPoint key(static_cast<float>(uv.x()), static_cast<float>(uv.y()), 31);
      f.keys.push_back(key);
      f.un.push_back(key.pt);
      f.depth.push_back(static_cast<float>(pc.z()));
      f.u_right.push_back(static_cast<float>(uv.x() - camera_.bf() / pc.z()));
    }
    f.descriptors = cv::Mat(static_cast<int>(ids.size()), 32, CV_8U);
    for (std::size_t k = 0; k < ids.size(); ++k) descriptors_.row(ids[k]).copyTo(f.descriptors.row(static_cast<int>(k)));
    f.grid.build(f.un, camera_.width, camera_.height);
    f.clearMatches();
    f.dynamic.assign(ids.size(), kNotDynamic);
    f.cluster.assign(ids.size(), -1);
    if (seen) *seen = ids;
    return f;
  }

  // A keyframe of one group: its points are the group's own (made by its
  // first keyframe that sees them), in the group's world.
  KeyFrame* addKeyFrame(std::int64_t id, double t, const SE3& T_c_w, const SE3& world) {
    std::vector<int> seen;
    KeyFrame* kf = map_.addKeyFrame(std::make_unique<KeyFrame>(id, frameAt(id, t, T_c_w, world, &seen)));
    truth_[id] = T_c_w;
    auto& points = world.isApprox(SE3::Identity()) ? older_points_ : newer_points_;
    for (std::size_t k = 0; k < seen.size(); ++k) {
      std::shared_ptr<MapPoint>& p = points[seen[k]];
      if (!p) {
        p = map_.createPoint(world * wall_[seen[k]], kf);
        descriptors_.row(seen[k]).copyTo(cv::Mat(1, 32, CV_8U, p->descriptor.data()));
      }
      kf->addObservation(p, static_cast<int>(k));
    }
    for (auto& [i, p] : points) p->updateFromObservations();
    return kf;
  }

  // The newer group mapped another wall: none of its points looks like a
  // feature of a frame of this one.
  void newerGroupMapsAnotherWall() {
    std::mt19937 rng(11);
    std::uniform_int_distribution<int> byte(0, 255);
    for (KeyFrame* kf : newer_)
      for (int r = 0; r < kf->frame.descriptors.rows; ++r)
        for (int b = 0; b < kf->frame.descriptors.cols; ++b)
          kf->frame.descriptors.at<std::uint8_t>(r, b) = static_cast<std::uint8_t>(byte(rng));
    for (auto& [i, p] : newer_points_) p->updateFromObservations();
  }

  double newestError() const {
    const SE3 T = newer_.back()->T_c_w() * truth_.at(newer_.back()->id).inverse();
    return T.translation().norm();
  }

  CameraModel camera_ = testing::vgaCamera();
  Map map_;
  std::vector<Vec3> wall_;
  cv::Mat descriptors_;
  SE3 drift_ = SE3::Identity();
  std::vector<KeyFrame*> older_, newer_;
  std::map<int, std::shared_ptr<MapPoint>> older_points_, newer_points_;
  std::map<std::int64_t, SE3> truth_;
};

namespace {

TEST_F(Crossing, AFrameTrackedOnTheOlderGroupPutsTheNewerBackOnIt) {
  const double before_m = newestError();
  ASSERT_GT(before_m, 0.04);
  // Tracking is on the older group (its world is the truth here), seconds
  // after the newest keyframe was made.
  const Frame frame = frameAt(100, 12, cameraAt(0.02, 0.02), SE3::Identity(), nullptr);
  SlamOptions options;
  LoopCloser closer(options, camera_, &map_);
  std::int64_t newest = -1;
  {
    std::shared_lock lock(map_.mutex());
    newest = closer.crossingDue(*older_[2], frame.stamp);
  }
  ASSERT_EQ(newest, newer_.back()->id);
  closer.processCrossing(frame, {}, older_[2]->id, newest, map_.epoch());
  const LoopStats stats = closer.stats();
  EXPECT_EQ(stats.crossings_checked, 1);
  ASSERT_EQ(stats.crossings_closed, 1);
  EXPECT_EQ(stats.closed, 1);
  const double after_m = newestError();
  std::printf("newest keyframe off the truth: %.4f m before the crossing, %.4f m after\n", before_m, after_m);
  EXPECT_LT(after_m, 0.25 * before_m);
  // The newer group's points were fused into the older group's.
  EXPECT_GT(newer_.back()->connections.count(older_[2]) + newer_.back()->connections.count(older_[3]), 0u);
  // The origin stays.
  EXPECT_LT((older_[0]->T_c_w() * truth_.at(0).inverse()).translation().norm(), 1e-9);
}

TEST_F(Crossing, AFrameTheNewerGroupDoesNotSeeClosesNothing) {
  newerGroupMapsAnotherWall();
  const Frame frame = frameAt(100, 12, cameraAt(0.02, 0.02), SE3::Identity(), nullptr);
  const SE3 newest_before = newer_.back()->T_c_w();
  SlamOptions options;
  LoopCloser closer(options, camera_, &map_);
  closer.processCrossing(frame, {}, older_[2]->id, newer_.back()->id, map_.epoch());
  EXPECT_EQ(closer.stats().crossings_checked, 1);
  EXPECT_EQ(closer.stats().crossings_closed, 0);
  EXPECT_EQ(closer.stats().closed, 0);
  EXPECT_TRUE(newer_.back()->T_c_w().isApprox(newest_before));
}

TEST_F(Crossing, WaitsLongerAfterEachCheckThatClosedNothing) {
  newerGroupMapsAnotherWall();  // every check fails
  LoopCloser closer(SlamOptions{}, camera_, &map_);
  auto due = [&](double t) {
    std::shared_lock lock(map_.mutex());
    return closer.crossingDue(*older_[2], Timestamp::fromSeconds(1000 + t));
  };
  auto check = [&](double t) {
    const std::int64_t newest = due(t);
    if (newest < 0) return false;
    closer.processCrossing(frameAt(100, t, cameraAt(0.02, 0.02), SE3::Identity(), nullptr), {}, older_[2]->id,
                           newest, map_.epoch());
    return true;
  };
  // Tracking asks every frame (30 Hz) for 43 s: the checks come 1, 2, 4 s
  // apart, then every 8 s.
  std::vector<double> checked;
  for (int f = 0; f < 1300; ++f)
    if (check(12 + f / 30.0)) checked.push_back(12 + f / 30.0);
  ASSERT_EQ(checked.size(), 8u);
  const double gaps[] = {1, 2, 4, 8, 8, 8, 8};
  for (std::size_t k = 0; k + 1 < checked.size(); ++k)
    EXPECT_NEAR(checked[k + 1] - checked[k], gaps[k], 1.0 / 30 + 1e-9) << "after check " << k + 1;
  EXPECT_EQ(closer.stats().crossings_checked, 8);
  EXPECT_EQ(closer.stats().crossings_closed, 0);
  // A new newest keyframe (the camera mapped new ground): 0.5 s again.
  const double last = checked.back();
  std::unique_lock lock(map_.mutex());
  KeyFrame* kf =
      map_.addKeyFrame(std::make_unique<KeyFrame>(20, frameAt(20, last, cameraAt(0.4, 0.05), drift_, nullptr)));
  kf->parent = newer_.back();
  newer_.back()->children.push_back(kf);
  lock.unlock();
  EXPECT_EQ(due(last + 0.3), -1);
  EXPECT_EQ(due(last + 0.55), kf->id);
}

// The two groups mapped the wall 2 mm and 0.1 degrees apart: as close as two
// fits of one frame come, and what a map an earlier loop joined looks like.
class CrossingWithoutSeam : public Crossing {
 protected:
  SE3 newerWorld() const override {
    SE3 world = SE3::Identity();
    world.linear() = Eigen::AngleAxisd(0.1 * M_PI / 180, Vec3::UnitY()).toRotationMatrix();
    world.translation() = Vec3(0.001, -0.001, 0.001);
    return world;
  }
};

TEST_F(CrossingWithoutSeam, ClosesNothingOnceAGlobalBaHasSeenTheNewerSide) {
  const Frame frame = frameAt(100, 12, cameraAt(0.02, 0.02), SE3::Identity(), nullptr);
  const SE3 newest_before = newer_.back()->T_c_w();
  const std::uint64_t epoch = map_.epoch();
  LoopCloser closer(SlamOptions{}, camera_, &map_);
  coveredByAGlobalBa(&closer);
  closer.processCrossing(frame, {}, older_[2]->id, newer_.back()->id, epoch);
  EXPECT_EQ(closer.stats().crossings_checked, 1);
  EXPECT_EQ(closer.stats().crossings_closed, 0);
  EXPECT_EQ(closer.stats().closed, 0);
  EXPECT_EQ(map_.epoch(), epoch);
  EXPECT_TRUE(newer_.back()->T_c_w().isApprox(newest_before));
}

TEST_F(CrossingWithoutSeam, ClosesWhereNoGlobalBaHasSeenTheNewerSide) {
  // Keyframes made since the last global BA: the loop and a global BA place
  // them with the rest.
  const Frame frame = frameAt(100, 12, cameraAt(0.02, 0.02), SE3::Identity(), nullptr);
  LoopCloser closer(SlamOptions{}, camera_, &map_);
  closer.processCrossing(frame, {}, older_[2]->id, newer_.back()->id, map_.epoch());
  EXPECT_EQ(closer.stats().crossings_closed, 1);
  EXPECT_EQ(closer.stats().global_ba_runs, 1);
}

TEST_F(Crossing, IsNotDueWhereTheReferenceIsCovisibleWithTheNewestKeyFrame) {
  std::shared_lock lock(map_.mutex());
  LoopCloser closer(SlamOptions{}, camera_, &map_);
  // Within the newer group itself: no crossing.
  EXPECT_EQ(closer.crossingDue(*newer_[3], Timestamp::fromSeconds(1012)), -1);
  // Into the older group: due, then not again within half a second.
  EXPECT_EQ(closer.crossingDue(*older_[1], Timestamp::fromSeconds(1012)), newer_.back()->id);
  EXPECT_EQ(closer.crossingDue(*older_[1], Timestamp::fromSeconds(1012.2)), -1);
}

}  // namespace
}  // namespace stillpoint::slam
