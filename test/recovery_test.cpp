// Recovery on real data: the camera covered for 2 s while it moves (black
// colour, zero depth), and a view tracking cannot place (mirrored frames). Frames without depth
// must say so, and once depth is back at least 95 % of the frames must have a
// pose: found in the map again, or in a new map started after
// tracking.new_map_after_lost_s, whose frames the geometry module judges
// against that map's frames only. And the other side of it: the untouched
// static scene is never distrusted.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <set>

#include <opencv2/core.hpp>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/eval/metrics.hpp"
#include "stillpoint/eval/trajectory.hpp"
#include "stillpoint/slam/system.hpp"

namespace stillpoint {
namespace {

class Recovery : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string dir = std::string(STILLPOINT_DATA_DIR) + "/tum_fr3_teddy_200";
    if (!std::filesystem::exists(dir + "/rgb.txt")) GTEST_SKIP() << "no sequence at " << dir;
    auto data = dataset::TumDataset::open(dir);
    ASSERT_TRUE(data.ok()) << data.error();
    data_ = std::make_unique<dataset::TumDataset>(std::move(*data));
    camera_ = *cameraPreset("fr3");
  }

  std::unique_ptr<slam::SlamSystem> makeSystem(int num_features = 0, bool report_features = false) {
    slam::SlamOptions options;
    options.sequential = true;
    options.geometry.report_features = report_features;
    if (num_features > 0) options.orb.num_features = num_features;
    auto system = slam::SlamSystem::create(camera_, options);
    EXPECT_TRUE(system.ok()) << system.error();
    return system.ok() ? std::move(*system) : nullptr;
  }

  // A covered camera: black colour, no depth.
  static void cover(slam::RgbdInput* input) {
    input->gray = cv::Mat(input->gray.size(), CV_8UC1, cv::Scalar(0));
    input->bgr = cv::Mat(input->bgr.size(), CV_8UC3, cv::Scalar::all(0));
    input->depth_m = cv::Mat(input->depth_m.size(), CV_32FC1, cv::Scalar(0));
  }

  std::unique_ptr<dataset::TumDataset> data_;
  CameraModel camera_;
};

TEST_F(Recovery, CameraCoveredForTwoSecondsWhileMoving) {
  auto system = makeSystem(0, /*report_features=*/true);
  ASSERT_TRUE(system);
  constexpr std::size_t kCoverFrom = 60, kCoverTo = 120;  // 60 frames, 2 s at 30 Hz
  std::size_t no_depth = 0, after = 0, after_with_pose = 0, checked = 0;
  std::set<std::uint32_t> maps;
  std::optional<std::size_t> new_map_at;
  std::optional<SE3> last_before_cover, new_map_start;
  for (std::size_t i = 0; i < data_->size(); ++i) {
    auto frame = data_->load(i);
    ASSERT_TRUE(frame.ok()) << frame.error();
    slam::RgbdInput input{frame->stamp, frame->gray, frame->depth_m, frame->bgr};
    const bool covered = i >= kCoverFrom && i < kCoverTo;
    if (covered) {
      cover(&input);
    }
    auto out = system->track(input);
    ASSERT_TRUE(out.ok()) << out.error();
    if (i < kCoverFrom) {
      ASSERT_TRUE(slam::hasPose(out->state)) << "frame " << i << ": " << toString(out->state);
      // A static scene, well tracked: nothing to distrust.
      EXPECT_EQ(out->quality.health, slam::PoseHealth::kGood)
          << "frame " << i << ": " << toString(out->quality.health) << ", " << out->quality.inliers << " inliers, "
          << out->quality.dynamic_share << " dynamic, " << out->quality.reprojection_rms_px << " px, conditioning "
          << out->quality.conditioning;
    }
    if (covered) {
      EXPECT_EQ(out->state, slam::TrackingState::kNoDepth) << "frame " << i;
      EXPECT_EQ(out->quality.health, slam::PoseHealth::kLost) << "frame " << i;
      no_depth += out->state == slam::TrackingState::kNoDepth;
    }
    // A map started after the cover is judged against its own frames only:
    // the geometry module's frames from before the cover hang in the old
    // map's world (no frame without depth clears them).
    if (i < kCoverFrom && slam::hasPose(out->state)) last_before_cover = out->T_w_c;
    if (out->state == slam::TrackingState::kNewMap) {
      new_map_at = i;
      new_map_start = out->T_w_c;
    }
    if (new_map_at && i > *new_map_at && i <= *new_map_at + 5) {
      const int frames_in_map = static_cast<int>(i - *new_map_at);
      for (const auto& f : out->geometry.judged) {
        if (f.evidence != slam::JudgedFeature::Evidence::kAnchor) continue;
        ++checked;
        ASSERT_LE(f.baseline, frames_in_map) << "frame " << i << ": anchor from before map " << out->map_id;
      }
    }
    if (i >= kCoverTo) {
      ++after;
      after_with_pose += slam::hasPose(out->state);
      if (slam::hasPose(out->state)) maps.insert(out->map_id);
    }
  }
  system->finish();
  EXPECT_EQ(no_depth, kCoverTo - kCoverFrom);
  EXPECT_EQ(system->mapStats().no_depth_frames, kCoverTo - kCoverFrom);
  EXPECT_GE(after_with_pose, (after * 95 + 99) / 100) << after_with_pose << " of " << after << " frames after the cover";
  EXPECT_GT(checked, 0u) << "no map started after the cover, or its first frames judged nothing";
  // The trajectory carries each pose's map.
  const auto trajectory = system->trajectory();
  std::size_t in_maps = 0;
  for (const auto& p : trajectory) in_maps += maps.count(p.map_id) > 0 || p.map_id == 0;
  EXPECT_EQ(in_maps, trajectory.size());
  std::printf("covered 2 s: %zu of %zu frames after the cover have a pose, in map(s)", after_with_pose, after);
  for (std::uint32_t m : maps) std::printf(" %u", m);
  std::printf("; %u maps started\n", system->mapStats().maps);

  // The new map goes on where the camera was last posed, in map 0's frame:
  // taken in one frame, as a consumer that ignores the map id takes them,
  // its poses are off by about what the camera moved unseen, not by where
  // it is from map 0's origin.
  // (Local BA moves the last pose by a millimetre or so after it was given.)
  ASSERT_TRUE(new_map_start && last_before_cover && new_map_at);
  EXPECT_LT((new_map_start->translation() - last_before_cover->translation()).norm(), 0.01);
  EXPECT_LT((new_map_start->linear() - last_before_cover->linear()).norm(), 0.01);
  ASSERT_TRUE(data_->hasGroundTruth());
  const auto gt = eval::readTumTrajectory(data_->groundTruthPath());
  ASSERT_TRUE(gt.ok()) << gt.error();
  eval::Trajectory est;
  for (const auto& p : trajectory) est.push_back({p.stamp, p.T_w_c, p.map_id});
  const auto result = eval::evaluate(*gt, est);
  ASSERT_TRUE(result.ok()) << result.error();
  const auto truth_at = [&](std::size_t i) {
    const Timestamp t = data_->load(i)->stamp;
    const auto off = [t](const eval::StampedPose& p) { return std::abs(secondsBetween(p.stamp, t)); };
    const auto near = std::min_element(gt->begin(), gt->end(),
                                       [&](const eval::StampedPose& a, const eval::StampedPose& b) { return off(a) < off(b); });
    return near->T_w_c.translation();
  };
  const double unseen_m = (truth_at(*new_map_at) - truth_at(kCoverFrom - 1)).norm();
  EXPECT_GE(result->maps, 2u);
  EXPECT_LT(result->ate_one_frame_rmse_m, unseen_m);
  std::printf("covered 2 s: ATE %.4f m each map on its own, %.4f m in one frame; the camera moved %.3f m unseen\n",
              result->ate_rmse_m, result->ate_one_frame_rmse_m, unseen_m);
}

// There and back, covered for 2 s on both ways (the same stretch of the
// excerpt): the first cover starts map 1, which the way back follows until
// the second cover. After it the camera is where map 0 was made: the frame
// relocalises in map 0, with no third map, and its pose there is the one
// map 0 gave the same image on the way there (a new map would also have taken
// in whatever moves in front of the camera at that moment).
TEST_F(Recovery, AfterASecondCoverTheCameraGoesOnInTheOlderMapThatKnowsThePlace) {
  auto system = makeSystem();
  ASSERT_TRUE(system);
  constexpr std::size_t kCoverFrom = 60, kCoverTo = 120;
  const std::size_t n = data_->size();
  std::vector<std::size_t> order;
  for (std::size_t i = 0; i < n; ++i) order.push_back(i);
  for (std::size_t i = n; i-- > 0;) order.push_back(i);
  const Timestamp start = data_->load(0)->stamp;
  std::vector<std::optional<SE3>> there(n);  // map 0's poses on the way there
  std::optional<std::size_t> back_in_map;     // the first frame with a pose after the second cover
  for (std::size_t k = 0; k < order.size(); ++k) {
    const std::size_t i = order[k];
    auto frame = data_->load(i);
    ASSERT_TRUE(frame.ok()) << frame.error();
    const Timestamp stamp = Timestamp::fromNanoseconds(start.nanoseconds() + static_cast<std::int64_t>(k) * 33'333'333);
    slam::RgbdInput input{stamp, frame->gray, frame->depth_m, frame->bgr};
    if (i >= kCoverFrom && i < kCoverTo) {
      cover(&input);
    }
    auto out = system->track(input);
    ASSERT_TRUE(out.ok()) << out.error();
    const bool way_back = k >= n;
    if (!way_back && i < kCoverFrom && slam::hasPose(out->state) && out->map_id == 0) there[i] = out->T_w_c;
    if (way_back && i < kCoverFrom && !back_in_map && slam::hasPose(out->state)) {
      back_in_map = i;
      EXPECT_EQ(out->state, slam::TrackingState::kRelocalised) << "frame " << i;
      EXPECT_EQ(out->map_id, 0u) << "frame " << i;
      ASSERT_TRUE(there[i]) << "frame " << i << " had no pose in map 0 on the way there";
      const double apart_m = (out->T_w_c.translation() - there[i]->translation()).norm();
      EXPECT_LT(apart_m, 0.03) << "frame " << i;
      std::printf("after the second cover: frame %zu in map %u, %.4f m from its pose on the way there\n", i,
                  out->map_id, apart_m);
    }
  }
  system->finish();
  ASSERT_TRUE(back_in_map) << "no pose after the second cover";
  EXPECT_EQ(*back_in_map, kCoverFrom - 1) << "the first frame after the cover had no pose";
  EXPECT_EQ(system->mapStats().maps, 2u);
}

TEST_F(Recovery, AViewThatCannotBePlacedStartsANewMapWithinASecond) {
  // From frame 70 on the images are mirrored: a consistent world the camera
  // moves through, but one no part of the map matches (ORB descriptors are
  // not mirror-invariant), so relocalisation cannot succeed and a new map
  // must start.
  auto system = makeSystem();
  ASSERT_TRUE(system);
  constexpr std::size_t kJump = 70;
  std::size_t after = 0, after_with_pose = 0, lost_run = 0, longest_lost_run = 0;
  bool saw_new_map = false;
  std::uint32_t last_map = 0;
  for (std::size_t i = 0; i < data_->size(); ++i) {
    auto frame = data_->load(i);
    ASSERT_TRUE(frame.ok()) << frame.error();
    slam::RgbdInput input{frame->stamp, frame->gray, frame->depth_m, frame->bgr};
    if (i >= kJump) {
      cv::flip(frame->gray, input.gray, 1);
      cv::flip(frame->depth_m, input.depth_m, 1);
      cv::flip(frame->bgr, input.bgr, 1);
    }
    auto out = system->track(input);
    ASSERT_TRUE(out.ok()) << out.error();
    if (i < kJump) continue;
    ++after;
    after_with_pose += slam::hasPose(out->state);
    lost_run = slam::hasPose(out->state) ? 0 : lost_run + 1;
    longest_lost_run = std::max(longest_lost_run, lost_run);
    if (out->state == slam::TrackingState::kNewMap) {
      saw_new_map = true;
      EXPECT_EQ(out->map_id, last_map + 1);
      EXPECT_TRUE(out->new_keyframe);
    }
    if (slam::hasPose(out->state)) last_map = out->map_id;
  }
  system->finish();
  EXPECT_TRUE(saw_new_map);
  // A second at 30 Hz, and the frame that starts the map.
  EXPECT_LE(longest_lost_run, 32u);
  EXPECT_GE(system->mapStats().maps, 2u);
  std::printf("unplaceable view: %zu of %zu frames after the jump have a pose, longest loss %zu frames, %u maps\n",
              after_with_pose, after, longest_lost_run, system->mapStats().maps);
}

// The excerpt is a static scene, well tracked: no frame's pose is to be
// distrusted, whatever the feature budget. The geometry module judges near
// surfaces against an anchor frame whose pose is a few millimetres off; judged
// under that pose as it stands, the teddy bear looked like a mover on 29 % of
// the view at 900 features and pose health said `degraded` for 15 frames.
TEST_F(Recovery, AStaticSceneIsTrustedOnEveryFrameAtEveryFeatureBudget) {
  for (const int budget : {900, 1000, 1100}) {
    auto system = makeSystem(budget);
    ASSERT_TRUE(system);
    std::size_t good = 0;
    double worst_share = 0;
    for (std::size_t i = 0; i < data_->size(); ++i) {
      auto frame = data_->load(i);
      ASSERT_TRUE(frame.ok()) << frame.error();
      auto out = system->track({frame->stamp, frame->gray, frame->depth_m, frame->bgr});
      ASSERT_TRUE(out.ok()) << out.error();
      ASSERT_TRUE(slam::hasPose(out->state)) << budget << " features, frame " << i << ": " << toString(out->state);
      good += out->quality.health == slam::PoseHealth::kGood;
      worst_share = std::max(worst_share, static_cast<double>(out->quality.dynamic_share));
      EXPECT_EQ(out->quality.health, slam::PoseHealth::kGood)
          << budget << " features, frame " << i << ": " << toString(out->quality.health) << ", "
          << out->quality.dynamic_share << " dynamic";
    }
    system->finish();
    std::printf("%d features: %zu of %zu frames good, largest dynamic share %.3f\n", budget, good, data_->size(),
                worst_share);
  }
}

}  // namespace
}  // namespace stillpoint
