// SlamOptions: range checks that name the field, and the YAML file format
// (round trip, unknown keys, wrong types, empty file).
#include "stillpoint/slam/options.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <sstream>
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
      {"tracking.min_inliers_local_map", [](SlamOptions& o) { o.tracking.min_inliers_local_map = 51; }},  // > relocalisation's
      {"tracking.close_depth_baselines", [](SlamOptions& o) { o.tracking.close_depth_baselines = 0; }},
      {"tracking.local_keyframes_max", [](SlamOptions& o) { o.tracking.local_keyframes_max = 0; }},
      {"tracking.relocalisation_candidates", [](SlamOptions& o) { o.tracking.relocalisation_candidates = 0; }},
      {"tracking.trajectory_records", [](SlamOptions& o) { o.tracking.trajectory_records = -2; }},
      {"tracking.mover_cells_every", [](SlamOptions& o) { o.tracking.mover_cells_every = 0; }},
      {"tracking.mover_cells_min_share", [](SlamOptions& o) { o.tracking.mover_cells_min_share = 1.5; }},
      {"tracking.mover_cells_radius_px", [](SlamOptions& o) { o.tracking.mover_cells_radius_px = 0; }},
      {"tracking.max_acceleration", [](SlamOptions& o) { o.tracking.max_acceleration = -1; }},
      {"tracking.max_angular_acceleration", [](SlamOptions& o) { o.tracking.max_angular_acceleration = 0; }},
      {"tracking.max_jump_m", [](SlamOptions& o) { o.tracking.max_jump_m = -0.01; }},
      {"tracking.max_jump_deg", [](SlamOptions& o) { o.tracking.max_jump_deg = -1; }},
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
      {"mapping.young_map_keyframes", [](SlamOptions& o) { o.mapping.young_map_keyframes = -1; }},
      {"mapping.young_map_wait_ms", [](SlamOptions& o) { o.mapping.young_map_wait_ms = 0; }},
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
      {"geometry.known_mover_min_rest", [](SlamOptions& o) { o.geometry.known_mover_min_rest = -1; }},
      {"geometry.mover_probation_frames", [](SlamOptions& o) { o.geometry.mover_probation_frames = -1; }},
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

// Every YAML key of `o` set away from its default (and still valid).
SlamOptions everythingChanged() {
  SlamOptions o;
  o.orb.num_features = 1500;
  o.orb.num_levels = 6;
  o.orb.scale_factor = 1.15;
  o.tracking.min_inliers_local_map = 40;
  o.tracking.relocalisation_candidates = 12;
  o.tracking.trajectory_records = 300;
  o.tracking.new_map_after_lost_s = 2.5;
  o.tracking.min_depth_share = 0.1;
  o.keyframes.max_interval_s = 0.75;
  o.mapping.local_ba = false;
  o.mapping.ba_max_keyframes = 15;
  o.mapping.keep_culled_keyframes = true;
  o.geometry.enabled = false;
  o.geometry.clustering.clusters_at_vga = 30;
  o.geometry.deadline_ms = 25;
  o.semantic.enabled = true;
  o.semantic.model_card = "card.yaml";
  o.semantic.model_dirs = {"/opt/models", "models"};
  o.semantic.movable_furniture = true;
  o.semantic.mask_dilation_px = 7;
  o.semantic.queue_capacity = 3;
  o.semantic.sequential_latency_frames = 4;
  o.semantic.threads = 2;
  o.semantic.confirm_with_geometry = "always";
  o.sequential = true;
  o.localisation = true;
  o.mapping.dense_views = true;
  return o;
}

void expectSameOptions(const SlamOptions& a, const SlamOptions& b) {
  EXPECT_EQ(toYaml(a), toYaml(b));
  EXPECT_EQ(a.orb.num_features, b.orb.num_features);
  EXPECT_EQ(a.orb.scale_factor, b.orb.scale_factor);
  EXPECT_EQ(a.tracking.trajectory_records, b.tracking.trajectory_records);
  EXPECT_EQ(a.tracking.new_map_after_lost_s, b.tracking.new_map_after_lost_s);
  EXPECT_EQ(a.tracking.min_depth_share, b.tracking.min_depth_share);
  EXPECT_EQ(a.keyframes.max_interval_s, b.keyframes.max_interval_s);
  EXPECT_EQ(a.mapping.keep_culled_keyframes, b.mapping.keep_culled_keyframes);
  EXPECT_EQ(a.geometry.clustering.clusters_at_vga, b.geometry.clustering.clusters_at_vga);
  EXPECT_EQ(a.geometry.deadline_ms, b.geometry.deadline_ms);
  EXPECT_EQ(a.semantic.model_dirs, b.semantic.model_dirs);
  EXPECT_EQ(a.semantic.confirm_with_geometry, b.semantic.confirm_with_geometry);
  EXPECT_EQ(a.sequential, b.sequential);
  EXPECT_EQ(a.localisation, b.localisation);
  EXPECT_EQ(a.mapping.dense_views, b.mapping.dense_views);
}

TEST_F(OptionsFileTest, EveryKeyRoundTrips) {
  const SlamOptions changed = everythingChanged();
  ASSERT_TRUE(changed.validate().ok()) << changed.validate().error();
  const auto loaded = loadSlamOptions(write(toYaml(changed)));
  ASSERT_TRUE(loaded.ok()) << loaded.error();
  expectSameOptions(*loaded, changed);
  // Each key differs from its default: a key missing from the table or
  // from everythingChanged() shows here.
  const std::string defaults = toYaml(SlamOptions{});
  std::istringstream a(toYaml(changed)), b(defaults);
  std::string la, lb;
  int lines = 0;
  while (std::getline(a, la) && std::getline(b, lb)) {
    ++lines;
    if (la.back() != ':') {  // a section header is the same in both
      EXPECT_NE(la, lb);
    }
  }
  EXPECT_GE(lines, 24);
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
  const auto nested = loadSlamOptions(write("tracking:\n  trajectory_records: 0\n  min_inlier_local_map: 20\n"));
  ASSERT_FALSE(nested.ok());
  EXPECT_TRUE(contains(nested.error(), "tracking.min_inlier_local_map"));
  EXPECT_TRUE(contains(nested.error(), "line 3"));

  const auto top = loadSlamOptions(write("orb:\n  num_features: 900\nsequentail: true\n"));
  ASSERT_FALSE(top.ok());
  EXPECT_TRUE(contains(top.error(), "sequentail"));
  EXPECT_TRUE(contains(top.error(), "line 3"));

  const auto section = loadSlamOptions(write("\nmaping:\n  local_ba: false\n"));
  ASSERT_FALSE(section.ok());
  EXPECT_TRUE(contains(section.error(), "unknown field 'maping'"));  // the section is the typo
  EXPECT_TRUE(contains(section.error(), "line 2"));
}

TEST_F(OptionsFileTest, WrongTypeNamesFieldAndLine) {
  const auto integer = loadSlamOptions(write("orb:\n  scale_factor: 1.3\n  num_features: many\n"));
  ASSERT_FALSE(integer.ok());
  EXPECT_TRUE(contains(integer.error(), "orb.num_features"));
  EXPECT_TRUE(contains(integer.error(), "line 3"));

  const auto real = loadSlamOptions(write("keyframes:\n  max_interval_s: [0.4]\n"));
  ASSERT_FALSE(real.ok());
  EXPECT_TRUE(contains(real.error(), "keyframes.max_interval_s"));
  EXPECT_TRUE(contains(real.error(), "line 2"));

  const auto boolean = loadSlamOptions(write("# comment\nsequential: maybe\n"));
  ASSERT_FALSE(boolean.ok());
  EXPECT_TRUE(contains(boolean.error(), "sequential"));
  EXPECT_TRUE(contains(boolean.error(), "line 2"));

  // A fractional value for an integer field is a type error, not a silent truncation.
  const auto fraction = loadSlamOptions(write("mapping:\n  ba_max_keyframes: 2.5\n"));
  ASSERT_FALSE(fraction.ok());
  EXPECT_TRUE(contains(fraction.error(), "mapping.ba_max_keyframes"));
}

TEST_F(OptionsFileTest, OutOfRangeValueInFileNamesField) {
  const auto loaded = loadSlamOptions(write("mapping:\n  ba_max_keyframes: 1\n"));
  ASSERT_FALSE(loaded.ok());
  EXPECT_TRUE(contains(loaded.error(), "mapping.ba_max_keyframes"));
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

// Tuned constants are not YAML keys: a file that sets one is a typo of a
// key or an experiment, and says so.
TEST_F(OptionsFileTest, TunedConstantsAreNotKeys) {
  const auto loaded = loadSlamOptions(write("geometry:\n  enabled: true\n  photo_release_ncc: 0.5\n"));
  ASSERT_FALSE(loaded.ok());
  EXPECT_TRUE(contains(loaded.error(), "unknown field 'geometry.photo_release_ncc'"));
  EXPECT_TRUE(contains(loaded.error(), "line 3"));
}

TEST_F(OptionsFileTest, DuplicateKeysAreErrors) {
  const auto nested = loadSlamOptions(write("orb:\n  num_features: 900\n  num_features: 1200\n"));
  ASSERT_FALSE(nested.ok());
  EXPECT_TRUE(contains(nested.error(), "duplicate field 'orb.num_features'"));
  EXPECT_TRUE(contains(nested.error(), "line 3"));
  const auto section = loadSlamOptions(write("orb:\n  num_features: 900\norb:\n  num_levels: 4\n"));
  ASSERT_FALSE(section.ok());
  EXPECT_TRUE(contains(section.error(), "duplicate field 'orb'"));
}

TEST_F(OptionsFileTest, OddShapesAreErrorsNotCrashes) {
  for (const std::string text : {"? [a, b]\n: 1\n", "orb:\n  ? {x: 1}\n  : 2\n", "orb: 5\n", "orb: [1, 2]\n",
                                 "- 1\n- 2\n", "semantic:\n  model_dirs: {a: 1}\n", "sequential: [true]\n"}) {
    SCOPED_TRACE(text);
    const auto loaded = loadSlamOptions(write(text));
    ASSERT_FALSE(loaded.ok());
    EXPECT_TRUE(contains(loaded.error(), "slam.yaml"));
  }
  // yaml-cpp calls nesting beyond its limit "bad file".
  const auto deep = loadSlamOptions(write("orb: " + std::string(600, '[') + std::string(600, ']') + "\n"));
  ASSERT_FALSE(deep.ok());
  EXPECT_TRUE(contains(deep.error(), "nested too deeply")) << deep.error();
}

// The shipped config/slam.yaml holds every key at its default, and
// docs/configuration.md holds the reference table optionsReference() writes
// (stillpoint-replay --options-reference prints it).
std::string readFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

TEST(SlamOptionsReference, ShippedConfigHoldsEveryKeyAtItsDefault) {
  const fs::path file = fs::path(STILLPOINT_SOURCE_DIR) / "config" / "slam.yaml";
  const auto loaded = loadSlamOptions(file.string());
  ASSERT_TRUE(loaded.ok()) << loaded.error();
  EXPECT_EQ(toYaml(*loaded), toYaml(SlamOptions{}));
  // Every key is written out (not left to its default by omission).
  const std::string text = readFile(file);
  std::istringstream table(optionsReference());
  std::string row;
  int keys = 0;
  while (std::getline(table, row)) {
    if (row.rfind("| `", 0) != 0) continue;
    const std::string key = row.substr(3, row.find('`', 3) - 3);
    const std::string leaf = key.substr(key.rfind('.') + 1);
    EXPECT_TRUE(contains(text, "\n" + leaf + ":") || contains(text, "  " + leaf + ":")) << key;
    ++keys;
  }
  EXPECT_LE(keys, 31);
}

TEST(SlamOptionsReference, DocsHoldTheGeneratedTable) {
  const std::string doc = readFile(fs::path(STILLPOINT_SOURCE_DIR) / "docs" / "configuration.md");
  const std::string begin = "<!-- options-reference: begin -->\n", end = "<!-- options-reference: end -->";
  const auto b = doc.find(begin), e = doc.find(end);
  ASSERT_NE(b, std::string::npos);
  ASSERT_NE(e, std::string::npos);
  EXPECT_EQ(doc.substr(b + begin.size(), e - b - begin.size()), optionsReference())
      << "regenerate it: stillpoint-replay --options-reference";
}

}  // namespace
}  // namespace stillpoint::slam
