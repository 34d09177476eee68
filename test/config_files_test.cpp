// The files in config/ are documentation that runs: they must load, and
// config/slam.yaml must equal the built-in defaults (update it when a default
// changes), config/camera_example.yaml the TUM fr3 preset it claims to be.
#include <gtest/gtest.h>

#include <fstream>
#include <iterator>
#include <string>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/slam/options.hpp"

namespace stillpoint {
namespace {

const std::string kConfigDir = STILLPOINT_SOURCE_DIR "/config/";

TEST(ConfigFiles, SlamYamlLoadsAndEqualsBuiltInDefaults) {
  const auto loaded = slam::loadSlamOptions(kConfigDir + "slam.yaml");
  ASSERT_TRUE(loaded.ok()) << loaded.error();
  EXPECT_EQ(slam::toYaml(*loaded), slam::toYaml(slam::SlamOptions{}))
      << "config/slam.yaml differs from the defaults in options.hpp / orb_extractor.hpp";
}

TEST(ConfigFiles, SlamYamlSetsEveryOption) {
  // Every field toYaml writes appears in the file, so it documents all of them.
  std::ifstream in(kConfigDir + "slam.yaml");
  const std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  const std::string defaults = slam::toYaml(slam::SlamOptions{});
  std::size_t start = 0;
  while (start < defaults.size()) {
    std::size_t end = defaults.find('\n', start);
    if (end == std::string::npos) end = defaults.size();
    const std::string line = defaults.substr(start, end - start);
    start = end + 1;
    const auto colon = line.find(':');
    if (colon == std::string::npos) continue;
    const std::string key = line.substr(line.find_first_not_of(' '), colon - line.find_first_not_of(' ') + 1);
    EXPECT_NE(text.find(key), std::string::npos) << "config/slam.yaml lacks '" << key << "'";
  }
}

TEST(ConfigFiles, CameraExampleLoadsAndIsTheFr3Preset) {
  const auto loaded = loadCameraYaml(kConfigDir + "camera_example.yaml");
  ASSERT_TRUE(loaded.ok()) << loaded.error();
  const CameraModel fr3 = *cameraPreset("fr3");
  EXPECT_EQ(loaded->width, fr3.width);
  EXPECT_EQ(loaded->height, fr3.height);
  EXPECT_EQ(loaded->fx, fr3.fx);
  EXPECT_EQ(loaded->fy, fr3.fy);
  EXPECT_EQ(loaded->cx, fr3.cx);
  EXPECT_EQ(loaded->cy, fr3.cy);
  EXPECT_EQ(loaded->dist, fr3.dist);
  EXPECT_EQ(loaded->depth_factor, fr3.depth_factor);
  EXPECT_EQ(loaded->baseline, fr3.baseline);
  EXPECT_EQ(loaded->min_depth, fr3.min_depth);
  EXPECT_EQ(loaded->max_depth, fr3.max_depth);
}

TEST(ConfigFiles, CameraExampleShowsEveryField) {
  std::ifstream in(kConfigDir + "camera_example.yaml");
  const std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  for (const char* key : {"name:", "width:", "height:", "fx:", "fy:", "cx:", "cy:", "distortion:",
                          "depth_factor:", "baseline:", "min_depth:", "max_depth:"}) {
    EXPECT_NE(text.find(std::string("\n") + key), std::string::npos) << key;
  }
}

}  // namespace
}  // namespace stillpoint
