// The semantic module inside SlamSystem: a fake Segmenter (a test double of
// our own interface) paints a known rectangle, so the test knows which
// keyframe features must leave the map; one test runs the real in-tree person
// model on real TUM frames. All runs are short (20 frames of 640x480).
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <utility>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "local_mapping.hpp"
#include "semantic_worker.hpp"
#include "stillpoint/dataset/testing.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "semantic_test_doubles.hpp"
#include "stillpoint/semantic/segmenter.hpp"
#include "stillpoint/slam/system.hpp"
#include "system_test_scenes.hpp"
#include "test_helpers.hpp"

namespace stillpoint::slam {
namespace {

namespace fs = std::filesystem;
using testing::contains;

struct Frames {
  CameraModel camera;
  std::vector<RgbdInput> inputs;
  std::vector<SE3> T_w_c;  // ground truth
};

// The dataset writer's textured plane, read back like the replay reads it.
const Frames& planeFrames() {
  static const Frames frames = [] {
    Frames out;
    const fs::path dir = fs::temp_directory_path() / ("stillpoint_semantic_test_" + std::to_string(::getpid()));
    fs::remove_all(dir);
    dataset::testing::SyntheticDatasetOptions options;
    options.n_frames = 30;
    options.width = 640;
    options.height = 480;
    options.lateral_velocity_m_s = Vec2(1.0, 0.15);
    const auto written = dataset::testing::writeSyntheticTumDataset(dir.string(), options);
    EXPECT_TRUE(written.ok()) << written.error();
    if (!written.ok()) return out;
    out.camera = written->camera;
    out.T_w_c = written->T_w_c;
    const auto tum = dataset::TumDataset::open(dir.string());
    EXPECT_TRUE(tum.ok()) << tum.error();
    for (std::size_t i = 0; tum.ok() && i < tum->size(); ++i) {
      const auto frame = tum->load(i);
      EXPECT_TRUE(frame.ok()) << frame.error();
      if (frame.ok()) out.inputs.push_back({frame->stamp, frame->gray, frame->depth_m, frame->bgr});
    }
    fs::remove_all(dir);
    return out;
  }();
  return frames;
}


SlamOptions semanticOptions(bool sequential = true) {
  SlamOptions o;
  o.sequential = sequential;
  o.semantic.enabled = true;
  o.semantic.max_removed_fraction = 1.0;
  // The rectangle stays put in the image while the scene moves through it:
  // it masks no object, so there is nothing for tracking to follow between
  // keyframes (MasksFollowTheirFeaturesBetweenKeyframes tests that).
  o.semantic.propagate_masks = false;
  return o;
}

struct RunResult {
  std::vector<TrajectoryPose> trajectory;
  std::vector<KeyFrameView> keyframes;
  MapStats stats;
};

RunResult runWith(const SlamOptions& options, std::unique_ptr<semantic::Segmenter> segmenter, bool with_colour = true) {
  RunResult run;
  const Frames& frames = planeFrames();
  auto system = SlamSystem::create(frames.camera, options, std::move(segmenter));
  EXPECT_TRUE(system.ok()) << system.error();
  if (!system.ok()) return run;
  for (RgbdInput input : frames.inputs) {
    if (!with_colour) input.bgr = cv::Mat();
    const auto out = (*system)->track(input);
    EXPECT_TRUE(out.ok()) << out.error();
    if (out.ok()) {
      EXPECT_EQ(out->state, TrackingState::kOk);
    }
  }
  (*system)->finish();
  run.trajectory = (*system)->trajectory();
  run.keyframes = (*system)->keyframes();
  run.stats = (*system)->mapStats();
  return run;
}

bool inside(const KeyFrameFeature& f, const cv::Rect& r, float margin) {
  return f.u >= r.x + margin && f.u < r.x + r.width - margin && f.v >= r.y + margin && f.v < r.y + r.height - margin;
}

// Features strictly inside the mask hold no map point; most outside do.
void expectMaskApplied(const RunResult& run) {
  ASSERT_FALSE(run.keyframes.empty());
  int checked = 0;
  for (const KeyFrameView& kf : run.keyframes) {
    SCOPED_TRACE("keyframe " + std::to_string(kf.id));
    EXPECT_TRUE(kf.segmented);
    int in = 0, out = 0, out_mapped = 0;
    for (const KeyFrameFeature& f : kf.features) {
      if (inside(f, kRect, 0)) {
        ++in;
        EXPECT_FALSE(f.mapped) << "feature at " << f.u << "," << f.v;
        EXPECT_TRUE(f.dynamic) << "feature at " << f.u << "," << f.v;
      } else if (!inside(f, kRect, -10)) {  // beyond the dilation
        ++out;
        out_mapped += f.mapped;
        EXPECT_FALSE(f.dynamic) << "feature at " << f.u << "," << f.v;
      }
    }
    EXPECT_GT(in, 20);
    EXPECT_GT(out_mapped, out / 4) << out_mapped << " of " << out << " features outside the mask are mapped";
    ++checked;
  }
  EXPECT_GT(checked, 0);
}

TEST(SemanticModule, SequentialRunDropsTheMaskedFeaturesOfEveryKeyframe) {
  auto fake = std::make_unique<RectangleSegmenter>(kRect, false);
  const std::shared_ptr<int> calls = fake->calls;
  const RunResult run = runWith(semanticOptions(), std::move(fake));
  ASSERT_EQ(run.trajectory.size(), planeFrames().inputs.size());
  expectMaskApplied(run);
  EXPECT_GE(run.keyframes.size(), 2u);
  EXPECT_EQ(*calls, static_cast<int>(run.keyframes.size()));  // keyframes only
  EXPECT_EQ(run.stats.semantic_keyframes_segmented, static_cast<int>(run.keyframes.size()));
  EXPECT_GT(run.stats.semantic_features_removed, 0);
  EXPECT_GT(run.stats.semantic_points_removed, 0);  // the first keyframe's points in the mask
  EXPECT_EQ(run.stats.semantic_keyframes_dropped, 0);
  EXPECT_EQ(run.stats.semantic_failures, 0);
}

// With propagation, every frame after the first segmented keyframe looks up
// that keyframe's masked features (world texture that lay in the rectangle)
// and keeps them out of the pose; keyframes never map a feature so marked.
TEST(SemanticModule, MasksFollowTheirFeaturesBetweenKeyframes) {
  for (const bool propagate : {true, false}) {
    SCOPED_TRACE(propagate ? "propagation on" : "propagation off");
    SlamOptions options = semanticOptions();
    options.semantic.propagate_masks = propagate;
    const Frames& frames = planeFrames();
    auto system = SlamSystem::create(frames.camera, options, std::make_unique<RectangleSegmenter>(kRect, false));
    ASSERT_TRUE(system.ok()) << system.error();
    int after_first = 0, marked_frames = 0, marked = 0;
    bool segmented = false;
    for (const RgbdInput& input : frames.inputs) {
      const auto out = (*system)->track(input);
      ASSERT_TRUE(out.ok()) << out.error();
      EXPECT_EQ(out->state, TrackingState::kOk);
      if (segmented) {
        ++after_first;
        marked_frames += out->semantic_features > 0;
      } else {
        EXPECT_EQ(out->semantic_features, 0) << "nothing is segmented yet";
      }
      marked += out->semantic_features;
      // Sequential mode applies a keyframe's mask when the next keyframe is mapped.
      segmented = segmented || (*system)->mapStats().semantic_keyframes_segmented > 0;
    }
    (*system)->finish();
    ASSERT_GT(after_first, 5);
    if (propagate) {
      EXPECT_GE(marked_frames, after_first * 8 / 10) << marked << " features marked in all";
      EXPECT_GT(marked / after_first, 10);
    } else {
      EXPECT_EQ(marked, 0);
    }
    for (const KeyFrameView& kf : (*system)->keyframes())
      for (const KeyFrameFeature& f : kf.features)
        EXPECT_FALSE(f.dynamic && f.mapped) << "keyframe " << kf.id << " feature at " << f.u << "," << f.v;
  }
}

// Growing the matches over their surface marks more of the masked region
// between keyframes, and only around it: the rectangle is 18 % of the image,
// 24 % with the growth radius around it.
TEST(SemanticModule, GrownMasksStayAroundTheirMatches) {
  const Frames& frames = planeFrames();
  auto run = [&](float grow, int* features) {
    SlamOptions options = semanticOptions();
    options.semantic.propagate_masks = true;
    options.semantic.propagate_grow_px = grow;
    // Counts of marked features compare propagation modes: the marked region
    // keeps its share of the feature budget in all of them.
    options.tracking.mover_cells_every = 1;
    auto system = SlamSystem::create(frames.camera, options, std::make_unique<RectangleSegmenter>(kRect, false));
    EXPECT_TRUE(system.ok()) << system.error();
    if (!system.ok()) return 0;
    int marked = 0;
    *features = 0;
    for (const RgbdInput& input : frames.inputs) {
      const auto out = (*system)->track(input);
      EXPECT_TRUE(out.ok()) << out.error();
      if (!out.ok()) return 0;
      marked += out->semantic_features;
      if (out->semantic_features > 0) *features += out->features;
    }
    (*system)->finish();
    for (const KeyFrameView& kf : (*system)->keyframes())
      for (const KeyFrameFeature& f : kf.features)
        EXPECT_FALSE(f.dynamic && f.mapped) << "keyframe " << kf.id << " feature at " << f.u << "," << f.v;
    return marked;
  };
  int features_matched = 0, features_grown = 0;
  const int matched = run(0.0f, &features_matched);
  const int grown = run(16.0f, &features_grown);
  ASSERT_GT(matched, 0);
  std::printf("marked between keyframes: %d matched, %d grown (of %d features)\n", matched, grown, features_grown);
  EXPECT_GT(grown, matched * 11 / 10) << "matched " << matched << ", grown " << grown;
  EXPECT_LT(grown, features_grown * 3 / 10) << grown << " of " << features_grown << " features marked";
}

// A textured card 0.5 m in front of the plane slides down the image while the
// camera moves sideways; it is the only thing the fake segmenter labels (its
// colour pixels have no blue).
class BlueFreeSegmenter : public RectangleSegmenter {
 public:
  BlueFreeSegmenter() : RectangleSegmenter(cv::Rect(0, 0, 1, 1), false) {}
  Result<semantic::Segmentation> segment(const cv::Mat& bgr) override {
    if (bgr.empty() || bgr.type() != CV_8UC3) return Error{"not a BGR image"};
    std::vector<cv::Mat> channels;
    cv::split(bgr, channels);
    cv::Mat mask = (channels[0] == 0) & (channels[1] > 0);
    const cv::Rect r = cv::boundingRect(mask);
    semantic::Segmentation seg;
    seg.labels = cv::Mat(bgr.size(), CV_8U, cv::Scalar(semantic::kNoLabel));
    seg.labels.setTo(0, mask);
    seg.movable_mask = mask;
    if (r.area() == 0) return seg;
    semantic::Instance inst;
    inst.class_id = 0;
    inst.class_name = "person";
    inst.score = 0.9f;
    inst.box = r;
    inst.mask = mask(r).clone();
    inst.area = cv::countNonZero(mask);
    inst.movable = true;
    seg.instances.push_back(inst);
    seg.movable_pixels = inst.area;
    return seg;
  }
};

// The plane sequence with a textured card 0.5 m in front of it sliding down
// the image (6 px a frame); the card is the only thing without blue.
cv::Rect slidingCardRect(std::size_t frame) { return cv::Rect(420, 40 + 6 * static_cast<int>(frame), 150, 200); }

// noise > 0: Gaussian noise of that sigma on the
// card in every frame (its features then match their keyframe in some frames
// and not in others).
std::vector<RgbdInput> slidingCardInputs(double noise) {
  const Frames& plane = planeFrames();
  cv::Mat coarse(25, 19, CV_8U), texture;  // random blocks of 8 px, like the plane's texture
  cv::RNG rng(7);
  rng.fill(coarse, cv::RNG::UNIFORM, 20, 236);  // green > 0 everywhere: the segmenter needs it
  cv::resize(coarse, texture, cv::Size(), 8, 8, cv::INTER_NEAREST);
  cv::GaussianBlur(texture, texture, cv::Size(3, 3), 0.8);
  std::vector<RgbdInput> inputs;
  for (std::size_t k = 0; k < plane.inputs.size(); ++k) {
    RgbdInput in{plane.inputs[k].stamp, plane.inputs[k].gray.clone(), plane.inputs[k].depth_m.clone(),
                 plane.inputs[k].bgr.clone()};
    const cv::Rect r = slidingCardRect(k);
    cv::Mat card = texture(cv::Rect(0, 0, 150, 200)).clone();
    if (noise > 0) {
      cv::Mat n(card.size(), CV_16S);
      rng.fill(n, cv::RNG::NORMAL, 0, noise);
      cv::Mat sum;
      cv::add(card, n, sum, cv::noArray(), CV_16S);
      sum.convertTo(card, CV_8U);
      cv::max(card, 1, card);  // green > 0
    }
    card.copyTo(in.gray(r));
    in.depth_m(r).setTo(1.0f);
    cv::Mat colour;
    cv::merge(std::vector<cv::Mat>{cv::Mat::zeros(card.size(), CV_8U), card, card}, colour);
    colour.copyTo(in.bgr(r));
    inputs.push_back(std::move(in));
  }
  return inputs;
}

// Finds nothing in its calls [first, last): a detector's miss while the card
// is still in view.
class MissingSegmenter : public BlueFreeSegmenter {
 public:
  MissingSegmenter(int first, int last) : first_(first), last_(last) {}
  Result<semantic::Segmentation> segment(const cv::Mat& bgr) override {
    const int call = calls_++;
    if (call < first_ || call >= last_) return BlueFreeSegmenter::segment(bgr);
    return noOneFound(bgr.size());
  }

 private:
  int first_, last_, calls_ = 0;
};

// The lookups beyond the newest segmented keyframe's matches (more growing
// passes, the last frame's flags) each keep more of the sliding card out
// through the detector's misses, and none spreads over the plane.
TEST(SemanticModule, MoreLookupsFollowAMovingCardThroughDetectorMisses) {
  const Frames& plane = planeFrames();
  ASSERT_FALSE(plane.inputs.empty());
  const std::vector<RgbdInput> inputs = slidingCardInputs(12.0);
  struct Count {
    int marked = 0;        // features kept out between keyframes
    int plane_flagged = 0;  // keyframe features well off the card flagged dynamic
    int plane = 0;
  };
  auto run = [&](int passes, bool from_last) {
    SlamOptions options = semanticOptions();
    options.semantic.propagate_masks = true;
    options.semantic.propagate_grow_px = 16.0f;
    options.semantic.propagate_grow_passes = passes;
    options.semantic.propagate_from_last = from_last;
    options.geometry.enabled = false;  // its verdict would take over the card's flags
    Count c;
    auto system = SlamSystem::create(plane.camera, options, std::make_unique<MissingSegmenter>(2, 6));
    EXPECT_TRUE(system.ok()) << system.error();
    if (!system.ok()) return c;
    for (const RgbdInput& input : inputs) {
      const auto out = (*system)->track(input);
      EXPECT_TRUE(out.ok()) << out.error();
      if (!out.ok()) return c;
      EXPECT_EQ(out->state, TrackingState::kOk);
      c.marked += out->semantic_features;
    }
    (*system)->finish();
    for (const KeyFrameView& kf : (*system)->keyframes()) {
      std::size_t k = 0;
      while (k < inputs.size() && inputs[k].stamp != kf.stamp) ++k;
      if (k == inputs.size()) continue;
      const cv::Rect near = slidingCardRect(k) + cv::Size(40, 40) - cv::Point(20, 20);
      for (const KeyFrameFeature& f : kf.features) {
        if (near.contains(cv::Point(static_cast<int>(f.u), static_cast<int>(f.v)))) continue;
        ++c.plane;
        c.plane_flagged += f.dynamic;
      }
    }
    return c;
  };
  const Count base = run(1, false);
  const Count passes = run(3, false);
  const Count last = run(1, true);
  std::printf("sliding card, 4 of its keyframes missed: marked %d (one pass), %d (3 passes), %d (last frame); "
              "plane features flagged %d/%d %d/%d %d/%d\n",
              base.marked, passes.marked, last.marked, base.plane_flagged, base.plane, passes.plane_flagged,
              passes.plane, last.plane_flagged, last.plane);
  ASSERT_GT(base.marked, 0);
  EXPECT_GT(passes.marked, base.marked);
  EXPECT_GT(last.marked, base.marked);
  for (const Count& c : {base, passes, last}) {
    ASSERT_GT(c.plane, 100);
    EXPECT_LE(c.plane_flagged, c.plane / 50) << "flags spread over the plane";
  }
}

// A card 300 x 380 px, 1 m away (the plane: 1.5 m), standing in the world
// where the segmenter finds it (frames 0-9), still standing where it finds it
// no more (10-19: a blue tint), then carried along with the camera, still
// unfound (20-29): a person the detector loses as they stand, who then walks
// on. The geometry module has not seen it move. Points keyframes make on it
// after its masks end serve a mover's probation, so it does not hold the
// pose when it goes; with the ordinary probation they pass in 3 frames, and
// it pulls the pose along with it.
std::vector<RgbdInput> standingCardInputs() {
  const Frames& plane = planeFrames();
  cv::Mat coarse(48, 38, CV_8U), texture;
  cv::RNG rng(5);
  rng.fill(coarse, cv::RNG::UNIFORM, 20, 236);
  cv::resize(coarse, texture, cv::Size(), 8, 8, cv::INTER_NEAREST);
  cv::GaussianBlur(texture, texture, cv::Size(3, 3), 0.8);
  const cv::Size size(300, 380);
  const double z = 1.0;
  std::vector<RgbdInput> inputs;
  for (std::size_t k = 0; k < plane.inputs.size(); ++k) {
    // Where it stood from frame 0, seen from frame k (the camera only translates).
    const Vec3 moved = plane.T_w_c[std::min<std::size_t>(k, 19)].translation() - plane.T_w_c[0].translation();
    const cv::Rect r(static_cast<int>(std::lround(330 - plane.camera.fx * moved.x() / z)),
                     static_cast<int>(std::lround(60 - plane.camera.fy * moved.y() / z)), size.width, size.height);
    RgbdInput in{plane.inputs[k].stamp, plane.inputs[k].gray.clone(), plane.inputs[k].depth_m.clone(),
                 plane.inputs[k].bgr.clone()};
    const cv::Mat card = texture(cv::Rect(cv::Point(0, 0), size));
    card.copyTo(in.gray(r));
    in.depth_m(r).setTo(static_cast<float>(z));
    const cv::Mat blue(size, CV_8U, cv::Scalar(k >= 10 ? 40 : 0));
    cv::Mat colour;
    cv::merge(std::vector<cv::Mat>{blue, card, card}, colour);
    colour.copyTo(in.bgr(r));
    inputs.push_back(std::move(in));
  }
  return inputs;
}

TEST(SemanticModule, AMoverLostByTheSegmenterServesAMoversProbation) {
  const Frames& plane = planeFrames();
  ASSERT_EQ(plane.T_w_c.size(), plane.inputs.size());
  const std::vector<RgbdInput> inputs = standingCardInputs();
  ASSERT_EQ(inputs.size(), 30u);
  // Worst position error (m) while the card stands unfound (frames 10-19)
  // and once it is carried (20-29); [0]: probation after masks off, [1]: on.
  double standing[2] = {0, 0}, carried[2] = {0, 0};
  for (int after_masks = 0; after_masks < 2; ++after_masks) {
    SlamOptions options = semanticOptions();
    options.semantic.propagate_masks = true;
    options.semantic.probation_after_masks = after_masks;
    auto system = SlamSystem::create(plane.camera, options, std::make_unique<BlueFreeSegmenter>());
    ASSERT_TRUE(system.ok()) << system.error();
    for (std::size_t k = 0; k < inputs.size(); ++k) {
      const auto out = (*system)->track(inputs[k]);
      ASSERT_TRUE(out.ok()) << out.error();
      if (k < 10) continue;
      ASSERT_TRUE(hasPose(out->state)) << "frame " << k;
      const double error = (out->T_w_c.translation() - plane.T_w_c[k].translation()).norm();
      double& worst = k < 20 ? standing[after_masks] : carried[after_masks];
      worst = std::max(worst, error);
    }
    (*system)->finish();
  }
  std::printf("card found, standing unfound, carried: worst error %.1f mm standing, %.1f mm carried without the "
              "probation after masks, %.1f / %.1f mm with it\n",
              standing[0] * 1e3, carried[0] * 1e3, standing[1] * 1e3, carried[1] * 1e3);
  EXPECT_GT(carried[0], 4 * standing[0]) << "the card's points pull the pose without it";
  EXPECT_LT(carried[1], 2 * standing[1]);
  EXPECT_LT(carried[1], 0.05);
}

// Paints the rectangle in its first `masked` calls only, then finds no one.
class FirstCallsSegmenter : public RectangleSegmenter {
 public:
  explicit FirstCallsSegmenter(int masked) : RectangleSegmenter(kRect, false), masked_(masked) {}
  Result<semantic::Segmentation> segment(const cv::Mat& bgr) override {
    if (calls_++ < masked_) return RectangleSegmenter::segment(bgr);
    return noOneFound(bgr.size());
  }

 private:
  int masked_, calls_ = 0;
};

// A mask over static texture in the first keyframe only: its marks follow
// that texture into the next frames, and into the keyframes made from them.
// Once those keyframes are segmented and nothing is found, their marks are
// dropped, and the newest segmented keyframe hands none on: the marks end
// instead of chaining (and growing) from keyframe to keyframe for good.
TEST(SemanticModule, AKeyframeWhoseSegmentationFindsNoOneEndsTheMarks) {
  const Frames& frames = planeFrames();
  SlamOptions options = semanticOptions();
  options.semantic.propagate_masks = true;
  options.geometry.enabled = false;  // every flag is then a mark
  auto system = SlamSystem::create(frames.camera, options, std::make_unique<FirstCallsSegmenter>(1));
  ASSERT_TRUE(system.ok()) << system.error();
  std::vector<int> marked;
  for (const RgbdInput& input : frames.inputs) {
    const auto out = (*system)->track(input);
    ASSERT_TRUE(out.ok()) << out.error();
    EXPECT_EQ(out->state, TrackingState::kOk);
    marked.push_back(out->semantic_features);
  }
  (*system)->finish();
  const std::vector<KeyFrameView> keyframes = (*system)->keyframes();
  // A keyframe after the first was made from a frame the marks had followed
  // into (frame 23 of 30).
  ASSERT_GE(keyframes.size(), 2u);
  std::size_t second = 0;
  while (second < frames.inputs.size() && frames.inputs[second].stamp != keyframes[1].stamp) ++second;
  ASSERT_LT(second, marked.size());
  EXPECT_GT(marked[second], 0);
  int marked_in_empty = 0;
  for (std::size_t k = 1; k < keyframes.size(); ++k) {
    EXPECT_TRUE(keyframes[k].segmented) << "keyframe " << keyframes[k].id;
    for (const KeyFrameFeature& f : keyframes[k].features) marked_in_empty += f.dynamic;
  }
  // The first keyframe's marks did follow the texture.
  int followed = 0;
  for (int m : marked) followed += m;
  EXPECT_GT(followed, 20);
  EXPECT_EQ(marked_in_empty, 0) << "marks kept by keyframes whose segmentation found no one";
  // The last frames come after the second keyframe (frame 23 of 30), which
  // was segmented and found empty before the next frame (sequential mode).
  int last_marked = 0;
  for (std::size_t i = marked.size() - 5; i < marked.size(); ++i) last_marked += marked[i];
  EXPECT_EQ(last_marked, 0);
}

TEST(SemanticModule, SequentialModeIsDeterministic) {
  const RunResult a = runWith(semanticOptions(), std::make_unique<RectangleSegmenter>(kRect, false));
  const RunResult b = runWith(semanticOptions(), std::make_unique<RectangleSegmenter>(kRect, false));
  ASSERT_EQ(a.trajectory.size(), b.trajectory.size());
  for (std::size_t i = 0; i < a.trajectory.size(); ++i)
    EXPECT_TRUE(a.trajectory[i].T_w_c.isApprox(b.trajectory[i].T_w_c, 0.0)) << "frame " << i;
  ASSERT_EQ(a.keyframes.size(), b.keyframes.size());
  for (std::size_t k = 0; k < a.keyframes.size(); ++k) {
    ASSERT_EQ(a.keyframes[k].features.size(), b.keyframes[k].features.size());
    for (std::size_t i = 0; i < a.keyframes[k].features.size(); ++i) {
      EXPECT_EQ(a.keyframes[k].features[i].mapped, b.keyframes[k].features[i].mapped);
      EXPECT_EQ(a.keyframes[k].features[i].dynamic, b.keyframes[k].features[i].dynamic);
    }
  }
  EXPECT_EQ(a.stats.points, b.stats.points);
  EXPECT_EQ(a.stats.semantic_features_removed, b.stats.semantic_features_removed);
}

// sequential_latency_frames: a keyframe is segmented when the (modelled)
// segmenter is free and its result lands that many frames later; keyframes
// made meanwhile wait in the drop-oldest queue. The schedule is replayed here
// from the keyframe decisions alone, frame by frame.
TEST(SemanticModule, SequentialLatencyAppliesResultsLateAndQueuesLikeAThread) {
  for (const int capacity : {1, 2}) {
    SCOPED_TRACE("queue_capacity " + std::to_string(capacity));
    const int latency = 8;
    SlamOptions options = semanticOptions();
    options.semantic.sequential_latency_frames = latency;
    options.semantic.queue_capacity = capacity;
    options.keyframes.tracked_ratio = 0.99;  // a keyframe nearly every frame: the queue overflows
    auto fake = std::make_unique<RectangleSegmenter>(kRect, false);
    const std::shared_ptr<int> calls = fake->calls;
    const Frames& frames = planeFrames();
    auto system = SlamSystem::create(frames.camera, options, std::move(fake));
    ASSERT_TRUE(system.ok()) << system.error();
    // The model: the keyframe under way (its due frame) and those waiting.
    int running_due = -1, expected_calls = 0, expected_dropped = 0, keyframes = 0;
    std::vector<int> waiting;  // frames that made them
    for (int i = 0; i < static_cast<int>(frames.inputs.size()); ++i) {
      // The first keyframe's frame is segmented before the map is built
      // from it, as in a live run; it never waits in the queue.
      if (i == 0) ++expected_calls;
      while (running_due >= 0 && i >= running_due) {  // what track(i) applies first
        ++expected_calls;
        if (waiting.empty()) {
          running_due = -1;
        } else {
          waiting.erase(waiting.begin());
          running_due += latency;
        }
      }
      const auto out = (*system)->track(frames.inputs[i]);
      ASSERT_TRUE(out.ok()) << out.error();
      if (out->new_keyframe) {
        ++keyframes;
        if (i == 0) {
          ASSERT_EQ(out->state, TrackingState::kOk);
        } else if (running_due < 0) {
          running_due = i + latency;
        } else {
          if (static_cast<int>(waiting.size()) >= capacity) {
            waiting.erase(waiting.begin());
            ++expected_dropped;
          }
          waiting.push_back(i);
        }
      }
      ASSERT_EQ(*calls, expected_calls) << "after frame " << i;
    }
    EXPECT_GE(keyframes, 4);
    EXPECT_GT(expected_dropped, 0) << "the test should make the queue overflow (" << keyframes << " keyframes)";
    (*system)->finish();  // segments what is under way and waiting
    const MapStats stats = (*system)->mapStats();
    EXPECT_EQ(*calls, keyframes - expected_dropped);
    EXPECT_EQ(stats.semantic_keyframes_dropped, expected_dropped);
    EXPECT_GT(stats.semantic_keyframes_segmented, 0);
  }
}

// With the semantic module as the only judge of what moves, the pose health
// says when the newest masks are too old to vouch for the view
// (docs/pose-health.md). In the rendered room (3 s, the fake segmenter's
// rectangle in a corner of the image), masks that come with the keyframes
// leave the poses `good`; when each segmentation takes 70 frames (2.3 s),
// every frame whose newest masks are over 0.6 s old is at least `degraded`,
// and over 2 s `unreliable`.
TEST(SemanticModule, StaleMasksLowerThePoseHealthOfTheSemanticModuleAlone) {
  static const Sequence room = roomSequence(90);
  struct Seen {
    float oldest = -1;
    int posed = 0, good = 0, unknown = 0, stale = 0, very_stale = 0;
  };
  const auto run = [](bool semantic, int latency) {
    Seen seen;
    SlamOptions options = semanticOptions();
    options.semantic.enabled = semantic;
    options.semantic.propagate_masks = true;
    options.semantic.sequential_latency_frames = latency;
    options.geometry.enabled = false;
    options.place.loop_closing = false;
    auto system = SlamSystem::create(room.camera, options,
                                     semantic ? std::make_unique<RectangleSegmenter>(cv::Rect(0, 0, 160, 120), false)
                                              : nullptr);
    EXPECT_TRUE(system.ok()) << system.error();
    if (!system.ok()) return seen;
    for (std::size_t i = 0; i < room.frames.size(); ++i) {
      RgbdInput input = room.frames[i];
      cv::cvtColor(input.gray, input.bgr, cv::COLOR_GRAY2BGR);
      const auto out = (*system)->track(input);
      EXPECT_TRUE(out.ok()) << out.error();
      if (!out.ok() || !hasPose(out->state)) continue;
      const PoseQuality& q = out->quality;
      ++seen.posed;
      // The first frame's masks come when the map is made from it.
      seen.unknown += i > 0 && q.mask_age_s < 0;
      seen.oldest = std::max(seen.oldest, q.mask_age_s);
      seen.good += q.health == PoseHealth::kGood;
      EXPECT_EQ(q.health == PoseHealth::kGood, q.causes == 0) << "frame " << i << ": " << health_cause::toString(q.causes);
      if (q.mask_age_s > 0.6f) {
        ++seen.stale;
        EXPECT_NE(q.health, PoseHealth::kGood) << "frame " << i << ": masks " << q.mask_age_s << " s old";
        EXPECT_TRUE(q.causes & health_cause::kMasksLate) << "frame " << i << ": " << health_cause::toString(q.causes);
      } else {
        EXPECT_FALSE(q.causes & health_cause::kMasksLate) << "frame " << i << ": masks " << q.mask_age_s << " s old";
      }
      if (q.mask_age_s > 2.0f) {
        ++seen.very_stale;
        EXPECT_EQ(q.health, PoseHealth::kUnreliable) << "frame " << i << ": masks " << q.mask_age_s << " s old";
      }
    }
    (*system)->finish();
    return seen;
  };
  const int frames = static_cast<int>(room.frames.size());
  const Seen off = run(false, 0);
  EXPECT_EQ(off.posed, frames);
  EXPECT_EQ(off.unknown, frames - 1) << "no masks, no age";
  EXPECT_GT(off.good, frames / 2);

  const Seen prompt = run(true, 0);
  EXPECT_EQ(prompt.posed, frames);
  EXPECT_EQ(prompt.unknown, 0);
  EXPECT_EQ(prompt.stale, 0) << "the oldest masks were " << prompt.oldest << " s old";
  EXPECT_GT(prompt.good, frames / 2);

  const Seen late = run(true, 70);
  EXPECT_GT(late.posed, frames * 9 / 10);
  EXPECT_EQ(late.unknown, 0);
  EXPECT_GT(late.stale, 20) << "the oldest masks were " << late.oldest << " s old";
  EXPECT_GT(late.very_stale, 3) << "the oldest masks were " << late.oldest << " s old";
  EXPECT_GT(late.good, 5) << "good while the masks were young";
}

TEST(SemanticModule, ThreadedRunAppliesEveryResultByFinish) {
  SlamOptions options = semanticOptions(false);
  options.semantic.queue_capacity = 100;  // nothing dropped: every keyframe is checked
  const RunResult run = runWith(options, std::make_unique<RectangleSegmenter>(kRect, false));
  ASSERT_EQ(run.stats.semantic_keyframes_dropped, 0);
  expectMaskApplied(run);
  EXPECT_GT(run.stats.semantic_latency_ms_p95, 0.0);
}

// A live run with a person in view from the first frame: the frame that
// becomes the first keyframe is segmented before the map is built from it,
// so none of its features in the mask holds a map point even while the
// segmenter (here 300 ms a call) would still be busy with it; its result is
// the first keyframe's (no second call).
TEST(SemanticModule, ThreadedRunBuildsTheFirstMapWithoutTheMoversInView) {
  const auto& frames = planeFrames();
  SlamOptions options = semanticOptions(false);
  options.semantic.queue_capacity = 100;
  auto fake = std::make_unique<RectangleSegmenter>(kRect, false);
  fake->delay = std::chrono::milliseconds(300);
  const std::shared_ptr<int> calls = fake->calls;
  auto system = SlamSystem::create(frames.camera, options, std::move(fake));
  ASSERT_TRUE(system.ok()) << system.error();
  auto out = (*system)->track(frames.inputs[0]);
  ASSERT_TRUE(out.ok()) << out.error();
  ASSERT_EQ(out->state, TrackingState::kOk);
  const std::vector<KeyFrameView> first = (*system)->keyframes();
  ASSERT_EQ(first.size(), 1u);
  int in = 0;
  for (const KeyFrameFeature& f : first[0].features)
    if (inside(f, kRect, 0)) {
      ++in;
      EXPECT_FALSE(f.mapped) << "feature at " << f.u << "," << f.v;
      EXPECT_TRUE(f.dynamic) << "feature at " << f.u << "," << f.v;
    }
  EXPECT_GT(in, 20);
  (*system)->finish();
  EXPECT_EQ(*calls, static_cast<int>((*system)->keyframes().size()));  // keyframes only, once each
}

// A mover that fills the view where a map would start: the masks the frame
// is segmented with ahead leave fewer features than a map needs
// (tracking.min_init_features), so the map waits for a view showing more of
// the scene; not for ever: after tracking.new_map_after_lost_s of waiting it
// starts as without the masks ahead.
TEST(SemanticModule, AMapStartWaitsWhileAMoverFillsTheView) {
  const auto& frames = planeFrames();
  ASSERT_GE(frames.inputs.size(), 20u);
  SlamOptions options = semanticOptions(false);
  options.tracking.new_map_after_lost_s = 0.2;
  auto fake = std::make_unique<RectangleSegmenter>(cv::Rect(0, 0, 600, 480), false);  // all but a 40 px strip
  const std::shared_ptr<int> calls = fake->calls;
  auto system = SlamSystem::create(frames.camera, options, std::move(fake));
  ASSERT_TRUE(system.ok()) << system.error();
  int started = -1;
  for (int i = 0; i < static_cast<int>(frames.inputs.size()) && started < 0; ++i) {
    const auto out = (*system)->track(frames.inputs[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    if (out->state == TrackingState::kOk) {
      started = i;
    } else {
      EXPECT_EQ(out->state, TrackingState::kInitialising) << "frame " << i;
      EXPECT_EQ(*calls, i + 1);  // segmented ahead (no keyframe yet to segment otherwise)
    }
  }
  ASSERT_GT(started, 0);
  const double waited = secondsBetween(frames.inputs[started].stamp, frames.inputs[0].stamp);
  EXPECT_GE(waited, 0.2);
  EXPECT_LT(waited, 0.3);
  (*system)->finish();
}

// A stop on request (stillpointd on SIGTERM) drops the keyframes still
// queued for segmentation instead of segmenting them first.
TEST(SemanticModule, FinishCanDropQueuedKeyframes) {
  const Frames& frames = planeFrames();
  SlamOptions options = semanticOptions(false);
  options.semantic.queue_capacity = 100;
  options.keyframes.tracked_ratio = 0.95;  // keyframes often (and a quick mapper), so that some wait
  options.mapping.local_ba = false;
  auto fake = std::make_unique<RectangleSegmenter>(kRect, false);
  // The first keyframe is segmented before the map is built; the second's
  // segmentation waits.
  fake->gate = std::make_shared<std::atomic<bool>>(false);
  fake->ungated_calls = 1;
  const auto gate = fake->gate;
  const auto calls = fake->calls;
  auto system = SlamSystem::create(frames.camera, options, std::move(fake));
  ASSERT_TRUE(system.ok()) << system.error();
  for (const RgbdInput& input : frames.inputs) ASSERT_TRUE((*system)->track(input).ok());
  std::thread opener([gate] {  // lets the running segmentation end once finish() has begun
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    *gate = true;
  });
  (*system)->finish(/*discard_pending_segmentation=*/true);
  opener.join();
  const MapStats stats = (*system)->mapStats();
  EXPECT_LE(*calls, 2);
  EXPECT_LE(stats.semantic_keyframes_segmented, 2);
  EXPECT_GE(stats.semantic_keyframes_dropped, 2);
  EXPECT_GE(stats.semantic_keyframes_segmented + stats.semantic_keyframes_dropped,
            static_cast<int>((*system)->keyframes().size()) - 1);
}

TEST(SemanticModule, ThreadHookRunsOnTheSegmentationThread) {
  const Frames& frames = planeFrames();
  std::atomic<int> calls{0};
  std::thread::id hook_thread;
  SlamThreadHooks hooks;
  hooks.semantic_start = [&] {
    hook_thread = std::this_thread::get_id();
    ++calls;
  };
  auto system = SlamSystem::create(frames.camera, semanticOptions(false),
                                   std::make_unique<RectangleSegmenter>(kRect, false), hooks);
  ASSERT_TRUE(system.ok()) << system.error();
  for (const RgbdInput& input : frames.inputs) ASSERT_TRUE((*system)->track(input).ok());
  (*system)->finish();
  EXPECT_EQ(calls, 1);
  EXPECT_NE(hook_thread, std::this_thread::get_id());
  EXPECT_GT((*system)->mapStats().semantic_keyframes_segmented, 0);
}

TEST(SemanticModule, CheckSemanticModelFindsTheCardAndItsModelFile) {
  SemanticOptions o;
  o.model_card = semantic::kPersonCardFile;  // relative: found in models/
  const auto found = checkSemanticModel(o);
  ASSERT_TRUE(found.ok()) << found.error();
  EXPECT_TRUE(std::filesystem::is_regular_file(found->model_path)) << found->model_path;
  o.model_card = "/nonexistent/card.yaml";
  const auto missing = checkSemanticModel(o);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().find("/nonexistent/card.yaml"), std::string::npos) << missing.error();
}

TEST(SemanticModule, UnconfirmedMasksOfAConfirmCardRemoveNothingWithoutGeometry) {
  const RunResult run = runWith(semanticOptions(), std::make_unique<RectangleSegmenter>(kRect, true));
  EXPECT_EQ(run.stats.semantic_features_removed, 0);
  EXPECT_EQ(run.stats.semantic_instances_applied, 0);
  EXPECT_EQ(run.stats.semantic_instances_unconfirmed, static_cast<int>(run.keyframes.size()));
  for (const KeyFrameView& kf : run.keyframes) {
    EXPECT_TRUE(kf.segmented);
    for (const KeyFrameFeature& f : kf.features) EXPECT_FALSE(f.dynamic);
  }
}

// A person model beside the main one also paints things that stand (the
// selfie model, the red box under the TUM teddy bear): its regions keep
// nothing out of a keyframe. Where a map starts, their features stay out of
// the first frame's pose and vote (the person who walks in front of the
// camera from the first frame, whom the main model misses) but still make
// points, on a mover's probation: what stands there joins the pose after it.
TEST(SemanticModule, ASecondOpinionMakesPointsOnProbationWhereAMapStarts) {
  SlamOptions options = semanticOptions();
  auto person_model = [](bool second_opinion) {
    auto fake = std::make_unique<RectangleSegmenter>(kRect, false);
    fake->second_opinion = second_opinion;
    return fake;
  };
  // Segmented as each keyframe is made: no map start segmentation.
  const RunResult inline_run = runWith(options, person_model(true));
  EXPECT_EQ(inline_run.stats.semantic_features_removed, 0);
  EXPECT_EQ(inline_run.stats.semantic_instances_applied, 0);
  EXPECT_EQ(inline_run.stats.semantic_instances_unconfirmed, static_cast<int>(inline_run.keyframes.size()));
  // The same region from the main model is applied in every keyframe.
  expectMaskApplied(runWith(options, person_model(false)));

  // Segmentations that come late: the map's first frame is segmented before
  // the map is built. The main model's region makes no points there; the
  // person model's makes them, and its keyframe's own verdict leaves the
  // region alone.
  options.semantic.sequential_latency_frames = 3;
  const Frames& frames = planeFrames();
  ASSERT_GE(frames.inputs.size(), 6u);
  for (const bool second_opinion : {false, true}) {
    SCOPED_TRACE(second_opinion ? "person model" : "main model");
    auto system = SlamSystem::create(frames.camera, options, person_model(second_opinion));
    ASSERT_TRUE(system.ok()) << system.error();
    for (int i = 0; i < 6; ++i) {
      const auto out = (*system)->track(frames.inputs[i]);
      ASSERT_TRUE(out.ok()) << out.error();
      EXPECT_EQ(out->state, TrackingState::kOk);
    }
    const std::vector<KeyFrameView> keyframes = (*system)->keyframes();
    ASSERT_FALSE(keyframes.empty());
    int in = 0, mapped = 0, dynamic = 0;
    for (const KeyFrameFeature& f : keyframes.front().features) {
      if (!inside(f, kRect, 0)) continue;
      ++in;
      mapped += f.mapped;
      dynamic += f.dynamic;
    }
    EXPECT_GT(in, 20);
    if (second_opinion) {
      EXPECT_EQ((*system)->mapStats().semantic_instances_applied, 0);
      EXPECT_GT(mapped, in * 3 / 4) << mapped << " of " << in;
      EXPECT_EQ(dynamic, 0);
    } else {
      EXPECT_EQ(mapped, 0);
      EXPECT_EQ(dynamic, in);
    }
    (*system)->finish();
  }
}

TEST(SemanticModule, RemovalCapKeepsAHugeUnconfirmedMaskFromEmptyingTheMap) {
  const cv::Rect most(0, 0, 560, 480);  // 7/8 of the image
  SlamOptions options = semanticOptions();
  options.semantic.max_removed_fraction = 0.5;
  options.semantic.min_kept_points = 0;  // the share alone
  const RunResult capped = runWith(options, std::make_unique<RectangleSegmenter>(most, false));
  EXPECT_EQ(capped.stats.semantic_features_removed, 0);
  EXPECT_GT(capped.stats.semantic_instances_capped, 0);
  EXPECT_GT(capped.stats.points, 100u);
  options.semantic.max_removed_fraction = 1.0;  // no cap: the same mask empties most of the keyframe
  // Its poses then jump by up to 0.4 m a frame, which the motion check would
  // drop; the run compares the map, every frame with its pose.
  options.tracking.max_acceleration = 0;
  const RunResult uncapped = runWith(options, std::make_unique<RectangleSegmenter>(most, false));
  EXPECT_GT(uncapped.stats.semantic_features_removed, 0);
  EXPECT_EQ(uncapped.stats.semantic_instances_capped, 0);
  EXPECT_LT(uncapped.stats.points, capped.stats.points);
}

// A person near the camera fills most of the view: over the share the cap
// allows, but the room outside the mask keeps enough points to track on.
TEST(SemanticModule, AMaskOverTheShareIsAppliedWhileEnoughPointsStayOutsideIt) {
  const cv::Rect three_quarters(0, 0, 480, 480);
  SlamOptions options = semanticOptions();
  options.semantic.max_removed_fraction = 0.5;
  const RunResult kept = runWith(options, std::make_unique<RectangleSegmenter>(three_quarters, false));
  EXPECT_EQ(kept.stats.semantic_instances_capped, 0);
  EXPECT_GT(kept.stats.semantic_features_removed, 0);
  ASSERT_FALSE(kept.keyframes.empty());
  for (const KeyFrameView& kf : kept.keyframes) {
    SCOPED_TRACE("keyframe " + std::to_string(kf.id));
    EXPECT_TRUE(kf.segmented);
    int in = 0, mapped_outside = 0;
    for (const KeyFrameFeature& f : kf.features) {
      if (inside(f, three_quarters, 0)) {
        ++in;
        EXPECT_FALSE(f.mapped) << "feature at " << f.u << "," << f.v;
      } else {
        mapped_outside += f.mapped;
      }
    }
    EXPECT_GT(in, 20);
    EXPECT_GE(mapped_outside, options.semantic.min_kept_points);
  }
  // Asked to keep more than the quarter outside holds, the share decides.
  options.semantic.min_kept_points = 100000;
  const RunResult capped = runWith(options, std::make_unique<RectangleSegmenter>(three_quarters, false));
  EXPECT_GT(capped.stats.semantic_instances_capped, 0);
  EXPECT_EQ(capped.stats.semantic_features_removed, 0);
}

TEST(StaticSightings, APlaceSeenStandingTwiceAndNeverMovingIsKnown) {
  StaticSightings memory;
  const auto at = [](double s) { return Timestamp::fromSeconds(100.0 + s); };
  const Vec3 bear(1.03, 0.52, 0.91), same_cell(1.08, 0.57, 0.96), away(1.33, 0.52, 0.91);
  memory.add(0, at(0), {bear, same_cell}, {});  // one keyframe counts a cell once
  EXPECT_FALSE(memory.seenStanding(0, bear, 2, 0.0));
  memory.add(0, at(1), {same_cell}, {});
  EXPECT_TRUE(memory.seenStanding(0, bear, 2, 0.0));
  EXPECT_FALSE(memory.seenStanding(0, bear, 2, 2.0)) << "seen for a second only";
  memory.add(0, at(2.5), {bear}, {});
  EXPECT_TRUE(memory.seenStanding(0, bear, 2, 2.0));
  EXPECT_FALSE(memory.seenStanding(0, away, 1, 0.0));
  EXPECT_FALSE(memory.seenStanding(1, bear, 1, 0.0));  // another map's world
  // A surface on a cell border, seen a millimetre either side of it.
  memory.add(0, at(3), {Vec3(-2.0, 3.0, 1.5004)}, {});
  memory.add(0, at(4), {Vec3(-2.0, 3.0, 1.4996)}, {});
  EXPECT_TRUE(memory.seenStanding(0, Vec3(-2.0, 3.0, 1.5), 2, 0.0));
  for (double s : {5.0, 6.0, 7.0}) memory.add(0, at(s), {}, {bear});
  EXPECT_FALSE(memory.seenStanding(0, bear, 2, 0.0)) << "seen moving as often as standing";
}

// A map found again is merged into the older one: its places move with it.
TEST(StaticSightings, PlacesMoveWithTheirMapIntoAnother) {
  StaticSightings memory;
  const auto at = [](double s) { return Timestamp::fromSeconds(100.0 + s); };
  const Vec3 bear(-0.47, 0.52, 1.31);
  // Stamps need not increase (a map file from a later recording).
  memory.add(1, at(3), {bear}, {});
  memory.add(1, at(0), {bear}, {});
  EXPECT_TRUE(memory.seenStanding(1, bear, 2, 3.0));
  SE3 T_0_1 = SE3::Identity();
  T_0_1.linear() = Eigen::AngleAxisd(0.3, Vec3::UnitY()).toRotationMatrix();
  T_0_1.translation() = Vec3(2.0, -0.1, 0.5);
  memory.add(0, at(1), {T_0_1 * bear}, {});  // map 0 saw it once itself
  memory.moveMap(1, 0, T_0_1);
  EXPECT_FALSE(memory.seenStanding(1, bear, 1, 0.0));
  EXPECT_TRUE(memory.seenStanding(0, T_0_1 * bear, 3, 3.0));
  EXPECT_FALSE(memory.seenStanding(0, bear, 1, 0.0));
}

// The memory travels with the map file: a robot back in the same place knows
// its furniture. A first run sees the view's middle as a static object only;
// a second, localising on the saved map (no keyframes, so no sightings of its
// own), is told it is a person in every segmented frame: it leaves most such
// regions alone when the file holds the sightings, and none when the first
// run kept no memory.
TEST(SemanticModule, TheMapFileRemembersWhatItSawStanding) {
  const Frames& frames = planeFrames();
  const fs::path dir = fs::temp_directory_path() / ("stillpoint_sightings_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  for (const int first_run_sightings : {2, 0}) {
    SCOPED_TRACE("first run's static_memory_sightings " + std::to_string(first_run_sightings));
    SlamOptions options = semanticOptions();
    options.semantic.static_memory_span_s = 0.15;  // the run is 1 s long
    options.semantic.static_memory_sightings = first_run_sightings;
    const std::string path = (dir / ("plane" + std::to_string(first_run_sightings) + ".map")).string();
    {
      auto first = SlamSystem::create(frames.camera, options, std::make_unique<RelabellingSegmenter>(kRect, 1000));
      ASSERT_TRUE(first.ok()) << first.error();
      for (const RgbdInput& input : frames.inputs) ASSERT_TRUE((*first)->track(input).ok());
      (*first)->finish();
      ASSERT_GE((*first)->mapStats().semantic_keyframes_segmented, 3);
      ASSERT_TRUE((*first)->saveMap(path).ok());
    }
    options.semantic.static_memory_sightings = 2;
    options.localisation = true;
    auto second = SlamSystem::create(frames.camera, options, std::make_unique<RelabellingSegmenter>(kRect, 0));
    ASSERT_TRUE(second.ok()) << second.error();
    const Status loaded = (*second)->loadMap(path);
    ASSERT_TRUE(loaded.ok()) << loaded.error();
    for (const RgbdInput& input : frames.inputs) {
      const auto out = (*second)->track(input);
      ASSERT_TRUE(out.ok()) << out.error();
      EXPECT_TRUE(hasPose(out->state));
    }
    (*second)->finish();
    const MapStats stats = (*second)->mapStats();
    ASSERT_GT(stats.semantic_frames_segmented, static_cast<int>(frames.inputs.size()) / 2);
    EXPECT_EQ(stats.semantic_keyframes_segmented, 0);
    if (first_run_sightings > 0) {
      EXPECT_GT(stats.semantic_sighting_cells, 0u);
      // All but the first few: what those show of the plane, the first run
      // saw over less than the span.
      EXPECT_GE(stats.semantic_frame_regions_known_static * 3, stats.semantic_frames_segmented * 2);
    } else {
      EXPECT_EQ(stats.semantic_frame_regions_known_static, 0);
      EXPECT_EQ(stats.semantic_sighting_cells, 0u);
    }
  }
  fs::remove_all(dir);
}

// The teddy bear labelled a person: a region most of whose features lie where
// earlier keyframes saw a static object (and no motion) is left alone; with
// the memory off, the same detections take the features out.
// The plane run with the map's memory of what stands (`sightings`, 0 off),
// the first 3 keyframes segmented as a static object and `rect` labelled a
// person after them.
RunResult relabelledRun(int sightings, const cv::Rect& rect) {
  SlamOptions options = semanticOptions();
  options.semantic.static_memory_sightings = sightings;
  options.semantic.static_memory_span_s = 0.15;  // the run is 1 s long
  options.keyframes.tracked_ratio = 0.9;         // more keyframes than the plane needs, to be segmented
  return runWith(options, std::make_unique<RelabellingSegmenter>(rect, 3));
}

TEST(SemanticModule, AStaticObjectRelabelledMovableIsLeftAlone) {
  for (const int sightings : {2, 0}) {
    SCOPED_TRACE("static_memory_sightings " + std::to_string(sightings));
    // Sightings count where the geometry module judged the feature, which it
    // does not on the first frame: the first 3 keyframes give the middle of
    // the view 2 sightings.
    const RunResult run = relabelledRun(sightings, kRect);
    ASSERT_GE(run.stats.semantic_keyframes_segmented, 5);
    const int relabelled = run.stats.semantic_keyframes_segmented - 3;
    if (sightings > 0) {
      EXPECT_EQ(run.stats.semantic_instances_known_static, relabelled);
      EXPECT_EQ(run.stats.semantic_instances_applied, 0);
      EXPECT_EQ(run.stats.semantic_features_removed, 0);
    } else {
      EXPECT_EQ(run.stats.semantic_instances_known_static, 0);
      EXPECT_EQ(run.stats.semantic_instances_applied, relabelled);
      EXPECT_GT(run.stats.semantic_features_removed, 20 * relabelled);
    }
  }
}

// A person's mask spilling over a place the map has seen standing (the teddy
// bear beside a person): the region is applied, but its features on that
// place keep their map points and stay in the pose; with the memory off the
// whole region is taken out. The first 3 keyframes see the whole plane as a
// static object; then a "person" holds the right of the view, where the
// camera's motion brings in ground no keyframe saw standing.
TEST(SemanticModule, AMaskLeavesThePlacesSeenStandingInThePose) {
  const cv::Rect right(320, 0, 320, 480);
  for (const int sightings : {2, 0}) {
    SCOPED_TRACE("static_memory_sightings " + std::to_string(sightings));
    const RunResult run = relabelledRun(sightings, right);
    ASSERT_GE(run.stats.semantic_keyframes_segmented, 8);
    std::vector<KeyFrameView> keyframes = run.keyframes;
    std::sort(keyframes.begin(), keyframes.end(), [](const auto& a, const auto& b) { return a.id < b.id; });
    // In the keyframes whose "person" region was applied (features in it
    // dropped): its features that kept their point.
    int applied = 0, kept = 0, dropped = 0;
    for (std::size_t k = 3; k < keyframes.size(); ++k) {
      const KeyFrameView& kf = keyframes[k];
      if (!kf.segmented || kf.bad) continue;
      int in_kept = 0, in_dropped = 0;
      for (const KeyFrameFeature& f : kf.features) {
        if (!inside(f, right, 10)) continue;
        in_kept += f.mapped && !f.dynamic;
        in_dropped += f.dynamic;
      }
      if (in_dropped == 0) continue;
      ++applied;
      kept += in_kept;
      dropped += in_dropped;
    }
    ASSERT_GT(applied, 0);
    EXPECT_GT(dropped, 20 * applied);
    if (sightings > 0) {
      EXPECT_GT(kept, 20) << "of " << kept + dropped << " features in " << applied << " applied regions";
      EXPECT_GE(run.stats.semantic_features_on_standing, kept);
    } else {
      EXPECT_EQ(kept, 0);
      EXPECT_EQ(run.stats.semantic_features_on_standing, 0);
    }
  }
}

TEST(SemanticModule, FramesWithoutColourAreTrackedButNotSegmented) {
  const RunResult run = runWith(semanticOptions(), std::make_unique<RectangleSegmenter>(kRect, false), false);
  ASSERT_EQ(run.trajectory.size(), planeFrames().inputs.size());
  EXPECT_EQ(run.stats.semantic_keyframes_segmented, 0);
  EXPECT_EQ(run.stats.semantic_keyframes_no_colour, static_cast<int>(run.keyframes.size()));
  for (const KeyFrameView& kf : run.keyframes) EXPECT_FALSE(kf.segmented);
}

TEST(SemanticModule, BadColourImageIsAnError) {
  const Frames& frames = planeFrames();
  auto system = SlamSystem::create(frames.camera, semanticOptions(), std::make_unique<RectangleSegmenter>(kRect, false));
  ASSERT_TRUE(system.ok()) << system.error();
  RgbdInput input = frames.inputs[0];
  input.bgr = frames.inputs[0].gray;  // one channel
  const auto grey = (*system)->track(input);
  ASSERT_FALSE(grey.ok());
  EXPECT_TRUE(contains(grey.error(), "colour"));
  cv::resize(frames.inputs[0].bgr, input.bgr, frames.inputs[0].bgr.size() / 2);
  const auto small = (*system)->track(input);
  ASSERT_FALSE(small.ok());
  EXPECT_TRUE(contains(small.error(), "colour"));
}

TEST(SemanticModule, BadModelIsAnErrorAtCreate) {
  const CameraModel camera = planeFrames().camera;
  SlamOptions options = semanticOptions();
  options.semantic.model_card = "/nonexistent/card.yaml";
  const auto missing_card = SlamSystem::create(camera, options);
  ASSERT_FALSE(missing_card.ok());
  EXPECT_TRUE(contains(missing_card.error(), "semantic.model_card"));
  EXPECT_TRUE(contains(missing_card.error(), "/nonexistent/card.yaml"));

  // A valid card whose model file does not exist.
  const fs::path dir = fs::temp_directory_path() / ("stillpoint_semantic_card_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  fs::copy_file(semantic::defaultModelCardDir() / semantic::kPersonCardFile, dir / "card.yaml",
                fs::copy_options::overwrite_existing);
  options.semantic.model_card = (dir / "card.yaml").string();
  const auto missing_model = SlamSystem::create(camera, options);
  ASSERT_FALSE(missing_model.ok());
  EXPECT_TRUE(contains(missing_model.error(), "person_selfie_256.onnx"));

  // A model file that is not a network.
  std::ofstream(dir / "person_selfie_256.onnx") << "not an onnx file";
  const auto corrupt = SlamSystem::create(camera, options);
  ASSERT_FALSE(corrupt.ok());
  EXPECT_TRUE(contains(corrupt.error(), "card.yaml"));
  fs::remove_all(dir);

  options.semantic.model_card = "";
  options.semantic.queue_capacity = 0;
  const auto bad_option = SlamSystem::create(camera, options);
  ASSERT_FALSE(bad_option.ok());
  EXPECT_TRUE(contains(bad_option.error(), "semantic.queue_capacity"));
}

TEST(SemanticModule, DilationGrowsTheMaskByItsRadius) {
  semantic::Segmentation seg;
  seg.movable_mask = cv::Mat(100, 100, CV_8U, cv::Scalar(0));
  semantic::Instance inst;
  inst.box = cv::Rect(40, 40, 10, 10);
  inst.mask = cv::Mat(10, 10, CV_8U, cv::Scalar(255));
  inst.area = 100;
  inst.movable = true;
  seg.instances.push_back(inst);
  inst.movable = false;  // a static instance is never painted
  inst.box = cv::Rect(0, 0, 10, 10);
  seg.instances.push_back(inst);
  SemanticResult r;
  buildRegions(seg, 5, 0.5, &r);
  ASSERT_EQ(r.regions.size(), 1u);
  EXPECT_EQ(r.labels.at<std::uint8_t>(45, 35), 1);  // 5 px left of the box
  EXPECT_EQ(r.labels.at<std::uint8_t>(45, 34), 0);
  EXPECT_EQ(r.labels.at<std::uint8_t>(5, 5), 0);
}


// The real excerpt (../shared/data), and its frames [first, last).
fs::path realExcerpt() { return fs::path(STILLPOINT_DATA_DIR) / "tum_fr3_teddy_200"; }

Frames realFrames(std::size_t first, std::size_t last) {
  Frames out;
  auto camera = loadCamera("fr3");
  EXPECT_TRUE(camera.ok()) << camera.error();
  if (!camera.ok()) return out;
  out.camera = *camera;
  dataset::DatasetOptions dopts;
  dopts.depth_factor = camera->depth_factor;
  const auto tum = dataset::TumDataset::open(realExcerpt().string(), dopts);
  EXPECT_TRUE(tum.ok()) << tum.error();
  for (std::size_t i = first; tum.ok() && i < last && i < tum->size(); ++i) {
    const auto f = tum->load(i);
    EXPECT_TRUE(f.ok()) << f.error();
    if (f.ok()) out.inputs.push_back({f->stamp, f->gray, f->depth_m, f->bgr});
  }
  return out;
}

// keyframes.min_interval_frames (stillpoint-replay --keyframe-spacing): a
// sequential run, whose local mapping is always free, makes its keyframes as
// far apart as a live run's busy mapper does (40 real frames, the camera
// moving on: a keyframe every frame or two otherwise).
TEST(SemanticModule, KeyframeSpacingHoldsSequentialKeyframesApart) {
  if (!fs::is_directory(realExcerpt())) GTEST_SKIP() << realExcerpt() << " not found";
  const Frames real = realFrames(40, 80);
  ASSERT_EQ(real.inputs.size(), 40u);
  const CameraModel* camera = &real.camera;
  const std::vector<RgbdInput>& inputs = real.inputs;
  auto keyframeIndices = [&](int spacing) {
    SlamOptions options;
    options.sequential = true;
    options.geometry.enabled = false;
    options.mapping.keep_culled_keyframes = true;
    options.keyframes.min_interval_frames = spacing;
    std::vector<int> frames;
    auto system = SlamSystem::create(*camera, options);
    EXPECT_TRUE(system.ok()) << system.error();
    if (!system.ok()) return frames;
    for (const RgbdInput& in : inputs) EXPECT_TRUE((*system)->track(in).ok());
    (*system)->finish();
    for (const KeyFrameView& kf : (*system)->keyframes())
      for (std::size_t k = 0; k < inputs.size(); ++k)
        if (inputs[k].stamp == kf.stamp) frames.push_back(static_cast<int>(k));
    std::sort(frames.begin(), frames.end());
    return frames;
  };
  const std::vector<int> every = keyframeIndices(0), spaced = keyframeIndices(3);
  std::printf("keyframes in %zu frames: %zu, at least 3 frames apart %zu\n", inputs.size(), every.size(),
              spaced.size());
  ASSERT_GE(spaced.size(), 5u);
  EXPECT_LT(spaced.size(), every.size());
  EXPECT_TRUE(std::adjacent_find(every.begin(), every.end(), [](int a, int b) { return b - a < 3; }) != every.end())
      << "without the spacing, some keyframes come closer than 3 frames";
  for (std::size_t k = 1; k < spaced.size(); ++k) EXPECT_GE(spaced[k] - spaced[k - 1], 3) << "frame " << spaced[k];
}

// The real in-tree person model on real TUM frames: it takes the teddy bear
// for a person (lib/semantic/README.md). Its card asks for the geometry
// module's agreement, so with geometry off nothing is removed; with the
// confirmation overridden, the keyframe's features inside the model's own
// mask lose their map points.
TEST(SemanticModule, PersonModelOnRealFrames) {
  if (!fs::is_directory(realExcerpt())) GTEST_SKIP() << realExcerpt() << " not found";
  const Frames real = realFrames(20, 30);  // person-free frames
  ASSERT_EQ(real.inputs.size(), 10u);
  const CameraModel* camera = &real.camera;
  const std::vector<RgbdInput>& inputs = real.inputs;
  auto track = [&](const SlamOptions& options) {
    auto system = SlamSystem::create(*camera, options);
    EXPECT_TRUE(system.ok()) << system.error();
    RunResult run;
    if (!system.ok()) return run;
    for (const RgbdInput& in : inputs) EXPECT_TRUE((*system)->track(in).ok());
    (*system)->finish();
    run.keyframes = (*system)->keyframes();
    run.stats = (*system)->mapStats();
    return run;
  };
  SlamOptions options;
  options.sequential = true;
  options.semantic.enabled = true;
  options.semantic.model_card = semantic::kPersonCardFile;
  const RunResult guarded = track(options);
  EXPECT_EQ(guarded.stats.semantic_model.rfind("person_selfie_256", 0), 0u) << guarded.stats.semantic_model;
  ASSERT_GE(guarded.stats.semantic_keyframes_segmented, 1);
  EXPECT_GE(guarded.stats.semantic_instances_unconfirmed, 1);
  EXPECT_EQ(guarded.stats.semantic_features_removed, 0);

  options.semantic.confirm_with_geometry = "never";
  options.semantic.max_removed_fraction = 1.0;
  const RunResult unguarded = track(options);
  ASSERT_GE(unguarded.stats.semantic_keyframes_segmented, 1);
  EXPECT_GT(unguarded.stats.semantic_features_removed, 50);
  // Keyframe 0 against the model's own mask of the same image.
  auto segmenter = semantic::createSegmenter(semantic::defaultModelCardDir() / semantic::kPersonCardFile);
  ASSERT_TRUE(segmenter.ok()) << segmenter.error();
  auto seg = (*segmenter)->segment(inputs[0].bgr);
  ASSERT_TRUE(seg.ok()) << seg.error();
  ASSERT_GT(seg->movableFraction(), 0.05);  // the bear
  int in_mask = 0;
  for (const KeyFrameFeature& f : unguarded.keyframes.at(0).features) {
    if (seg->movable_mask.at<std::uint8_t>(cvRound(f.v), cvRound(f.u)) == 0) continue;
    ++in_mask;
  }
  EXPECT_GT(in_mask, 20);
  // Depth agreement may trim the mask where depth disagrees; count well inside it.
  cv::Mat core;
  cv::erode(seg->movable_mask, core, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(31, 31)));
  int core_features = 0, core_mapped = 0;
  for (const KeyFrameFeature& f : unguarded.keyframes.at(0).features) {
    if (core.at<std::uint8_t>(cvRound(f.v), cvRound(f.u)) == 0) continue;
    ++core_features;
    core_mapped += f.mapped;
  }
  std::printf("person model, keyframe 0: %d features deep inside its mask, %d still mapped\n", core_features,
              core_mapped);
  EXPECT_GT(core_features, 10);
  EXPECT_LE(core_mapped, core_features / 10);  // depth agreement may cut a few
}

}  // namespace
}  // namespace stillpoint::slam
