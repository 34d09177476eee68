// SlamOptions: range checks that name the field, and the YAML file format
// (round trip, unknown keys, wrong types, empty file).
#include "stillpoint/slam/options.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "test_helpers.hpp"

namespace stillpoint::slam {
namespace {

namespace fs = std::filesystem;

using testing::contains;

// Every test writes its YAML into its own temporary folder.
class OptionsFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() /
           ("stillpoint_options_test_" + std::to_string(::getpid()) + "_" + info->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string write(const std::string& text) {
    const fs::path path = dir_ / "slam.yaml";
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out << text;
    return path.string();
  }

  fs::path dir_;
};

TEST(SlamOptionsValidate, DefaultsAreValid) {
  const SlamOptions defaults;
  EXPECT_TRUE(defaults.orb.validate().ok()) << defaults.orb.validate().error();
  EXPECT_TRUE(defaults.tracking.validate().ok()) << defaults.tracking.validate().error();
  EXPECT_TRUE(defaults.keyframes.validate().ok()) << defaults.keyframes.validate().error();
  EXPECT_TRUE(defaults.mapping.validate().ok()) << defaults.mapping.validate().error();
  EXPECT_TRUE(defaults.validate().ok()) << defaults.validate().error();
}

struct BadValue {
  const char* field;  // the name the error must contain
  std::function<void(SlamOptions&)> spoil;
};

// One out-of-range value per check; each must fail both its own struct's
// validate() and SlamOptions::validate(), naming the field.
TEST(SlamOptionsValidate, EachOutOfRangeValueNamesItsField) {
  const std::vector<BadValue> cases = {
      {"orb.num_features", [](SlamOptions& o) { o.orb.num_features = 10; }},
      {"orb.num_levels", [](SlamOptions& o) { o.orb.num_levels = 0; }},
      {"orb.scale_factor", [](SlamOptions& o) { o.orb.scale_factor = 1.0; }},
      {"orb.fast_threshold", [](SlamOptions& o) { o.orb.fast_threshold = 0; }},
      {"orb.min_fast_threshold", [](SlamOptions& o) { o.orb.min_fast_threshold = o.orb.fast_threshold + 1; }},
      {"orb.cell_size", [](SlamOptions& o) { o.orb.cell_size = 4; }},
      {"tracking.min_init_features", [](SlamOptions& o) { o.tracking.min_init_features = 19; }},
      {"tracking.min_inliers_local_map", [](SlamOptions& o) { o.tracking.min_inliers_local_map = 5; }},
      {"tracking.min_inliers_after_reloc", [](SlamOptions& o) { o.tracking.min_inliers_after_reloc = 10; }},
      {"tracking.close_depth_baselines", [](SlamOptions& o) { o.tracking.close_depth_baselines = 0; }},
      {"tracking.local_keyframes_max", [](SlamOptions& o) { o.tracking.local_keyframes_max = 0; }},
      {"tracking.relocalisation_candidates", [](SlamOptions& o) { o.tracking.relocalisation_candidates = 0; }},
      {"tracking.trajectory_records", [](SlamOptions& o) { o.tracking.trajectory_records = -2; }},
      {"tracking.mover_cells_every", [](SlamOptions& o) { o.tracking.mover_cells_every = 0; }},
      {"tracking.mover_cells_min_share", [](SlamOptions& o) { o.tracking.mover_cells_min_share = 1.5; }},
      {"tracking.mover_cells_radius_px", [](SlamOptions& o) { o.tracking.mover_cells_radius_px = 0; }},
      {"keyframes.max_interval_s", [](SlamOptions& o) { o.keyframes.max_interval_s = -1; }},
      {"keyframes.min_interval_frames", [](SlamOptions& o) { o.keyframes.min_interval_frames = -1; }},
      {"keyframes.tracked_ratio", [](SlamOptions& o) { o.keyframes.tracked_ratio = 1.5; }},
      {"keyframes.close_tracked_min", [](SlamOptions& o) { o.keyframes.close_tracked_min = -1; }},
      {"keyframes.close_untracked_min", [](SlamOptions& o) { o.keyframes.close_untracked_min = -1; }},
      {"keyframes.min_new_points", [](SlamOptions& o) { o.keyframes.min_new_points = -1; }},
      {"mapping.ba_iterations", [](SlamOptions& o) { o.mapping.ba_iterations = 0; }},
      {"mapping.ba_max_keyframes", [](SlamOptions& o) { o.mapping.ba_max_keyframes = 1; }},
      {"mapping.redundant_ratio", [](SlamOptions& o) { o.mapping.redundant_ratio = 0; }},
      {"mapping.redundant_min_observers", [](SlamOptions& o) { o.mapping.redundant_min_observers = 0; }},
      {"mapping.point_found_ratio", [](SlamOptions& o) { o.mapping.point_found_ratio = 1; }},
  };
  for (const BadValue& c : cases) {
    SCOPED_TRACE(c.field);
    SlamOptions o;
    c.spoil(o);
    const std::string section = std::string(c.field).substr(0, std::string(c.field).find('.'));
    const Status own = section == "orb"        ? o.orb.validate()
                       : section == "tracking" ? o.tracking.validate()
                       : section == "keyframes" ? o.keyframes.validate()
                                                : o.mapping.validate();
    ASSERT_FALSE(own.ok());
    EXPECT_TRUE(contains(own.error(), c.field));
    const Status whole = o.validate();
    ASSERT_FALSE(whole.ok());
    EXPECT_TRUE(contains(whole.error(), c.field));
  }
}

// Each case spoils one geometry field: geometry.validate() and the whole
// options' validate() reject it, and the geometry error names the field.
void expectGeometryErrorsNameTheirFields(const std::vector<BadValue>& cases) {
  for (const BadValue& c : cases) {
    SCOPED_TRACE(c.field);
    SlamOptions o;
    c.spoil(o);
    const Status own = o.geometry.validate();
    ASSERT_FALSE(own.ok());
    EXPECT_TRUE(contains(own.error(), c.field));
    ASSERT_FALSE(o.validate().ok());
  }
}

TEST(SlamOptionsValidate, FrameSigmaFieldsNameThemselves) {
  const std::vector<BadValue> cases = {
  };
  expectGeometryErrorsNameTheirFields(cases);
}

TEST(SlamOptionsValidate, FreeSpaceFieldsNameThemselves) {
  const std::vector<BadValue> cases = {
      {"geometry.freespace_flag", [](SlamOptions& o) { o.geometry.freespace_flag = 1.5; }},
      {"geometry.freespace_tolerance_m", [](SlamOptions& o) { o.geometry.freespace_tolerance_m = -0.1; }},
      {"geometry.freespace_split_keep", [](SlamOptions& o) { o.geometry.freespace_split_keep = -1; }},
      {"geometry.freespace_split_min_samples", [](SlamOptions& o) { o.geometry.freespace_split_min_samples = 0; }},
      {"geometry.freespace_split_radius_m", [](SlamOptions& o) { o.geometry.freespace_split_radius_m = -1; }},
      {"geometry.freespace_grow_angle_deg", [](SlamOptions& o) { o.geometry.freespace_grow_angle_deg = 95; }},
      {"geometry.freespace_frames", [](SlamOptions& o) { o.geometry.freespace_frames = 0; }},
      {"geometry.carried_frames", [](SlamOptions& o) { o.geometry.carried_frames = 0; }},
      {"geometry.near_anchor_frames", [](SlamOptions& o) { o.geometry.near_anchor_frames = 1; }},
      {"geometry.near_anchor_frames", [](SlamOptions& o) { o.geometry.near_anchor_frames = 31; }},
      {"geometry.lone_moving_chi2", [](SlamOptions& o) { o.geometry.lone_moving_chi2 = -1; }},
      {"geometry.consensus_ratio", [](SlamOptions& o) { o.geometry.consensus_ratio = 1.5; }},
      {"geometry.consensus_ratio", [](SlamOptions& o) { o.geometry.consensus_ratio = -0.1; }},
      {"geometry.consensus_samples", [](SlamOptions& o) { o.geometry.consensus_samples = 0; }},
      {"geometry.evidence_depth_max_m", [](SlamOptions& o) { o.geometry.evidence_depth_max_m = -1; }},
      {"geometry.static_match_margin", [](SlamOptions& o) { o.geometry.static_match_margin = 300; }},
      {"geometry.photo_release_ncc", [](SlamOptions& o) { o.geometry.photo_release_ncc = 1.5; }},
      {"geometry.photo_depth_share", [](SlamOptions& o) { o.geometry.photo_depth_share = -0.1; }},
      {"geometry.photo_patch_radius", [](SlamOptions& o) { o.geometry.photo_patch_radius = 0; }},
      {"geometry.photo_frames", [](SlamOptions& o) { o.geometry.photo_frames = 4; }},
      {"geometry.photo_one_ncc", [](SlamOptions& o) { o.geometry.photo_one_ncc = -0.1; }},
      {"geometry.photo_one_others", [](SlamOptions& o) { o.geometry.photo_one_others = 1.2; }},
      {"geometry.photo_detect_share", [](SlamOptions& o) { o.geometry.photo_detect_share = 1.0; }},
      {"geometry.photo_detect_min", [](SlamOptions& o) { o.geometry.photo_detect_min = 0; }},
      {"geometry.photo_detect_gate", [](SlamOptions& o) { o.geometry.photo_detect_gate = -1; }},
      {"geometry.photo_frames_back", [](SlamOptions& o) { o.geometry.photo_frames_back = 0; }},
  };
  expectGeometryErrorsNameTheirFields(cases);
}

TEST(SlamOptionsValidate, NonFiniteValuesAreRejected) {
  SlamOptions o;
  o.keyframes.tracked_ratio = std::nan("");
  EXPECT_FALSE(o.validate().ok());
  o = SlamOptions{};
  o.tracking.close_depth_baselines = std::nan("");
  EXPECT_FALSE(o.validate().ok());
}

// Every field of `o` set away from its default (and still valid).
SlamOptions everythingChanged() {
  SlamOptions o;
  o.orb.num_features = 1500;
  o.orb.num_levels = 6;
  o.orb.scale_factor = 1.15;
  o.orb.fast_threshold = 25;
  o.orb.min_fast_threshold = 9;
  o.orb.cell_size = 40;
  o.tracking.min_init_features = 250;
  o.tracking.min_inliers_local_map = 35;
  o.tracking.min_inliers_after_reloc = 60;
  o.tracking.close_depth_baselines = 37.5;
  o.tracking.local_keyframes_max = 45;
  o.tracking.relocalisation_candidates = 12;
  o.tracking.trajectory_records = 300;
  o.tracking.mover_cells_every = 3;
  o.tracking.mover_cells_min_share = 0.25;
  o.tracking.mover_cells_radius_px = 40;
  o.keyframes.max_interval_s = 0.75;
  o.keyframes.min_interval_frames = 3;
  o.keyframes.tracked_ratio = 0.55;
  o.keyframes.close_tracked_min = 90;
  o.keyframes.close_untracked_min = 65;
  o.keyframes.min_new_points = 80;
  o.mapping.local_ba = false;
  o.mapping.ba_iterations = 7;
  o.mapping.ba_max_keyframes = 15;
  o.mapping.redundant_ratio = 0.85;
  o.mapping.redundant_min_observers = 4;
  o.mapping.point_found_ratio = 0.3;
  o.mapping.keep_culled_keyframes = true;
  o.geometry.evidence_depth_max_m = 4.0;
  o.geometry.static_match_margin = -1;
  o.geometry.photo_release_ncc = 0.55;
  o.geometry.photo_depth_share = 0.75;
  o.geometry.photo_patch_radius = 6;
  o.geometry.photo_frames = 1;
  o.geometry.photo_release_memory = false;
  o.geometry.photo_release_anchored = false;
  o.geometry.photo_frames_back = 9;
  o.geometry.photo_fallback = false;
  o.geometry.freespace_frames = 9;
  o.geometry.freespace_flag = 0.35;
  o.geometry.freespace_tolerance_m = 0.05;
  o.geometry.freespace_tolerance_z2 = 0.01;
  o.geometry.freespace_split_keep = 0.7;
  o.geometry.freespace_split_min_samples = 6;
  o.geometry.freespace_split_radius_m = 0.15;
  o.geometry.freespace_split_protect_chi2 = 20;
  o.geometry.freespace_grow_plane_m = 0.03;
  o.geometry.freespace_grow_angle_deg = 40;
  o.geometry.carried_frames = 7;
  o.geometry.near_anchor_frames = 4;
  o.geometry.lone_moving_chi2 = 12.5;
  o.geometry.consensus_ratio = 0.75;
  o.geometry.consensus_samples = 100;
  o.sequential = true;
  return o;
}

void expectSameOptions(const SlamOptions& a, const SlamOptions& b) {
  EXPECT_EQ(a.orb.num_features, b.orb.num_features);
  EXPECT_EQ(a.orb.num_levels, b.orb.num_levels);
  EXPECT_EQ(a.orb.scale_factor, b.orb.scale_factor);
  EXPECT_EQ(a.orb.fast_threshold, b.orb.fast_threshold);
  EXPECT_EQ(a.orb.min_fast_threshold, b.orb.min_fast_threshold);
  EXPECT_EQ(a.orb.cell_size, b.orb.cell_size);
  EXPECT_EQ(a.tracking.min_init_features, b.tracking.min_init_features);
  EXPECT_EQ(a.tracking.min_inliers_local_map, b.tracking.min_inliers_local_map);
  EXPECT_EQ(a.tracking.min_inliers_after_reloc, b.tracking.min_inliers_after_reloc);
  EXPECT_EQ(a.tracking.close_depth_baselines, b.tracking.close_depth_baselines);
  EXPECT_EQ(a.tracking.local_keyframes_max, b.tracking.local_keyframes_max);
  EXPECT_EQ(a.tracking.relocalisation_candidates, b.tracking.relocalisation_candidates);
  EXPECT_EQ(a.tracking.trajectory_records, b.tracking.trajectory_records);
  EXPECT_EQ(a.keyframes.max_interval_s, b.keyframes.max_interval_s);
  EXPECT_EQ(a.keyframes.min_interval_frames, b.keyframes.min_interval_frames);
  EXPECT_EQ(a.tracking.mover_cells_every, b.tracking.mover_cells_every);
  EXPECT_EQ(a.tracking.mover_cells_min_share, b.tracking.mover_cells_min_share);
  EXPECT_EQ(a.tracking.mover_cells_radius_px, b.tracking.mover_cells_radius_px);
  EXPECT_EQ(a.keyframes.tracked_ratio, b.keyframes.tracked_ratio);
  EXPECT_EQ(a.keyframes.close_tracked_min, b.keyframes.close_tracked_min);
  EXPECT_EQ(a.keyframes.close_untracked_min, b.keyframes.close_untracked_min);
  EXPECT_EQ(a.keyframes.min_new_points, b.keyframes.min_new_points);
  EXPECT_EQ(a.mapping.local_ba, b.mapping.local_ba);
  EXPECT_EQ(a.mapping.ba_iterations, b.mapping.ba_iterations);
  EXPECT_EQ(a.mapping.ba_max_keyframes, b.mapping.ba_max_keyframes);
  EXPECT_EQ(a.mapping.redundant_ratio, b.mapping.redundant_ratio);
  EXPECT_EQ(a.mapping.redundant_min_observers, b.mapping.redundant_min_observers);
  EXPECT_EQ(a.mapping.point_found_ratio, b.mapping.point_found_ratio);
  EXPECT_EQ(a.mapping.keep_culled_keyframes, b.mapping.keep_culled_keyframes);
  EXPECT_EQ(a.geometry.evidence_depth_max_m, b.geometry.evidence_depth_max_m);
  EXPECT_EQ(a.geometry.static_match_margin, b.geometry.static_match_margin);
  EXPECT_EQ(a.geometry.photo_release_ncc, b.geometry.photo_release_ncc);
  EXPECT_EQ(a.geometry.photo_depth_share, b.geometry.photo_depth_share);
  EXPECT_EQ(a.geometry.photo_patch_radius, b.geometry.photo_patch_radius);
  EXPECT_EQ(a.geometry.photo_frames, b.geometry.photo_frames);
  EXPECT_EQ(a.geometry.photo_release_memory, b.geometry.photo_release_memory);
  EXPECT_EQ(a.geometry.photo_release_anchored, b.geometry.photo_release_anchored);
  EXPECT_EQ(a.geometry.photo_frames_back, b.geometry.photo_frames_back);
  EXPECT_EQ(a.geometry.photo_fallback, b.geometry.photo_fallback);
  EXPECT_EQ(a.geometry.freespace_frames, b.geometry.freespace_frames);
  EXPECT_EQ(a.geometry.freespace_flag, b.geometry.freespace_flag);
  EXPECT_EQ(a.geometry.freespace_tolerance_m, b.geometry.freespace_tolerance_m);
  EXPECT_EQ(a.geometry.freespace_tolerance_z2, b.geometry.freespace_tolerance_z2);
  EXPECT_EQ(a.geometry.freespace_split_keep, b.geometry.freespace_split_keep);
  EXPECT_EQ(a.geometry.freespace_split_min_samples, b.geometry.freespace_split_min_samples);
  EXPECT_EQ(a.geometry.freespace_split_radius_m, b.geometry.freespace_split_radius_m);
  EXPECT_EQ(a.geometry.freespace_split_protect_chi2, b.geometry.freespace_split_protect_chi2);
  EXPECT_EQ(a.geometry.freespace_grow_plane_m, b.geometry.freespace_grow_plane_m);
  EXPECT_EQ(a.geometry.freespace_grow_angle_deg, b.geometry.freespace_grow_angle_deg);
  EXPECT_EQ(a.geometry.carried_frames, b.geometry.carried_frames);
  EXPECT_EQ(a.geometry.near_anchor_frames, b.geometry.near_anchor_frames);
  EXPECT_EQ(a.geometry.lone_moving_chi2, b.geometry.lone_moving_chi2);
  EXPECT_EQ(a.geometry.consensus_ratio, b.geometry.consensus_ratio);
  EXPECT_EQ(a.geometry.consensus_samples, b.geometry.consensus_samples);
  EXPECT_EQ(a.sequential, b.sequential);
}

TEST_F(OptionsFileTest, ToYamlRoundTripsEveryField) {
  const SlamOptions changed = everythingChanged();
  ASSERT_TRUE(changed.validate().ok()) << changed.validate().error();
  const auto loaded = loadSlamOptions(write(toYaml(changed)));
  ASSERT_TRUE(loaded.ok()) << loaded.error();
  expectSameOptions(*loaded, changed);
  EXPECT_EQ(toYaml(*loaded), toYaml(changed));
  // Guard against a test that compares defaults with defaults: each field differs from its default.
  EXPECT_NE(toYaml(changed), toYaml(SlamOptions{}));
}

TEST_F(OptionsFileTest, DefaultsRoundTrip) {
  const auto loaded = loadSlamOptions(write(toYaml(SlamOptions{})));
  ASSERT_TRUE(loaded.ok()) << loaded.error();
  expectSameOptions(*loaded, SlamOptions{});
}

TEST_F(OptionsFileTest, PartialFileKeepsOtherDefaults) {
  const auto loaded = loadSlamOptions(write("tracking:\n  min_inliers_local_map: 40\nsequential: true\n"));
  ASSERT_TRUE(loaded.ok()) << loaded.error();
  SlamOptions expected;
  expected.tracking.min_inliers_local_map = 40;
  expected.sequential = true;
  expectSameOptions(*loaded, expected);
}

TEST_F(OptionsFileTest, EmptyFileGivesDefaults) {
  for (const std::string text : {"", "\n", "# only a comment\n"}) {
    SCOPED_TRACE("file: \"" + text + "\"");
    const auto loaded = loadSlamOptions(write(text));
    ASSERT_TRUE(loaded.ok()) << loaded.error();
    expectSameOptions(*loaded, SlamOptions{});
  }
}

TEST_F(OptionsFileTest, UnknownKeyNamesFieldAndLine) {
  const auto nested = loadSlamOptions(write("tracking:\n  min_init_features: 300\n  min_inlier_local_map: 20\n"));
  ASSERT_FALSE(nested.ok());
  EXPECT_TRUE(contains(nested.error(), "tracking.min_inlier_local_map"));
  EXPECT_TRUE(contains(nested.error(), "line 3"));

  const auto top = loadSlamOptions(write("orb:\n  num_features: 900\nsequentail: true\n"));
  ASSERT_FALSE(top.ok());
  EXPECT_TRUE(contains(top.error(), "sequentail"));
  EXPECT_TRUE(contains(top.error(), "line 3"));

  const auto section = loadSlamOptions(write("\nmaping:\n  local_ba: false\n"));
  ASSERT_FALSE(section.ok());
  EXPECT_TRUE(contains(section.error(), "maping.local_ba"));
  EXPECT_TRUE(contains(section.error(), "line 3"));
}

TEST_F(OptionsFileTest, WrongTypeNamesFieldAndLine) {
  const auto integer = loadSlamOptions(write("orb:\n  scale_factor: 1.3\n  num_features: many\n"));
  ASSERT_FALSE(integer.ok());
  EXPECT_TRUE(contains(integer.error(), "orb.num_features"));
  EXPECT_TRUE(contains(integer.error(), "line 3"));

  const auto real = loadSlamOptions(write("keyframes:\n  tracked_ratio: [0.4]\n"));
  ASSERT_FALSE(real.ok());
  EXPECT_TRUE(contains(real.error(), "keyframes.tracked_ratio"));
  EXPECT_TRUE(contains(real.error(), "line 2"));

  const auto boolean = loadSlamOptions(write("# comment\nsequential: maybe\n"));
  ASSERT_FALSE(boolean.ok());
  EXPECT_TRUE(contains(boolean.error(), "sequential"));
  EXPECT_TRUE(contains(boolean.error(), "line 2"));

  // A fractional value for an integer field is a type error, not a silent truncation.
  const auto fraction = loadSlamOptions(write("mapping:\n  ba_iterations: 2.5\n"));
  ASSERT_FALSE(fraction.ok());
  EXPECT_TRUE(contains(fraction.error(), "mapping.ba_iterations"));
}

TEST_F(OptionsFileTest, OutOfRangeValueInFileNamesField) {
  const auto loaded = loadSlamOptions(write("mapping:\n  redundant_ratio: 1.5\n"));
  ASSERT_FALSE(loaded.ok());
  EXPECT_TRUE(contains(loaded.error(), "mapping.redundant_ratio"));
}

TEST_F(OptionsFileTest, MalformedYamlAndMissingFileAreErrors) {
  const auto malformed = loadSlamOptions(write("orb:\n  num_features: [1000\n"));
  ASSERT_FALSE(malformed.ok());
  EXPECT_TRUE(contains(malformed.error(), "line"));

  const std::string missing = (dir_ / "does_not_exist.yaml").string();
  const auto none = loadSlamOptions(missing);
  ASSERT_FALSE(none.ok());
  EXPECT_TRUE(contains(none.error(), missing));
}

}  // namespace
}  // namespace stillpoint::slam
