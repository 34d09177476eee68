// Map bookkeeping that bounds memory: culled keyframes are freed, and poses
// expressed through them (trajectory records) still resolve and still follow
// the keyframes that remain.
#include "map.hpp"
#include "map_io.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <vector>

namespace stillpoint::slam {
namespace {

SE3 pose(double tx, double ty, double tz, double yaw) {
  SE3 T = SE3::Identity();
  T.linear() = Eigen::AngleAxisd(yaw, Vec3::UnitY()).toRotationMatrix();
  T.translation() = Vec3(tx, ty, tz);
  return T;
}

bool near(const SE3& a, const SE3& b) { return (a.matrix() - b.matrix()).cwiseAbs().maxCoeff() < 1e-12; }

// Keyframes 0 <- 1 <- 2 (spanning tree), sharing points: 40 seen by all
// three, 20 by 1 and 2, 10 by 1 alone.
class CulledKeyFrames : public ::testing::Test {
 protected:
  void SetUp() override {
    kf0_ = map_.addKeyFrame(testing::handMadeKeyFrame(0, 70, pose(0, 0, 0, 0)));
    kf1_ = map_.addKeyFrame(testing::handMadeKeyFrame(1, 70, pose(0.1, 0, 0, 0.05)));
    for (int i = 0; i < 40; ++i) observe(map_.createPoint(Vec3(i, 0, 2), kf1_), {kf0_, kf1_}, i);
    for (int i = 40; i < 50; ++i) only_kf1_.push_back(observe(map_.createPoint(Vec3(i, 1, 2), kf1_), {kf1_}, i));
    kf1_->updateConnections();
    kf2_ = map_.addKeyFrame(testing::handMadeKeyFrame(2, 70, pose(0.2, 0, 0.05, 0.1)));
    for (int i = 0; i < 40; ++i) kf2_->addObservation(kf1_->frame.points[i], i);
    for (int i = 50; i < 70; ++i) shared_12_.push_back(observe(map_.createPoint(Vec3(i, 2, 2), kf1_), {kf1_, kf2_}, i));
    kf2_->updateConnections();
    ASSERT_EQ(kf1_->parent, kf0_);
    ASSERT_EQ(kf2_->parent, kf1_);
  }

  std::shared_ptr<MapPoint> observe(std::shared_ptr<MapPoint> p, std::vector<KeyFrame*> kfs, int index) {
    for (KeyFrame* kf : kfs) kf->addObservation(p, index);
    return p;
  }

  Map map_;
  KeyFrame *kf0_ = nullptr, *kf1_ = nullptr, *kf2_ = nullptr;
  std::vector<std::shared_ptr<MapPoint>> only_kf1_, shared_12_;
};

TEST_F(CulledKeyFrames, AreFreedAndPosesThroughThemStillResolve) {
  // What trajectory records hold: anchors, and poses relative to them.
  const std::shared_ptr<const PoseAnchor> at1 = kf1_->anchor(), at2 = kf2_->anchor();
  const SE3 T1_w = kf1_->T_c_w(), T2_w = kf2_->T_c_w();
  std::vector<std::weak_ptr<MapPoint>> watched(only_kf1_.begin(), only_kf1_.end());
  only_kf1_.clear();
  const std::size_t points_before = map_.pointsInMemory();

  // Child first, then its parent: the chain 2 -> 1 -> 0 must hold.
  map_.setKeyFrameBad(kf2_);
  map_.setKeyFrameBad(kf1_);
  EXPECT_TRUE(near(at2->T_c_w(), T2_w));
  EXPECT_TRUE(near(at1->T_c_w(), T1_w));
  // Points seen by 1 and 2 only lost both observers; their reference must
  // not point at a keyframe about to be freed.
  for (const auto& p : shared_12_) {
    EXPECT_TRUE(p->bad);
    EXPECT_EQ(p->reference, nullptr);
  }

  EXPECT_EQ(map_.releaseCulledKeyFrames(), 2u);
  ASSERT_EQ(map_.keyframes().size(), 1u);
  EXPECT_EQ(map_.keyFrame(0), kf0_);
  EXPECT_EQ(map_.keyFrame(1), nullptr);
  EXPECT_EQ(map_.keyFrame(2), nullptr);
  EXPECT_EQ(map_.nextKeyFrameId(), 3) << "ids are never reused";
  EXPECT_TRUE(kf0_->children.empty());
  EXPECT_TRUE(kf0_->connections.empty());
  for (const auto& w : watched) EXPECT_TRUE(w.expired()) << "a point only the culled keyframe held must be freed";
  EXPECT_LT(map_.pointsInMemory(), points_before);

  // The freed keyframes' poses resolve as before, and follow keyframe 0 when
  // bundle adjustment moves it.
  EXPECT_TRUE(near(at2->T_c_w(), T2_w));
  EXPECT_TRUE(near(at1->T_c_w(), T1_w));
  const SE3 T0_old = kf0_->T_c_w();
  kf0_->T_c_w() = pose(0.01, -0.02, 0.03, 0.02) * T0_old;
  const SE3 expected = renormalized(T2_w * T0_old.inverse() * kf0_->T_c_w());
  EXPECT_LT((at2->T_c_w().matrix() - expected.matrix()).cwiseAbs().maxCoeff(), 1e-9);
}

TEST_F(CulledKeyFrames, ChildrenMoveToTheParentAndReferencesToTheRemainingObserver) {
  map_.setKeyFrameBad(kf1_);
  EXPECT_EQ(kf2_->parent, kf0_);
  ASSERT_EQ(kf0_->children.size(), 1u);
  EXPECT_EQ(kf0_->children[0], kf2_);
  for (int i = 0; i < 40; ++i) {
    const auto& p = kf2_->frame.points[i];
    ASSERT_TRUE(p);
    EXPECT_FALSE(p->bad) << "still seen by keyframes 0 and 2";
    EXPECT_EQ(p->reference, kf0_);
  }
  for (const auto& p : shared_12_) {
    EXPECT_TRUE(p->bad) << "one observer left";
    EXPECT_EQ(p->reference, nullptr);
  }
  for (const auto& p : only_kf1_) {
    EXPECT_TRUE(p->bad);
    EXPECT_EQ(p->reference, nullptr);
  }
  EXPECT_EQ(map_.releaseCulledKeyFrames(), 1u);
  EXPECT_EQ(map_.keyframes().size(), 2u);
  EXPECT_EQ(map_.goodKeyFrameCount(), 2u);
  // Keyframe 2 keeps working with the survivors.
  kf2_->updateConnections();
  EXPECT_EQ(kf2_->bestNeighbours(5), std::vector<KeyFrame*>{kf0_});
}

// A culled keyframe is linked to nothing and stays so: updating its
// connections afterwards (a late segmentation result, applied to a keyframe
// culled while it waited) must not link it back into its neighbours, which
// would hold it after it is freed (a crash in sequential runs with
// semantic.sequential_latency_frames).
TEST_F(CulledKeyFrames, StayUnlinkedWhenTheirConnectionsAreUpdatedLate) {
  map_.setKeyFrameBad(kf1_);
  kf1_->updateConnections();
  EXPECT_TRUE(kf1_->connections.empty());
  for (KeyFrame* kf : {kf0_, kf2_}) {
    EXPECT_EQ(kf->connections.count(kf1_), 0u) << "keyframe " << kf->id;
    for (KeyFrame* n : kf->ordered_neighbours) EXPECT_NE(n, kf1_) << "keyframe " << kf->id;
  }
  EXPECT_EQ(map_.releaseCulledKeyFrames(), 1u);
  kf2_->updateConnections();
  EXPECT_EQ(kf2_->bestNeighbours(5), std::vector<KeyFrame*>{kf0_});
}

// A map file whose spanning tree has a cycle (a corrupt or hand-edited file
// with a valid checksum) is refused: culling and the poses expressed through
// culled keyframes would walk the cycle forever.
TEST_F(CulledKeyFrames, AFileWhoseParentsFormACycleIsRefused) {
  CameraModel camera;
  camera.fx = camera.fy = 500;
  camera.cx = 320;
  camera.cy = 240;
  const std::string dir = ::testing::TempDir();
  const std::string tree = dir + "/stillpoint_tree.map", cycle = dir + "/stillpoint_cycle.map";
  map_.beginMap();  // as tracking does before its first keyframe, and the frames' ids
  for (int k = 0; k < 3; ++k) map_.nextFrameId();
  ASSERT_TRUE(saveMap(map_, camera, testing::oneLevel(), tree).ok());
  kf0_->parent = kf2_;  // 0 -> 2 -> 1 -> 0
  ASSERT_TRUE(saveMap(map_, camera, testing::oneLevel(), cycle).ok());
  kf0_->parent = nullptr;

  Map loaded;
  const Status good = loadMap(tree, camera, testing::oneLevel(), &loaded);
  ASSERT_TRUE(good.ok()) << good.error();
  EXPECT_EQ(loaded.keyFrame(2)->parent, loaded.keyFrame(1));
  Map refused;
  const Status bad = loadMap(cycle, camera, testing::oneLevel(), &refused);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().find("cycle"), std::string::npos) << bad.error();
  std::remove(tree.c_str());
  std::remove(cycle.c_str());
}

// Maps are kept apart by their whole id: maps started thousands of losses
// apart keep their sightings apart, and a merge moves only its own map's
// cells.
TEST(StaticSightings, KeepTheMapsOfALongRunApart) {
  for (const Eigen::Vector3i& cell : {Eigen::Vector3i(3, -2, 7), Eigen::Vector3i(-(1 << 20) + 1, 0, (1 << 20) - 1)})
    EXPECT_EQ(cellOfKey(cellKey(cell)), cell);
  StaticSightings sightings;
  const Vec3 p(0.35, -0.15, 0.75);
  for (int k = 0; k < 3; ++k)
    sightings.add(1024, Timestamp::fromNanoseconds(k * 1'000'000'000LL), {p}, {});
  EXPECT_TRUE(sightings.seenStanding(1024, p, 3, 1.0));
  for (std::uint32_t other : {0u, 256u, 2048u, 1024u + (1u << 22)})
    EXPECT_FALSE(sightings.seenStanding(other, p, 1, 0.0)) << other;
  sightings.moveMap(0, 1, SE3::Identity());
  sightings.moveMap(2048, 1, SE3::Identity());
  EXPECT_TRUE(sightings.seenStanding(1024, p, 3, 1.0));
  EXPECT_FALSE(sightings.seenStanding(1, p, 1, 0.0));
  const std::size_t cells = sightings.cells();
  sightings.moveMap(1024, 5, SE3::Identity());
  EXPECT_FALSE(sightings.seenStanding(1024, p, 1, 0.0));
  EXPECT_TRUE(sightings.seenStanding(5, p, 3, 1.0));
  EXPECT_EQ(sightings.cells(), cells);
}

TEST(MapPoint, ReferenceIsDroppedWithItsObservation) {
  Map map;
  KeyFrame* a = map.addKeyFrame(testing::handMadeKeyFrame(0, 4, SE3::Identity()));
  KeyFrame* b = map.addKeyFrame(testing::handMadeKeyFrame(1, 4, SE3::Identity()));
  auto p = map.createPoint(Vec3(0, 0, 1), b);
  a->addObservation(p, 0);
  b->addObservation(p, 1);
  b->eraseObservation(1);  // as bundle adjustment does for an outlier
  EXPECT_EQ(p->reference, nullptr);
  EXPECT_EQ(p->observations.size(), 1u);
  p->updateFromObservations();  // falls back to the remaining observer
  EXPECT_FALSE(p->bad);
}

// Keyframes are found by the words of their views; culled ones and those
// the filter refuses are not, and the best match comes first.
// The semantic module's hold: the points of a keyframe sent for
// segmentation wait until a result at or after it comes back. Results come
// in keyframe order, so a newer keyframe's result also ends the wait of one
// the full queue dropped; a keyframe never sent (no colour image) after the
// newest sent one never waits.
TEST(Map, PointsAwaitTheirKeyframesMaskUntilAResultAtOrAfterItComesBack) {
  Map map;
  EXPECT_FALSE(map.awaitingMask(0)) << "nothing sent yet";
  map.maskRequested(0);
  map.maskRequested(1);
  EXPECT_TRUE(map.awaitingMask(0));
  EXPECT_TRUE(map.awaitingMask(1));
  EXPECT_FALSE(map.awaitingMask(2)) << "keyframe 2 was not sent";
  map.maskResolved(0);
  EXPECT_FALSE(map.awaitingMask(0));
  EXPECT_TRUE(map.awaitingMask(1));
  map.maskRequested(2);
  map.maskRequested(3);
  map.maskResolved(3);  // 1 and 2 were dropped from the queue
  for (int id = 0; id <= 3; ++id) EXPECT_FALSE(map.awaitingMask(id)) << "keyframe " << id;
  map.maskResolved(2);  // late and out of order: changes nothing
  map.maskRequested(5);
  EXPECT_FALSE(map.awaitingMask(3));
  EXPECT_TRUE(map.awaitingMask(4)) << "made while 5 was under way: 5's result ends its wait";
  EXPECT_TRUE(map.awaitingMask(5));
}

// A keyframe that stops sharing points with a neighbour leaves both sides of
// the link: the neighbour's ordered list too, or it would point at the
// keyframe after it is culled and freed (seen as a use-after-free in a live
// replay).
TEST(Map, AKeyframeThatLosesItsSharedPointsLeavesItsOldNeighbourEntirely) {
  Map map;
  KeyFrame* a = map.addKeyFrame(testing::handMadeKeyFrame(0, 40, SE3::Identity()));
  KeyFrame* b = map.addKeyFrame(testing::handMadeKeyFrame(1, 40, SE3::Identity()));
  for (int i = 0; i < 30; ++i) {
    auto p = map.createPoint(Vec3(0.1 * i, 0, 2), a);
    a->addObservation(p, i);
    b->addObservation(p, i);
  }
  b->updateConnections();
  ASSERT_EQ(a->bestNeighbours(5), std::vector<KeyFrame*>{b});
  for (int i = 0; i < 30; ++i) b->eraseObservation(i);
  b->updateConnections();
  EXPECT_FALSE(a->connections.count(b));
  EXPECT_TRUE(std::find(a->ordered_neighbours.begin(), a->ordered_neighbours.end(), b) == a->ordered_neighbours.end());
}

// A map started after the active one merged into (or tracking moved back to)
// an older map takes a new id, never one that older keyframes still carry.
TEST(Map, MapIdsAreNeverReused) {
  Map map;
  std::unique_lock lock(map.mutex());
  EXPECT_EQ(map.beginMap(), 0u);
  EXPECT_EQ(map.beginMap(), 1u);
  EXPECT_EQ(map.beginMap(), 2u);
  map.activate(0);  // map 2 joined map 0; map 1 is still there
  EXPECT_EQ(map.activeMapId(), 0u);
  EXPECT_EQ(map.beginMap(), 3u);
  map.activate(1);
  EXPECT_EQ(map.activeMapId(), 1u);
  EXPECT_EQ(map.beginMap(), 4u);
  EXPECT_EQ(map.mapsStarted(), 5u);
}

TEST(PlaceRecognition, SimilarKeyFramesRanksByScoreAndForgetsCulledOnes) {
  Map map;
  std::unique_lock lock(map.mutex());
  map.beginMap();
  auto words = [](std::initializer_list<features::WordId> ids) {
    features::BowVector v;
    for (features::WordId w : ids) v.entries.emplace_back(w, 1.0f / static_cast<float>(ids.size()));
    return v;
  };
  std::vector<KeyFrame*> kfs;
  for (int k = 0; k < 4; ++k) {
    auto kf = testing::handMadeKeyFrame(k, 4, SE3::Identity());
    kf->origin = k == 0;
    kf->bow = k == 0 ? words({1, 2, 3, 4}) : k == 1 ? words({1, 2, 3, 9}) : k == 2 ? words({1, 7, 8, 9}) : words({20, 21});
    kfs.push_back(map.addKeyFrame(std::move(kf)));
  }
  const features::BowVector query = words({1, 2, 3, 4});
  auto all = [](const KeyFrame*) { return true; };
  auto found = map.similarKeyFrames(query, all, 0.0, 10);
  ASSERT_FALSE(found.empty());
  EXPECT_EQ(found[0].keyframe, kfs[0]);
  EXPECT_DOUBLE_EQ(found[0].score, 1.0);
  for (const auto& m : found) EXPECT_NE(m.keyframe, kfs[3]);  // no word in common
  // Only those sharing nearly as many words as the best are scored.
  EXPECT_EQ(found.size(), 1u);
  found = map.similarKeyFrames(query, [&](const KeyFrame* kf) { return kf != kfs[0]; }, 0.0, 10);
  ASSERT_FALSE(found.empty());
  EXPECT_EQ(found[0].keyframe, kfs[1]);
  EXPECT_NEAR(found[0].score, 0.75, 1e-6);
  EXPECT_TRUE(map.similarKeyFrames(query, [&](const KeyFrame* kf) { return kf != kfs[0]; }, 0.8, 10).empty());
  map.setKeyFrameBad(kfs[1]);
  found = map.similarKeyFrames(query, [&](const KeyFrame* kf) { return kf != kfs[0]; }, 0.0, 10);
  ASSERT_FALSE(found.empty());
  EXPECT_EQ(found[0].keyframe, kfs[2]);
}

// Far points seen past a near mover: 60 on a wall 3-5 m away, with depth
// noise as a camera's; 20 of the mover's features matched by chance to far
// points, 15 of them too near for depth, 5 with it; others fitted out or
// without depth. A pose 8 cm back along the view shows as the wall's median
// offset; the mover's few features with depth barely move it.
TEST(DepthOffset, TellsAPoseOffAlongTheViewFromTheInliersDepth) {
  const int n = 90;
  Frame f;
  f.keys.resize(n);
  f.depth.assign(n, 0.0f);
  f.points.resize(n);
  f.outlier.assign(n, 0);
  std::uint32_t seed = 7;
  const auto noise = [&seed] {  // uniform in [-1, 1]
    seed = seed * 1664525u + 1013904223u;
    return static_cast<double>(seed >> 8) / (1u << 23) - 1.0;
  };
  for (int i = 0; i < n; ++i) {
    const double z = i < 60 ? 3.0 + 2.0 * i / 60 : 4.0;
    f.points[i] = std::make_shared<MapPoint>(i, Vec3(0.01 * i - 0.4, 0.2, z), nullptr);
    if (i < 60) f.depth[i] = static_cast<float>(z + 0.01 * z * z * noise());
    if (i >= 75 && i < 80) f.depth[i] = 0.4f;  // on the mover, its map point far behind it
    if (i >= 80) f.outlier[i] = i % 2, f.depth[i] = i % 2 ? 0.5f : 0.0f;  // fitted out, or no depth
  }
  f.T_c_w = SE3::Identity();
  const DepthOffset right = depthOffset(f);
  EXPECT_EQ(right.samples, 65);
  EXPECT_LT(std::abs(right.metres), 0.03);
  f.T_c_w.translation() = Vec3(0, 0, 0.08);  // the camera 8 cm behind
  const DepthOffset back = depthOffset(f);
  EXPECT_LT(back.metres, -0.06);
  EXPECT_GT(back.metres, -0.10);
  EXPECT_GT(back.standard_error, 0.0);
  EXPECT_LT(back.standard_error, 0.04);
  EXPECT_GT(std::abs(back.metres), 3 * back.standard_error);
  EXPECT_FALSE(offAlongView(right));
  EXPECT_TRUE(offAlongView(back));
  // As far off, but too few with depth, or too noisy to tell.
  EXPECT_FALSE(offAlongView({back.metres, back.standard_error, 9}));
  EXPECT_FALSE(offAlongView({back.metres, std::abs(back.metres) / 2.5, back.samples}));
  EXPECT_FALSE(offAlongView({0.045, 0.001, back.samples}));  // under 5 cm
  // Without the mover's features, the wall alone: its median within its noise.
  for (int i = 60; i < 80; ++i) f.outlier[i] = 1;
  f.T_c_w = SE3::Identity();
  const DepthOffset wall = depthOffset(f);
  EXPECT_EQ(wall.samples, 60);
  EXPECT_LT(std::abs(wall.metres), 3 * wall.standard_error + 0.005);
  f.depth.assign(n, 0.0f);
  EXPECT_EQ(depthOffset(f).samples, 0);
}

// A lost frame placed by several keyframes: the best supported of the poses
// another one agrees with, not a lone pose with more inliers.
TEST(AgreedPlacement, TakesTheBestSupportedPoseThatAnotherAgreesWith) {
  const auto camera_at = [](const Vec3& centre, double yaw_deg) {
    SE3 T_w_c = SE3::Identity();
    T_w_c.linear() = Eigen::AngleAxisd(yaw_deg * M_PI / 180, Vec3::UnitY()).toRotationMatrix();
    T_w_c.translation() = centre;
    return SE3(T_w_c.inverse());
  };
  const Vec3 c(1.0, -0.2, 2.0);
  const SE3 right = camera_at(c, 30), near = camera_at(c + Vec3(0.02, 0.01, -0.02), 31.5);
  const SE3 sideways = camera_at(c + Vec3(0.15, 0, 0), 28), turned = camera_at(c, 34);
  EXPECT_EQ(agreedPlacement({right, sideways, near}, {90, 250, 120}), 2);
  EXPECT_EQ(agreedPlacement({right, sideways, near}, {130, 250, 120}), 0);
  // 4 degrees turned, or 15 cm away: no agreement.
  EXPECT_EQ(agreedPlacement({right, turned}, {90, 80}), -1);
  EXPECT_EQ(agreedPlacement({right, sideways}, {90, 80}), -1);
  // The cameras' centres are compared: 2 degrees about the same centre 2.2 m
  // from the origin move T_c_w's translation by 7.7 cm.
  const SE3 same_centre = camera_at(c, 32);
  ASSERT_GT((same_centre.translation() - right.translation()).norm(), 0.07);
  EXPECT_EQ(agreedPlacement({right, same_centre}, {90, 80}), 0);
  EXPECT_EQ(agreedPlacement({right}, {90}), -1);
  EXPECT_EQ(agreedPlacement({}, {}), -1);
}

}  // namespace
}  // namespace stillpoint::slam
