// Mover configuration: shipped files and presets load, bad files are refused
// with the file, line and field named.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include <unistd.h>

#include "stillpoint/synth/config.hpp"

namespace stillpoint::synth {
namespace {

namespace fs = std::filesystem;

std::string writeYaml(const std::string& name, const std::string& text) {
  const fs::path p = fs::temp_directory_path() / ("stillpoint_synth_cfg_" + name + "_" + std::to_string(::getpid()) + ".yaml");
  std::ofstream(p) << text;
  return p.string();
}

TEST(SynthConfig, ShippedConfigsLoad) {
  const fs::path dir = fs::path(STILLPOINT_SOURCE_DIR) / "config" / "synth";
  int loaded = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().extension() != ".yaml") continue;
    Result<SynthConfig> c = loadSynthConfig(e.path().string());
    ASSERT_TRUE(c.ok()) << c.error();
    EXPECT_FALSE(c->movers.empty()) << e.path();
    ++loaded;
  }
  EXPECT_GE(loaded, 2);
}

TEST(SynthConfig, EveryPresetIsValid) {
  for (const std::string& name : presetNames()) {
    Result<SynthConfig> c = synthPreset(name, "/nonexistent");  // photos fall back to styles
    ASSERT_TRUE(c.ok()) << name << ": " << c.error();
    EXPECT_TRUE(c->validate().ok());
  }
  Result<SynthConfig> bad = synthPreset("no-such-preset", "");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().find("poster-walk"), std::string::npos) << bad.error();
}

TEST(SynthConfig, ReadsAllFields) {
  const std::string p = writeYaml("full",
                                  "seed: 9\n"
                                  "sensor: {max_depth_m: 4.0, sigma_at_1m: 0.002}\n"
                                  "motion_blur: {enabled: true, samples: 3}\n"
                                  "room: {motion: rpy, frames: 12}\n"
                                  "movers:\n"
                                  "  - name: b\n"
                                  "    shape: box\n"
                                  "    texture: wood\n"
                                  "    size: [0.2, 0.3, 0.4]\n"
                                  "    yaw_rate_deg_s: 5\n"
                                  "    path: {type: stop_and_go, start: [0, 1, 1], end: [1, 1, 1], speed: 0.3, go_s: 2, stop_s: 0.5}\n");
  Result<SynthConfig> c = loadSynthConfig(p);
  ASSERT_TRUE(c.ok()) << c.error();
  EXPECT_EQ(c->seed, 9u);
  EXPECT_DOUBLE_EQ(c->sensor.max_depth_m, 4.0);
  EXPECT_TRUE(c->blur.enabled);
  EXPECT_EQ(c->blur.samples, 3);
  EXPECT_EQ(c->room.motion, CameraMotion::kRpy);
  EXPECT_EQ(c->room.frames, 12);
  ASSERT_EQ(c->movers.size(), 1u);
  EXPECT_EQ(c->movers[0].shape, MoverShape::kBox);
  EXPECT_EQ(c->movers[0].path.type, PathType::kStopAndGo);
  EXPECT_DOUBLE_EQ(c->movers[0].path.end.x(), 1.0);
  EXPECT_DOUBLE_EQ(c->movers[0].path.go_s, 2.0);
  EXPECT_DOUBLE_EQ(c->movers[0].size.z(), 0.4);
  fs::remove(p);
}

TEST(SynthConfig, BadFilesNameTheField) {
  struct Case {
    std::string text, expect;
  };
  const std::vector<Case> cases = {
      {"movers:\n  - name: a\n    colour: red\n", "movers[0].colour"},
      {"movers:\n  - name: a\n    shape: sphere\n", "sphere"},
      {"movers:\n  - name: a\n    size: [1]\n", "movers[0].size"},
      {"movers:\n  - name: a\n    path: {type: walk, speed: -1}\n", "movers[0].path.speed"},
      {"movers:\n  - name: a\n    path: {type: teleport}\n", "teleport"},
      {"sensor: {max_depth_m: abc}\n", "sensor.max_depth_m"},
      {"sensor: {edge_dropout: 2}\n", "sensor.edge_dropout"},
      {"seed: 1\nspeed: 3\n", "'speed'"},
      {"room: {motion: spin}\n", "spin"},
      {"movers: [a: [1, 2\n", "line"},
  };
  for (const Case& c : cases) {
    const std::string p = writeYaml("bad", c.text);
    Result<SynthConfig> r = loadSynthConfig(p);
    ASSERT_FALSE(r.ok()) << c.text;
    EXPECT_NE(r.error().find(c.expect), std::string::npos) << r.error();
    EXPECT_NE(r.error().find(p), std::string::npos) << r.error();
    fs::remove(p);
  }
  Result<SynthConfig> missing = loadSynthConfig("/nonexistent/movers.yaml");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().find("/nonexistent/movers.yaml"), std::string::npos);
}

}  // namespace
}  // namespace stillpoint::synth
