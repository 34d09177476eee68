// stillpoint-synth's command-line contract: generation writes the TUM layout
// plus masks and movers.yaml, score reads a feature file back, bad input exits
// 1 with a message naming what is wrong, usage errors exit 2.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "cli_runner.hpp"

namespace stillpoint {
namespace {

namespace fs = std::filesystem;
using test::RunResult;

::testing::AssertionResult contains(const std::string& text, const std::string& part) {
  if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "\"" << part << "\" not found in:\n" << text;
}

class SynthCli : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    scratch_ = fs::temp_directory_path() / ("stillpoint_synth_cli_" + std::to_string(::getpid()) + "_" + info->name());
    fs::remove_all(scratch_);
    fs::create_directories(scratch_);
  }
  void TearDown() override { fs::remove_all(scratch_); }
  RunResult synth(std::vector<std::string> args) {
    args.insert(args.begin(), STILLPOINT_SYNTH);
    return test::run(args, scratch_);
  }
  fs::path scratch_;
};

TEST_F(SynthCli, RoomThenScore) {
  const fs::path out = scratch_ / "room";
  const RunResult r = synth({"room", out.string(), "--preset", "room-walker", "--frames", "3", "--size", "80x60",
                             "--seed", "4"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(contains(test::lastLine(r.out), "frames=3 "));
  for (const char* f : {"rgb.txt", "depth.txt", "mask.txt", "groundtruth.txt", "movers.yaml", "movers.txt"}) {
    EXPECT_TRUE(fs::exists(out / f)) << f;
  }
  EXPECT_TRUE(contains(test::readFile(out / "movers.yaml"), "shape: walker"));
  // Score one flagged feature at the centre of the image against frame 1.
  const std::string stamp = "1000000000.000000";
  ASSERT_TRUE(contains(test::readFile(out / "mask.txt"), stamp));
  test::writeFile(scratch_ / "features.txt", "# t u v flagged\n" + stamp + " 40 30 1\n" + stamp + " 1 1 0\n");
  const RunResult s = synth({"score", out.string(), (scratch_ / "features.txt").string(), "--per-frame"});
  ASSERT_EQ(s.exit_code, 0) << s.err;
  EXPECT_TRUE(contains(s.out, "precision_mean="));
  EXPECT_TRUE(contains(s.out, stamp));
  // Scoring moving movers only reads movers.txt; a bad speed is a usage error.
  const RunResult m = synth({"score", out.string(), (scratch_ / "features.txt").string(), "--min-speed", "0.05"});
  ASSERT_EQ(m.exit_code, 0) << m.err;
  EXPECT_TRUE(contains(m.out, "min speed 0.050 m/s"));
  const RunResult bad = synth({"score", out.string(), (scratch_ / "features.txt").string(), "--min-speed", "fast"});
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_TRUE(contains(bad.err, "--min-speed needs a number"));
}

TEST_F(SynthCli, EditCoversCutsAndPlaysBack) {
  const fs::path room = scratch_ / "room";
  ASSERT_EQ(synth({"room", room.string(), "--preset", "room-static", "--frames", "12", "--size", "80x60"}).exit_code,
            0);
  // 12 frames at 30 Hz: frames 3..5 covered (0.1 s .. 0.2 s), 7..8 cut, then back.
  const fs::path out = scratch_ / "edited";
  const RunResult r = synth({"edit", room.string(), out.string(), "--cover", "0.09:0.1", "--cut", "0.22:0.06",
                             "--there-and-back"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  // 10 kept frames forwards, 9 backwards; the covered ones twice.
  EXPECT_TRUE(contains(test::lastLine(r.out), "frames=19 covered=6 cut=2 ground_truth=19")) << r.out;
  const RunResult again = synth({"edit", room.string(), out.string()});
  EXPECT_EQ(again.exit_code, 1);
  EXPECT_TRUE(contains(again.err, "exists"));
  // The edit is a sequence stillpoint reads, with increasing stamps.
  const std::string rgb = test::readFile(out / "rgb.txt");
  std::istringstream lines(rgb);
  double last = 0;
  int frames = 0;
  for (std::string line; std::getline(lines, line);) {
    if (line.empty() || line[0] == '#') continue;
    const double t = std::stod(line);
    EXPECT_GT(t, last) << line;
    last = t;
    ++frames;
  }
  EXPECT_EQ(frames, 19);
  EXPECT_EQ(synth({"edit", room.string(), (scratch_ / "bad").string(), "--cover", "1"}).exit_code, 2);
}

// Every example config of config/synth generates (its first frames, without
// writing them): the teddy_* ones over the real excerpt, the others in the
// room. A config whose footage is not installed (opencv-doc) fails naming it.
TEST_F(SynthCli, EveryExampleConfigGenerates) {
  const fs::path configs = fs::path(STILLPOINT_SOURCE_DIR) / "config" / "synth";
  const fs::path excerpt = fs::path(STILLPOINT_DATA_DIR) / "tum_fr3_teddy_200";
  int checked = 0;
  for (const auto& entry : fs::directory_iterator(configs)) {
    if (entry.path().extension() != ".yaml") continue;
    const std::string name = entry.path().filename().string();
    SCOPED_TRACE(name);
    const bool overlay = name.rfind("teddy_", 0) == 0;
    if (overlay && !fs::is_directory(excerpt)) continue;
    std::vector<std::string> args{"room", (scratch_ / "out").string()};
    if (overlay) args = {"overlay", excerpt.string(), (scratch_ / "out").string(), "--camera", "fr3"};
    args.insert(args.end(), {"--config", entry.path().string(), "--max-frames", "3", "--no-write"});
    const RunResult r = synth(args);
    ++checked;
    const std::string text = test::readFile(entry.path());
    // Footage and photos from Debian's opencv-doc: without the package the
    // error names the file.
    bool absent = false;
    for (const std::string key : {"video: ", "texture: /"}) {
      const auto at = text.find(key);
      if (at == std::string::npos) continue;
      const std::size_t from = at + key.size() - (key.back() == '/' ? 1 : 0);
      const std::string file = text.substr(from, text.find('\n', at) - from);
      if (fs::exists(file)) continue;
      EXPECT_EQ(r.exit_code, 1);
      EXPECT_TRUE(contains(r.err, file)) << r.err;
      absent = true;
    }
    if (absent) continue;
    EXPECT_EQ(r.exit_code, 0) << r.err;
    EXPECT_TRUE(contains(test::lastLine(r.out), "frames=3 "));
  }
  EXPECT_GE(checked, 5);
}

TEST_F(SynthCli, BadInputExitsOneWithAMessage) {
  RunResult r = synth({"overlay", "/nonexistent/seq", (scratch_ / "o").string(), "--camera", "fr3", "--preset",
                       "poster-walk"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_TRUE(contains(r.err, "/nonexistent/seq"));
  test::writeFile(scratch_ / "bad.yaml", "movers:\n  - name: a\n    shape: sphere\n");
  r = synth({"room", (scratch_ / "o").string(), "--config", (scratch_ / "bad.yaml").string()});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_TRUE(contains(r.err, "sphere"));
  EXPECT_TRUE(contains(r.err, "line 3"));
  r = synth({"score", scratch_.string(), (scratch_ / "f.txt").string()});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_TRUE(contains(r.err, "mask.txt"));
  // Render poses that cannot be read name the file.
  const fs::path excerpt = fs::path(STILLPOINT_DATA_DIR) / "tum_fr3_teddy_200";
  if (!fs::is_directory(excerpt)) return;
  r = synth({"overlay", excerpt.string(), (scratch_ / "o2").string(), "--camera", "fr3", "--preset", "poster-walk",
             "--render-poses", (scratch_ / "no_poses.txt").string(), "--no-write"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_TRUE(contains(r.err, "no_poses.txt")) << r.err;
}

TEST_F(SynthCli, UsageErrorsExitTwo) {
  EXPECT_EQ(synth({}).exit_code, 2);
  EXPECT_EQ(synth({"room", "a", "--frames", "zero"}).exit_code, 2);
  const RunResult poses = synth({"room", "a", "--preset", "room-static", "--render-poses", "t.txt"});
  EXPECT_EQ(poses.exit_code, 2);
  EXPECT_TRUE(contains(poses.err, "--render-poses is for overlay only"));
  const RunResult help = synth({"--help"});
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_TRUE(contains(help.out, "usage: stillpoint-synth"));
}

}  // namespace
}  // namespace stillpoint
