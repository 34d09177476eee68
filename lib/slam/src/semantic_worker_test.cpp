// The semantic module's parts without SlamSystem: its options (range checks,
// YAML) and the SemanticWorker (drop-oldest queue, detector hysteresis).
#include <gtest/gtest.h>
#include <unistd.h>

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

#include "semantic_worker.hpp"
#include "stillpoint/dataset/testing.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/semantic/segmenter.hpp"
#include "stillpoint/slam/system.hpp"
#include "test_helpers.hpp"
#include "semantic_test_doubles.hpp"

namespace stillpoint::slam {
namespace {

namespace fs = std::filesystem;
using testing::contains;

TEST(SemanticOptions, EachOutOfRangeValueNamesItsField) {
  const std::vector<std::pair<const char*, std::function<void(SemanticOptions&)>>> cases = {
      {"semantic.mask_dilation_px", [](SemanticOptions& o) { o.mask_dilation_px = -1; }},
      {"semantic.queue_capacity", [](SemanticOptions& o) { o.queue_capacity = 0; }},
      {"semantic.sequential_latency_frames", [](SemanticOptions& o) { o.sequential_latency_frames = -1; }},
      {"semantic.threads", [](SemanticOptions& o) { o.threads = -1; }},
      {"semantic.min_region_fraction", [](SemanticOptions& o) { o.min_region_fraction = 1; }},
      {"semantic.min_region_confidence", [](SemanticOptions& o) { o.min_region_confidence = 2; }},
      {"semantic.static_overlap_iou", [](SemanticOptions& o) { o.static_overlap_iou = -0.1; }},
      {"semantic.confirm_with_geometry", [](SemanticOptions& o) { o.confirm_with_geometry = "sometimes"; }},
      {"semantic.confirm_min_flagged", [](SemanticOptions& o) { o.confirm_min_flagged = 0; }},
      {"semantic.confirm_ratio", [](SemanticOptions& o) { o.confirm_ratio = std::nan(""); }},
      {"semantic.max_removed_fraction", [](SemanticOptions& o) { o.max_removed_fraction = 1.5; }},
      {"semantic.min_kept_points", [](SemanticOptions& o) { o.min_kept_points = -1; }},
      {"semantic.other_motion_share", [](SemanticOptions& o) { o.other_motion_share = -0.1; }},
      {"semantic.point_masked_ratio", [](SemanticOptions& o) { o.point_masked_ratio = 1; }},
      {"semantic.propagate_grow_px", [](SemanticOptions& o) { o.propagate_grow_px = -1; }},
      {"semantic.propagate_grow_passes", [](SemanticOptions& o) { o.propagate_grow_passes = 0; }},
      {"semantic.track_score_ratio", [](SemanticOptions& o) { o.track_score_ratio = 1.5; }},
      {"semantic.track_iou", [](SemanticOptions& o) { o.track_iou = 0; }},
      {"semantic.track_max_keyframes", [](SemanticOptions& o) { o.track_max_keyframes = 0; }},
      {"semantic.track_min_hits", [](SemanticOptions& o) { o.track_min_hits = 0; }},
      {"semantic.temp_exclusion_px", [](SemanticOptions& o) { o.temp_exclusion_px = -1; }},
      {"semantic.model_dirs", [](SemanticOptions& o) { o.model_dirs = {""}; }},
  };
  for (const auto& [field, spoil] : cases) {
    SCOPED_TRACE(field);
    SlamOptions o;
    spoil(o.semantic);
    const Status s = o.validate();
    ASSERT_FALSE(s.ok());
    EXPECT_TRUE(contains(s.error(), field));
  }
}

TEST(SemanticOptions, YamlRoundTrip) {
  SlamOptions o;
  o.semantic.enabled = true;
  o.semantic.model_card = "cards/my card.yaml";
  o.semantic.model_dirs = {"/opt/models", "relative/dir"};
  o.semantic.movable_furniture = true;
  o.semantic.mask_dilation_px = 9;
  o.semantic.queue_capacity = 3;
  o.semantic.threads = 2;
  o.semantic.confirm_with_geometry = "always";
  const fs::path file = fs::temp_directory_path() / ("stillpoint_semantic_options_" + std::to_string(::getpid()) + ".yaml");
  std::ofstream(file) << toYaml(o);
  const auto loaded = loadSlamOptions(file.string());
  fs::remove(file);
  ASSERT_TRUE(loaded.ok()) << loaded.error();
  EXPECT_EQ(toYaml(*loaded), toYaml(o));
  EXPECT_EQ(loaded->semantic.model_dirs, o.semantic.model_dirs);
  EXPECT_EQ(loaded->semantic.confirm_with_geometry, "always");
}

TEST(SemanticWorker, DropsTheOldestJobWhenFull) {
  std::vector<std::int64_t> done;
  SemanticOptions options;
  options.queue_capacity = 2;
  SemanticWorker worker(std::make_unique<RectangleSegmenter>(kRect, false), options,
                        [&](SemanticResult r) { done.push_back(r.keyframe_id); });
  const cv::Mat bgr(200, 300, CV_8UC3, cv::Scalar(1, 2, 3));
  // Not started: jobs wait; the third pushes the first out.
  for (std::int64_t id = 0; id < 3; ++id) worker.submit({id, bgr, cv::Mat(), std::chrono::steady_clock::now()});
  EXPECT_EQ(worker.dropped(), 1);
  worker.start();
  worker.finish();  // segments what is queued
  EXPECT_EQ(done, (std::vector<std::int64_t>{1, 2}));
  // process() without a thread: the dilated rectangle, clipped to the image.
  const SemanticResult r = worker.process({7, bgr, cv::Mat(), std::chrono::steady_clock::now()});
  ASSERT_TRUE(r.ok) << r.error;
  ASSERT_EQ(r.regions.size(), 1u);
  EXPECT_EQ(r.labels.at<std::uint8_t>(199, 150), 1);  // clipped at the bottom
  EXPECT_EQ(r.labels.at<std::uint8_t>(150, 35), 1);   // dilated by 5 px
  EXPECT_EQ(r.labels.at<std::uint8_t>(150, 34), 0);
  const SemanticResult bad = worker.process({8, cv::Mat(), cv::Mat(), std::chrono::steady_clock::now()});
  EXPECT_FALSE(bad.ok);
}

// Detector hysteresis: a keyframe's instance is kept at a lower score (or
// under another label) only where the previous keyframe kept one.
semantic::Instance boxInstance(int class_id, const std::string& name, float score, cv::Rect box, bool movable,
                               bool kept = true, const std::string& drop_reason = "") {
  semantic::Instance inst;
  inst.class_id = class_id;
  inst.class_name = name;
  inst.score = score;
  inst.box = box;
  inst.mask = cv::Mat(box.size(), CV_8U, cv::Scalar(255));
  inst.area = box.area();
  inst.movable = movable;
  inst.kept = kept;
  inst.drop_reason = drop_reason;
  return inst;
}

semantic::Segmentation segmentationOf(std::vector<semantic::Instance> instances) {
  semantic::Segmentation seg;
  seg.movable_mask = cv::Mat(200, 300, CV_8U, cv::Scalar(0));
  for (const semantic::Instance& inst : instances)
    if (inst.movable && inst.kept) seg.movable_mask(inst.box).setTo(255, inst.mask);
  seg.instances = std::move(instances);
  return seg;
}

TEST(SemanticWorker, HysteresisContinuesAWeakDetectionOfATrackOnly) {
  SemanticOptions o;
  o.track_score_ratio = 0.5;  // strong 0.25, weak 0.125
  o.track_iou = 0.3;
  o.track_max_keyframes = 2;
  const cv::Rect person(100, 50, 40, 100), moved(108, 52, 40, 100), elsewhere(10, 10, 40, 100);
  std::vector<SemanticTrack> tracks;
  // Keyframe 1: a weak person and no track: dropped.
  semantic::Segmentation seg = segmentationOf({boxInstance(0, "person", 0.2f, person, true)});
  EXPECT_EQ(continueTracks(o, 0.25, &seg, &tracks), 0);
  EXPECT_FALSE(seg.instances[0].kept);
  EXPECT_EQ(seg.movable_pixels, 0);
  EXPECT_TRUE(tracks.empty());
  // Keyframe 2: a strong person starts a track, but one strong keyframe is
  // not enough (track_min_hits 2): a weak person there is not carried on.
  seg = segmentationOf({boxInstance(0, "person", 0.8f, person, true)});
  EXPECT_EQ(continueTracks(o, 0.25, &seg, &tracks), 0);
  EXPECT_TRUE(seg.instances[0].kept);
  ASSERT_EQ(tracks.size(), 1u);
  EXPECT_EQ(tracks[0].hits, 1);
  std::vector<SemanticTrack> once = tracks;
  semantic::Segmentation weak = segmentationOf({boxInstance(0, "person", 0.2f, moved, true)});
  EXPECT_EQ(continueTracks(o, 0.25, &weak, &once), 0);
  EXPECT_FALSE(weak.instances[0].kept);
  // Keyframe 2b: seen strong again.
  seg = segmentationOf({boxInstance(0, "person", 0.7f, person, true)});
  EXPECT_EQ(continueTracks(o, 0.25, &seg, &tracks), 0);
  ASSERT_EQ(tracks.size(), 1u);
  EXPECT_EQ(tracks[0].hits, 2);
  // Keyframe 3: the person, moved a little, at 0.2 (and a weak one elsewhere,
  // and one below the weak score where it moved): the overlapping one is kept.
  seg = segmentationOf({boxInstance(0, "person", 0.2f, moved, true), boxInstance(0, "person", 0.2f, elsewhere, true)});
  EXPECT_EQ(continueTracks(o, 0.25, &seg, &tracks), 1);
  EXPECT_TRUE(seg.instances[0].kept);
  EXPECT_TRUE(seg.instances[0].continued);
  EXPECT_FALSE(seg.instances[1].kept);
  EXPECT_EQ(seg.movable_pixels, moved.area());
  ASSERT_EQ(tracks.size(), 1u);
  EXPECT_EQ(tracks[0].weak_keyframes, 1);
  // Keyframe 4: dropped by the post-filter as the same object as a static
  // label: continued too. A "teddy bear" on the same box is not, without
  // track_any_class.
  seg = segmentationOf({boxInstance(0, "person", 0.3f, moved, true, false, "same object as static 'teddy bear'"),
                        boxInstance(1, "teddy bear", 0.6f, person, false)});
  EXPECT_EQ(continueTracks(o, 0.25, &seg, &tracks), 1);
  EXPECT_TRUE(seg.instances[0].kept);
  EXPECT_FALSE(seg.instances[1].movable);
  EXPECT_EQ(tracks[0].weak_keyframes, 2);
  // Keyframe 5: track_max_keyframes weak keyframes in a row: the track ends.
  seg = segmentationOf({boxInstance(0, "person", 0.2f, moved, true)});
  EXPECT_EQ(continueTracks(o, 0.25, &seg, &tracks), 0);
  EXPECT_FALSE(seg.instances[0].kept);
  EXPECT_TRUE(tracks.empty());
  // Below the weak score nothing continues a track.
  tracks = {{person, 0, "person", 0, 2}};
  seg = segmentationOf({boxInstance(0, "person", 0.1f, moved, true)});
  EXPECT_EQ(continueTracks(o, 0.25, &seg, &tracks), 0);
  EXPECT_FALSE(seg.instances[0].kept);
}

// A track the person model beside the main one started hands its need for
// the geometry module's confirmation on to the weak detections continuing it.
TEST(SemanticWorker, ATrackOfTheSecondOpinionStaysOne) {
  SemanticOptions o;
  o.track_score_ratio = 0.5;
  o.track_iou = 0.3;
  const cv::Rect person(100, 50, 40, 100), moved(108, 52, 40, 100);
  std::vector<SemanticTrack> tracks;
  for (int k = 0; k < 2; ++k) {
    semantic::Segmentation seg = segmentationOf({boxInstance(0, "person", 0.95f, person, true)});
    seg.instances[0].second_opinion = true;
    EXPECT_EQ(continueTracks(o, 0.25, &seg, &tracks), 0);
  }
  ASSERT_EQ(tracks.size(), 1u);
  EXPECT_TRUE(tracks[0].second_opinion);
  semantic::Segmentation seg = segmentationOf({boxInstance(0, "person", 0.2f, moved, true)});
  EXPECT_EQ(continueTracks(o, 0.25, &seg, &tracks), 1);
  EXPECT_TRUE(seg.instances[0].kept);
  EXPECT_TRUE(seg.instances[0].second_opinion);
  ASSERT_EQ(tracks.size(), 1u);
  EXPECT_TRUE(tracks[0].second_opinion);
  // The main model's own strong detection starts a track of its own.
  seg = segmentationOf({boxInstance(0, "person", 0.8f, moved, true)});
  EXPECT_EQ(continueTracks(o, 0.25, &seg, &tracks), 0);
  ASSERT_EQ(tracks.size(), 1u);
  EXPECT_FALSE(tracks[0].second_opinion);
}

TEST(SemanticWorker, HysteresisAcrossLabelsNeedsTheTracksOwnBox) {
  SemanticOptions o;
  o.track_score_ratio = 0.5;
  o.track_any_class = true;
  const cv::Rect person(100, 50, 40, 100), bear_behind(95, 45, 60, 120);
  // The person seen as "teddy bear" on nearly its own box: continued, as a person.
  std::vector<SemanticTrack> tracks = {{person, 0, "person", 0, 2}};
  semantic::Segmentation seg = segmentationOf({boxInstance(1, "teddy bear", 0.5f, cv::Rect(102, 50, 40, 100), false)});
  EXPECT_EQ(continueTracks(o, 0.25, &seg, &tracks), 1);
  EXPECT_TRUE(seg.instances[0].movable);
  EXPECT_TRUE(seg.instances[0].kept);
  EXPECT_EQ(seg.instances[0].class_id, 0);
  // A larger static object behind it (box IoU 0.56: enough for the same
  // class at track_iou 0.3, below the 0.6 another label needs): not continued.
  tracks = {{person, 0, "person", 0, 2}};
  seg = segmentationOf({boxInstance(1, "teddy bear", 0.8f, bear_behind, false)});
  EXPECT_EQ(continueTracks(o, 0.25, &seg, &tracks), 0);
  EXPECT_FALSE(seg.instances[0].movable);
  EXPECT_EQ(seg.movable_pixels, 0);
}

}  // namespace
}  // namespace stillpoint::slam
