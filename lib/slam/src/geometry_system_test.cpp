// The geometry module through SlamSystem: a board moving in a ray-cast room,
// each cue on and off (sequential mode, so every run is the same).
#include <algorithm>
#include <map>
#include <optional>

#include "system_test_scenes.hpp"

namespace stillpoint::slam {
namespace {

TEST(SlamSystemGeometry, MovingBoardIsFlaggedAndKeptOutOfThePose) {
  const MovingBoardSequence data = movingBoardSequence(45);
  const Sequence& seq = data.seq;
  std::vector<SE3> online[2];
  BoardScore score;
  int static_flags_before_motion = 0;
  for (int module = 0; module < 2; ++module) {
    SlamOptions options = sequentialOptions();
    options.geometry.enabled = module == 1;
    auto system = makeSystem(seq.camera, options);
    ASSERT_TRUE(system);
    for (std::size_t i = 0; i < seq.frames.size(); ++i) {
      const auto out = system->track(seq.frames[i]);
      ASSERT_TRUE(out.ok()) << out.error();
      ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
      online[module].push_back(out->T_w_c);
      if (!module) continue;
      EXPECT_EQ(out->geometry.ran, i > 0) << "frame " << i;
      if (i > 0) {
        EXPECT_EQ(out->geometry.clusters, 24);
      }
      for (const JudgedFeature& f : out->geometry.judged) {
        if (i < 10) {
          static_flags_before_motion += f.dynamic;
          continue;
        }
        score.add(data.masks[i], f);
      }
    }
    system->finish();
  }
  const double precision = score.precision(), recall = score.recall();
  const PoseErrors off = compare(online[0], seq.T_w_c), on = compare(online[1], seq.T_w_c);
  std::printf("moving board: precision %.3f recall %.3f (%d/%d/%d), flags while still %d\n", precision, recall,
              score.true_positive, score.false_positive, score.false_negative, static_flags_before_motion);
  std::printf("  online error: module off max %.2f mm rms %.2f mm; on max %.2f mm rms %.2f mm\n",
              off.max_translation * 1e3, off.rms_translation * 1e3, on.max_translation * 1e3,
              on.rms_translation * 1e3);
  EXPECT_GE(recall, 0.9);
  EXPECT_GE(precision, 0.9);
  EXPECT_LT(on.rms_translation, off.rms_translation);
}

// The moving board as a dynamic object: one id while it moves, its centroid
// where its surface is (the median of the mask's pixels in the world, from the
// rendered depth and the true pose), its velocity that of this surface.
TEST(SlamSystemGeometry, MovingBoardIsReportedAsAnObject) {
  const MovingBoardSequence data = movingBoardSequence(45);
  const Sequence& seq = data.seq;
  SlamOptions options = sequentialOptions();
  auto system = makeSystem(seq.camera, options);
  ASSERT_TRUE(system);
  std::map<std::uint32_t, int> ids;
  int reported = 0, scored = 0;
  double error_sum = 0, worst = 0;
  Vec3 velocity_sum = Vec3::Zero(), truth_velocity_sum = Vec3::Zero();
  int velocities = 0;
  std::optional<Vec3> last_truth;
  for (std::size_t i = 0; i < seq.frames.size(); ++i) {
    const auto out = system->track(seq.frames[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    if (i < 10) {
      EXPECT_TRUE(out->objects.empty()) << "frame " << i << ": the board has not moved yet";
      continue;
    }
    if (i < 15 || out->objects.empty()) continue;  // the module needs a few frames of motion
    ++reported;
    const DynamicObject* board = &out->objects[0];
    for (const DynamicObject& o : out->objects)
      if (o.samples > board->samples) board = &o;
    EXPECT_EQ(board->label, "unknown");
    EXPECT_EQ(board->sources, DynamicObject::kGeometry);
    ++ids[board->id];
    std::vector<double> axis[3];
    const cv::Mat& depth = seq.frames[i].depth_m;
    for (int v = 0; v < depth.rows; v += 2)
      for (int u = 0; u < depth.cols; u += 2) {
        if (!data.masks[i].at<std::uint8_t>(v, u) || !(depth.at<float>(v, u) > 0)) continue;
        const Vec3 p = seq.T_w_c[i] * seq.camera.unproject(Vec2(u, v), depth.at<float>(v, u));
        for (int k = 0; k < 3; ++k) axis[k].push_back(p[k]);
      }
    ASSERT_FALSE(axis[0].empty());
    Vec3 truth;
    for (int k = 0; k < 3; ++k) {
      std::nth_element(axis[k].begin(), axis[k].begin() + axis[k].size() / 2, axis[k].end());
      truth[k] = axis[k][axis[k].size() / 2];
    }
    const double error = (board->centroid - truth).norm();
    error_sum += error, worst = std::max(worst, error), ++scored;
    if (board->has_velocity && last_truth) {
      velocity_sum += board->velocity, ++velocities;
      truth_velocity_sum += (truth - *last_truth) * 30.0;
    }
    last_truth = truth;
  }
  system->finish();
  const int main_id_frames = std::max_element(ids.begin(), ids.end(), [](auto& a, auto& b) { return a.second < b.second; })->second;
  const Vec3 velocity = velocity_sum / std::max(1, velocities);
  const Vec3 truth_velocity = truth_velocity_sum / std::max(1, velocities);
  std::printf("board object: reported in %d of 30 frames, %zu ids (the main one in %d), centroid error mean %.1f mm "
              "max %.1f mm, velocity (%.2f %.2f %.2f) m/s, its surface's (%.2f %.2f %.2f)\n",
              reported, ids.size(), main_id_frames, 1e3 * error_sum / std::max(1, scored), 1e3 * worst, velocity.x(),
              velocity.y(), velocity.z(), truth_velocity.x(), truth_velocity.y(), truth_velocity.z());
  EXPECT_GE(reported, 27);
  EXPECT_GE(main_id_frames, reported - 2);
  EXPECT_LT(error_sum / std::max(1, scored), 0.05);
  EXPECT_GT(velocities, 20);
  EXPECT_LT((velocity - truth_velocity).norm(), 0.1);
}

// tracking.motion_prior_sigma_m: the board covers few features (8 % of the
// matches) but, 1.3 m away in front of a room 3 m deep, most of what fixes the
// translation; without a prior stage 1 follows its first 15 mm step (20 mm
// error at frame 11, 50 mm at 12 with 3 levels), the module sees only part of
// the motion and flags the room instead (precision 0.87). The motion model's
// prediction as a 2 mm prior holds stage 1 in place.
TEST(SlamSystemGeometry, MotionPriorHoldsStageOneOffTheBoard) {
  SlamOptions options = sequentialOptions();
  options.orb.num_levels = 3;
  options.tracking.motion_prior_sigma_m = 0.002;
  options.tracking.motion_prior_sigma_deg = 1.0;
  BoardRun run;
  ASSERT_NO_FATAL_FAILURE(runBoard(movingBoardSequence(45), options, &run));
  std::printf("moving board, 3 levels, motion prior: precision %.3f recall %.3f, online rms %.2f mm, max %.2f mm\n",
              run.score.precision(), run.score.recall(), run.errors.rms_translation * 1e3,
              run.errors.max_translation * 1e3);
  EXPECT_GE(run.score.recall(), 0.9);
  EXPECT_GE(run.score.precision(), 0.9);
  EXPECT_LT(run.errors.max_translation, 0.01);
}

// geometry.consensus_ratio: a board that starts from rest (0.45 m/s^2, as a
// person sets off) moves a fraction of a pixel a frame at first, and with 3
// levels stage 1 follows it into a compromise under which the board and the
// room both pass the gate; judged under that pose, the module flags the room
// (consensus off: precision 0.65, online rms 23 mm, max 84 mm). Judged under
// the consensus pose of the anchor matches, the board is what disagrees.
TEST(SlamSystemGeometry, ConsensusPoseCatchesABoardStartingFromRest) {
  const MovingBoardSequence data = boardSequence(45, [](int k) {
    const double t = k < 10 ? 0.0 : (k - 10) / 30.0;
    return Vec3(0.5 * 0.45 * t * t, 0, 0);
  });
  BoardRun runs[2];
  for (int consensus = 0; consensus < 2; ++consensus) {
    SlamOptions options = sequentialOptions();
    options.orb.num_levels = 3;
    options.geometry.consensus_ratio = consensus ? 0.9 : 0.0;
    // Every frame keeps its pose, however wrong: the runs compare the poses
    // (the motion check drops the initial pose's worst frame, 94 mm off).
    options.tracking.max_acceleration = 0;
    ASSERT_NO_FATAL_FAILURE(runBoard(data, options, &runs[consensus]));
    printRun(consensus ? "board from rest, consensus pose" : "board from rest, initial pose", runs[consensus]);
  }
  const BoardRun& run = runs[1];
  std::printf("  judged under the consensus pose in %d of 44 frames\n", run.consensus_frames);
  EXPECT_EQ(runs[0].consensus_frames, 0);
  EXPECT_GT(run.consensus_frames, 0);
  EXPECT_GE(run.score.precision(), 0.95);
  EXPECT_GE(run.score.recall(), runs[0].score.recall());
  EXPECT_LT(run.errors.rms_translation, 0.01);
  EXPECT_LT(run.errors.rms_translation, 0.5 * runs[0].errors.rms_translation);
  // The scene is one the initial pose fails on.
  EXPECT_LT(runs[0].score.precision(), 0.9);
}

// Free space, the dense evidence: once the board has moved over the anchor
// baseline (5 frames, 7.5 cm), the depth samples along its leading edge lie
// where the anchor frame saw the room behind it. Clusters on the board must
// show that; clusters without any board sample must not (clean depth, a
// tracked pose).
TEST(SlamSystemGeometry, FreeSpaceSeesTheMovingBoard) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  ASSERT_EQ(options.geometry.freespace_flag, 0.2);  // the default: such clusters are dynamic
  auto system = makeSystem(data.seq.camera, options);
  ASSERT_TRUE(system);
  int board_frames = 0, board_seen = 0, static_tested = 0;
  float static_max = 0, board_best_sum = 0;
  for (std::size_t i = 0; i < data.seq.frames.size(); ++i) {
    const auto out = system->track(data.seq.frames[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    const GeometryOutput& g = out->geometry;
    if (!g.ran) continue;
    ASSERT_TRUE(g.labels);
    ASSERT_EQ(g.freespace.size(), static_cast<std::size_t>(g.clusters));
    const geometry::DepthClusters& c = *g.labels;
    std::vector<int> on_board(c.clusters, 0), total(c.clusters, 0);
    for (int r = 0; r < c.labels.rows; ++r)
      for (int col = 0; col < c.labels.cols; ++col) {
        const int j = c.labels.at<std::int16_t>(r, col);
        if (j < 0) continue;
        ++total[j];
        on_board[j] += data.masks[i].at<std::uint8_t>(r * c.step + c.step / 2, col * c.step + c.step / 2) != 0;
      }
    float board_best = -1;
    for (int j = 0; j < c.clusters; ++j) {
      if (g.freespace[j] >= 0.2f) {
        EXPECT_TRUE(g.scores[j].dynamic) << "frame " << i << " cluster " << j;
      }
      if (g.freespace[j] < 0) continue;
      if (on_board[j] == 0) {
        static_max = std::max(static_max, g.freespace[j]);
        ++static_tested;
      } else if (2 * on_board[j] > total[j]) {
        board_best = std::max(board_best, g.freespace[j]);
      }
    }
    if (i < 15 || board_best < 0) continue;
    ++board_frames;
    board_seen += board_best >= 0.1f;
    board_best_sum += board_best;
  }
  system->finish();
  std::printf("free space: board clusters best share mean %.3f, >= 0.1 in %d of %d frames; static clusters max %.3f (%d tested)\n",
              board_best_sum / std::max(1, board_frames), board_seen, board_frames, static_max, static_tested);
  ASSERT_GT(board_frames, 20);
  EXPECT_GE(board_seen, board_frames * 9 / 10);
  EXPECT_GT(static_tested, 500);
  EXPECT_LT(static_max, 0.02f);
}

// geometry.freespace_split_keep (off by default): a dynamic cluster is split
// by the surface grown from its free-space violations. The board is one
// surface, so it stays found; a feature is only ever released from a dynamic
// cluster, and never when its own evidence disagrees with the pose.
TEST(SlamSystemGeometry, FreeSpaceSplitKeepsTheBoardAndItsDisagreeingFeatures) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  options.geometry.photo_release_ncc = 0;  // every release counted here is this test's own
  options.geometry.freespace_split_keep = 0.8;
  options.geometry.lone_moving_chi2 = 0;  // every feature outside a dynamic cluster is static (own test)
  auto system = makeSystem(data.seq.camera, options);
  ASSERT_TRUE(system);
  BoardScore score;
  int in_dynamic = 0, released = 0;
  for (std::size_t i = 0; i < data.seq.frames.size(); ++i) {
    const auto out = system->track(data.seq.frames[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    for (const JudgedFeature& f : out->geometry.judged) {
      const bool cluster_dynamic = out->geometry.scores[f.cluster].dynamic;
      EXPECT_FALSE(f.dynamic && !cluster_dynamic) << "frame " << i;
      if (cluster_dynamic && !f.dynamic) {
        ++released;
        EXPECT_LE(f.chi2, options.geometry.freespace_split_protect_chi2) << "frame " << i;
      }
      in_dynamic += cluster_dynamic;
      if (i >= 10) score.add(data.masks[i], f);
    }
  }
  system->finish();
  std::printf("moving board, free-space split: precision %.3f recall %.3f, %d of %d features of dynamic clusters released\n",
              score.precision(), score.recall(), released, in_dynamic);
  EXPECT_GT(in_dynamic, 0);
  EXPECT_GE(score.recall(), 0.9);
  EXPECT_GE(score.precision(), 0.9);
}

// geometry.near_anchor_frames and geometry.lone_moving_chi2, on
// by default, each only where it belongs: a feature judged by a nearer anchor
// lies in a cluster with fewer than min_features matches to the frame's
// anchor itself, and a feature flagged outside a dynamic cluster lies in a
// cluster too small to judge, its carried evidence above the limit. The board
// is still found and the room kept.
TEST(SlamSystemGeometry, NearerAnchorsAndLoneFeaturesOnlyWhereTheClusterVerdictCannotReach) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  options.geometry.photo_release_ncc = 0;     // nothing released: every flag is the verdict's or a lone feature's
  options.geometry.freespace_split_keep = 0;  // (both have their own tests)
  const int min_features = options.geometry.verdict.min_features;
  auto system = makeSystem(data.seq.camera, options);
  ASSERT_TRUE(system);
  BoardScore score;
  int nearer = 0, lone = 0;
  for (std::size_t i = 0; i < data.seq.frames.size(); ++i) {
    const auto out = system->track(data.seq.frames[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    const GeometryOutput& g = out->geometry;
    int anchor_baseline = 0;  // the anchor frame's (fewer frames back while the history is short)
    for (const JudgedFeature& f : g.judged) anchor_baseline = std::max(anchor_baseline, f.baseline);
    std::vector<int> at_anchor(g.scores.size(), 0), at_nearer(g.scores.size(), 0);
    for (const JudgedFeature& f : g.judged) {
      ASSERT_GE(f.cluster, 0);
      ASSERT_LT(f.cluster, static_cast<int>(g.scores.size()));
      if (f.evidence == JudgedFeature::Evidence::kAnchor) {
        EXPECT_GE(f.baseline, 1) << "frame " << i;
        EXPECT_LE(f.baseline, options.geometry.anchor_frames) << "frame " << i;
        ++(f.baseline == anchor_baseline ? at_anchor : at_nearer)[f.cluster];
      } else {
        EXPECT_EQ(f.baseline, 0) << "frame " << i;
      }
      const geometry::ClusterScore& c = g.scores[f.cluster];
      if (f.dynamic && !c.dynamic) {
        ++lone;
        EXPECT_FALSE(c.judged) << "frame " << i;
        EXPECT_EQ(f.evidence, JudgedFeature::Evidence::kCarried) << "frame " << i;
        EXPECT_TRUE(f.inherited) << "frame " << i;
        EXPECT_GT(f.chi2, options.geometry.lone_moving_chi2) << "frame " << i;
      }
      if (i >= 10) score.add(data.masks[i], f);
    }
    for (std::size_t c = 0; c < g.scores.size(); ++c) {
      if (at_nearer[c] == 0) continue;
      nearer += at_nearer[c];
      EXPECT_LT(at_anchor[c], min_features) << "frame " << i << " cluster " << c;
      EXPECT_GE(at_anchor[c] + at_nearer[c], min_features) << "frame " << i << " cluster " << c;
    }
  }
  system->finish();
  std::printf("moving board, nearer anchors and lone features: precision %.3f recall %.3f, %d features judged by "
              "a nearer anchor, %d lone features flagged\n",
              score.precision(), score.recall(), nearer, lone);
  EXPECT_GT(nearer, 0);  // both were exercised
  EXPECT_GT(lone, 0);
  EXPECT_GE(score.recall(), 0.9);
  EXPECT_GE(score.precision(), 0.9);
}

// Evidence that geometry.static_match_margin sets aside (another copy of the
// pattern explains the feature as static) stays out of the verdict, but the
// feature is still reported with its outcome, so that a score counts it:
// every matched feature of the frame is scored, not only those the verdict used.
TEST(SlamSystemGeometry, SetAsideEvidenceIsStillReported) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  options.geometry.photo_release_ncc = 0;  // every release counted here is this test's own
  options.geometry.static_match_margin = 40;  // wide, so that the board's texture sets some aside
  auto system = makeSystem(data.seq.camera, options);
  ASSERT_TRUE(system);
  int set_aside = 0, set_aside_dynamic = 0;
  for (std::size_t i = 0; i < data.seq.frames.size(); ++i) {
    const auto out = system->track(data.seq.frames[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    for (const JudgedFeature& f : out->geometry.judged) {
      if (!f.explained) continue;
      ++set_aside;
      set_aside_dynamic += f.dynamic;
      EXPECT_GT(f.chi2, options.geometry.verdict.rho_cap) << "frame " << i;  // only disagreeing evidence
      ASSERT_GE(f.cluster, 0);
      // Its outcome is its cluster's: nothing releases it.
      EXPECT_EQ(f.dynamic, out->geometry.scores[f.cluster].dynamic) << "frame " << i;
    }
  }
  system->finish();
  std::printf("moving board, static_match_margin 40: %d features set aside, %d of them dynamic\n", set_aside,
              set_aside_dynamic);
  EXPECT_GT(set_aside, 0);
}

// geometry.photo_release_ncc (on by default): the static hypothesis tested on
// pixels frees features of dynamic clusters. On the board scene, whose
// texture of colour blocks is all alike edges, it must leave the board
// flagged and the pose on the room.
TEST(SlamSystemGeometry, PhotometricReleaseKeepsTheBoardFlagged) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  ASSERT_GT(options.geometry.photo_release_ncc, 0);
  BoardRun run;
  ASSERT_NO_FATAL_FAILURE(runBoard(data, options, &run));
  printRun("moving board, photometric release", run);
  expectBoardKeptFlagged(run);
}

// The photometric test is judged under the pose fitted without the dynamic
// clusters. Judged under the initial pose it confirmed a mover stage 1 had
// followed: with 3 levels (stage 1 half follows the board's first steps,
// MotionPriorHoldsStageOneOffTheBoard) and anchored features free to go, it
// freed board features and the pose stepped 20 mm. The consensus pose is off
// here: it judges the board's first step (frame 11) under a pose that did not
// follow it, which flags 12 more board features there, and the release test
// frees 11 of them (the board moves along its blocks' edges, where a patch
// looks the same); the run otherwise is identical (recall 0.923 against
// 0.922, the same poses), but 70 of 1278 board features freed against 59 of
// 1266 would fail the 5 % bound below, which is about a pose that followed
// the board, the case this test builds.
TEST(SlamSystemGeometry, PhotometricReleaseDoesNotConfirmAPoseThatFollowedTheBoard) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  options.orb.num_levels = 3;
  options.tracking.motion_prior_sigma_m = 0.002;
  options.tracking.motion_prior_sigma_deg = 1.0;
  options.geometry.photo_release_ncc = 0.6;
  options.geometry.photo_release_anchored = true;
  options.geometry.photo_frames_back = 5;  // the frames it was seen failing with
  options.geometry.photo_frames = 2;
  options.geometry.photo_fallback = false;
  options.geometry.consensus_ratio = 0;
  BoardRun run;
  ASSERT_NO_FATAL_FAILURE(runBoard(data, options, &run));
  printRun("moving board, 3 levels, photometric release of anchored features too", run);
  expectBoardKeptFlagged(run);
  EXPECT_LT(run.errors.max_translation, 0.01);
}

// A board sliding 10 cm in front of the back wall shares its clusters with the
// wall: the wall's features there are dropped with them. The photometric test
// frees most of those (their pixels match at the static hypothesis) and
// almost none of the board's; the few it frees (about 2 %: where the board's
// texture matched by chance in both frames) may cost that much recall.
TEST(SlamSystemGeometry, PhotometricReleaseFreesTheWallBehindABoard) {
  RoomScene scene(5);
  scene.addMovingBoard(Vec3(-0.9, -0.6, 2.9), 0.8, 0.8, 77);
  MovingBoardSequence data;
  data.seq.camera = RoomScene::camera();
  for (int k = 0; k < 45; ++k) {
    const double s = static_cast<double>(k) / 30.0;
    const SE3 T_w_c = pose(Vec3(0.02 * std::sin(2 * s), 0.05 * std::sin(1.5 * s), 0), Vec3(0.15 * s, 0.02 * s, 0.05 * s));
    cv::Mat mask;
    data.seq.T_w_c.push_back(T_w_c);
    data.seq.frames.push_back(
        scene.render(data.seq.camera, T_w_c, frameStamp(k), Vec3(k < 10 ? 0.0 : 0.015 * (k - 10), 0, 0), &mask));
    data.masks.push_back(mask);
  }
  BoardRun run[2];
  for (int photo = 0; photo < 2; ++photo) {
    SlamOptions options = sequentialOptions();
    options.geometry.photo_release_ncc = photo ? 0.6 : 0.0;
    options.geometry.photo_release_anchored = true;
    ASSERT_NO_FATAL_FAILURE(runBoard(data, options, &run[photo]));
    printRun(std::string("board at the wall, photometric release ") + (photo ? "on" : "off"), run[photo]);
  }
  EXPECT_GE(run[1].score.recall(), run[0].score.recall() - 0.03);
  EXPECT_GT(run[1].score.precision(), run[0].score.precision());
  EXPECT_LT(run[1].errors.rms_translation, run[0].errors.rms_translation);
  EXPECT_GT(run[1].released_off_board, run[0].released_off_board + run[1].dynamic_off_board / 3);
  EXPECT_LT(run[1].released_on_board, 0.05 * run[1].dynamic_on_board);
}

// The same loop from the other side: a verdict that flags most of the room
// (floor 0.5, factor 1) and no anchor matches. Judged under the initial pose,
// the test freed the board, the pose followed it and recall fell to 0.03.
// Under the pose fitted without the dynamic clusters, and only while that
// pose rests on most of the view (geometry.max_dynamic_fraction), it frees
// the room, far more of it than of the board, and the pose is better for it
// (measured: max error 339 -> 211 mm, recall 0.74 -> 0.81; without the
// fraction check the pose once followed the board again, 862 mm). The lone
// features (geometry.lone_moving_chi2) are off in both runs, so that the
// release is the only difference: with them on, the release-off run is
// already near the board's truth (recall 0.948, rms 55 mm, max 116 mm), and
// the release lowers the rms to 32 mm but not the max (126 mm).
TEST(SlamSystemGeometry, PhotometricReleaseHoldsUnderAVerdictThatFlagsTheRoom) {
  const MovingBoardSequence data = movingBoardSequence(45);
  BoardRun run[2];
  for (int photo = 0; photo < 2; ++photo) {
    SlamOptions options = sequentialOptions();
    options.geometry.verdict.absolute_floor = 0.5;
    options.geometry.verdict.relative_factor = 1.0;
    options.geometry.anchor_frames = 0;
    options.geometry.lone_moving_chi2 = 0;
    options.geometry.photo_release_ncc = photo ? 0.6 : 0.0;
    options.tracking.max_acceleration = 0;  // every frame keeps its pose: the runs compare the poses
    ASSERT_NO_FATAL_FAILURE(runBoard(data, options, &run[photo]));
    printRun(std::string("moving board, eager verdict, no anchors, photometric release ") + (photo ? "on" : "off"),
             run[photo]);
  }
  EXPECT_GT(run[1].score.recall(), run[0].score.recall());
  EXPECT_GT(run[1].score.precision(), run[0].score.precision());
  EXPECT_LT(run[1].released_on_board, 0.1 * run[1].released_off_board);
  EXPECT_LT(run[1].errors.max_translation, run[0].errors.max_translation);
}

// geometry.evidence_ratio: ambiguous projection matches are not judged (every
// reported non-anchor feature passed the ratio), and the board is still found.
TEST(SlamSystemGeometry, RatioTestedEvidenceKeepsTheBoardFlagged) {
  const MovingBoardSequence data = movingBoardSequence(45);
  const Sequence& seq = data.seq;
  SlamOptions options = sequentialOptions();
  options.geometry.evidence_ratio = 0.9;
  auto system = makeSystem(seq.camera, options);
  ASSERT_TRUE(system);
  BoardScore score;
  int ratio_reported = 0;
  std::vector<SE3> online;
  for (std::size_t i = 0; i < seq.frames.size(); ++i) {
    const auto out = system->track(seq.frames[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    online.push_back(out->T_w_c);
    for (const JudgedFeature& f : out->geometry.judged) {
      if (f.evidence != JudgedFeature::Evidence::kAnchor) {
        EXPECT_LE(f.ratio, 0.9f) << "frame " << i;
        ratio_reported += f.ratio > 0;
      }
      if (i < 10) continue;
      score.add(data.masks[i], f);
    }
  }
  system->finish();
  const double precision = score.precision(), recall = score.recall();
  const PoseErrors on = compare(online, seq.T_w_c);
  std::printf("moving board, ratio-tested evidence: precision %.3f recall %.3f (%d/%d/%d), rms %.2f mm\n", precision,
              recall, score.true_positive, score.false_positive, score.false_negative, on.rms_translation * 1e3);
  EXPECT_GT(ratio_reported, 0);  // the motion model's matches carry their ratio
  EXPECT_GE(recall, 0.9);
  EXPECT_GE(precision, 0.9);
  EXPECT_LT(on.rms_translation, 0.01);
}

// geometry.evidence_depth_max_m: real sensors' far depth is off by decimetres
// to a metre from frame to frame (the real excerpt's background at 5 m), and
// as evidence that flagged static clusters. Here the room's back wall (3 m)
// gets such noise, fresh in every frame, in 16 px blocks: with the limit below
// it, the wall's features are judged by the image alone and stay static. Free
// space is off: the noise also puts wall samples in front of where the anchor
// saw the wall, which is the free-space test's tolerance, not this rule.
TEST(SlamSystemGeometry, FarDepthNoiseIsNoEvidence) {
  MovingBoardSequence data = boardSequence(40, [](int) { return Vec3::Zero(); });
  cv::RNG rng(11);
  for (RgbdInput& frame : data.seq.frames) {
    cv::Mat noise(frame.depth_m.rows / 16, frame.depth_m.cols / 16, CV_32F);
    rng.fill(noise, cv::RNG::UNIFORM, -1.0, 1.0);
    cv::resize(noise, noise, frame.depth_m.size(), 0, 0, cv::INTER_NEAREST);
    cv::Mat far = frame.depth_m > 2.6;
    cv::add(frame.depth_m, noise, frame.depth_m, far);
  }
  int far_judged[2] = {0, 0}, far_flagged[2] = {0, 0};
  for (int limited = 0; limited < 2; ++limited) {
    SlamOptions options = sequentialOptions();
    options.geometry.freespace_flag = 0;
    options.geometry.freespace_split_keep = 0;
    options.geometry.evidence_depth_max_m = limited ? 2.5 : 0.0;
    auto system = makeSystem(data.seq.camera, options);
    ASSERT_TRUE(system);
    for (std::size_t i = 0; i < data.seq.frames.size(); ++i) {
      const auto out = system->track(data.seq.frames[i]);
      ASSERT_TRUE(out.ok()) << out.error();
      ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
      for (const JudgedFeature& f : out->geometry.judged) {
        if (f.depth < 2.6f) continue;
        ++far_judged[limited];
        far_flagged[limited] += f.dynamic;
      }
    }
    system->finish();
  }
  const double share_off = far_flagged[0] / std::max(1.0, double(far_judged[0]));
  const double share_on = far_flagged[1] / std::max(1.0, double(far_judged[1]));
  std::printf("noisy far wall: flagged %d/%d without the limit (%.3f), %d/%d with it (%.3f)\n", far_flagged[0],
              far_judged[0], share_off, far_flagged[1], far_judged[1], share_on);
  ASSERT_GT(far_judged[1], 500);
  EXPECT_GT(share_off, 0.1);  // the noise is evidence enough to flag without the limit
  EXPECT_LT(share_on, 0.02);
}


// geometry.probation_frames: map points made by keyframes stay out of the
// pose fits until they have been matched consistently with a pose fitted
// without them. The board mapped while it went unflagged pulls the pose less
// (online rms 4.15 mm against 4.53 mm without), tracking never fails although
// every new point waits, and the board is still found.
TEST(SlamSystemGeometry, ProbationKeepsAnAppearingBoardOutOfThePose) {
  const MovingBoardSequence data = appearingBoardSequence(55);
  BoardRun runs[2];
  for (int probation = 0; probation < 2; ++probation) {
    SlamOptions options = sequentialOptions();
    options.geometry.probation_frames = probation ? 3 : 0;
    BoardRun& run = runs[probation];
    ASSERT_NO_FATAL_FAILURE(runBoard(data, options, &run, 0));
    std::printf("appearing board, probation %d: precision %.3f recall %.3f (%d/%d/%d), max %.2f mm rms %.2f mm\n",
                probation ? 3 : 0, run.score.precision(), run.score.recall(), run.score.true_positive,
                run.score.false_positive, run.score.false_negative, run.errors.max_translation * 1e3,
                run.errors.rms_translation * 1e3);
  }
  EXPECT_GE(runs[1].score.precision(), 0.95);
  EXPECT_GE(runs[1].score.recall(), 0.8);
  EXPECT_LT(runs[1].errors.rms_translation, runs[0].errors.rms_translation);
  EXPECT_LT(runs[1].errors.rms_translation, 0.005);
}



}  // namespace
}  // namespace stillpoint::slam
