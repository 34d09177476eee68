// stillpoint-eval's command-line contract: one machine-readable line on good
// input, exit 1 naming file (and line) on bad input, exit 2 on usage errors.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <regex>
#include <string>
#include <vector>

#include "cli_runner.hpp"

namespace stillpoint {
namespace {

namespace fs = std::filesystem;
using test::RunResult;
using test::writeFile;

std::string describe(const RunResult& r) {
  return "exit " + std::to_string(r.exit_code) + "\n--- stdout ---\n" + r.out + "--- stderr ---\n" + r.err;
}

::testing::AssertionResult contains(const std::string& text, const std::string& part) {
  if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "\"" << part << "\" not found in:\n" << text;
}

// A planar loop with yaw, 20 Hz for 3 s, in TUM format. `yaw0`, `x0`, `y0`
// move the whole trajectory rigidly (about and along the world axes); the
// poses from `jump_from` on are 5 cm higher.
std::string trajectoryText(double yaw0, double x0, double y0, int jump_from = 60) {
  std::string text = "# timestamp tx ty tz qx qy qz qw\n";
  for (int k = 0; k < 60; ++k) {
    const double t = 1000.0 + 0.05 * k;
    const double px = 0.5 * std::cos(0.6 * k * 0.05), py = 0.3 * std::sin(0.6 * k * 0.05);
    const double pz = 0.1 * k * 0.05 + (k >= jump_from ? 0.05 : 0.0), yaw = 0.4 * k * 0.05;
    const double x = std::cos(yaw0) * px - std::sin(yaw0) * py + x0;
    const double y = std::sin(yaw0) * px + std::cos(yaw0) * py + y0;
    char line[200];
    std::snprintf(line, sizeof(line), "%.6f %.9f %.9f %.9f 0 0 %.9f %.9f\n", t, x, y, pz,
                  std::sin(0.5 * (yaw + yaw0)), std::cos(0.5 * (yaw + yaw0)));
    text += line;
  }
  return text;
}

// One drift line of --frame-log's output, `key`=`name`: its groups are the
// poses, then the median, p90, max and share over 2 cm.
std::regex driftLine(const std::string& key, const std::string& name) {
  const std::string number = "([0-9.]+)";
  return std::regex("\n" + key + "=" + name + " poses=([0-9]+) drift_median_m=" + number + " drift_p90_m=" + number +
                    " drift_max_m=" + number + " over_2cm=" + number + "\n");
}

class EvalCli : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    scratch_ = fs::temp_directory_path() /
               ("stillpoint_eval_cli_" + std::to_string(::getpid()) + "_" + info->name());
    fs::remove_all(scratch_);
    fs::create_directories(scratch_);
    gt_ = (scratch_ / "groundtruth.txt").string();
    est_ = (scratch_ / "estimate.txt").string();
    writeFile(gt_, trajectoryText(0, 0, 0));
    writeFile(est_, trajectoryText(0.7, 1.5, -2.0));
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(scratch_);
  }
  RunResult eval(std::vector<std::string> args) {
    args.insert(args.begin(), STILLPOINT_EVAL);
    return test::run(args, scratch_);
  }
  // Writes `text` to a file of the scratch folder; its path.
  std::string writeScratch(const std::string& name, const std::string& text) {
    const std::string path = (scratch_ / name).string();
    writeFile(path, text);
    return path;
  }

  fs::path scratch_;
  std::string gt_, est_;
};

TEST_F(EvalCli, GoodInputPrintsExactlyOneMetricsLine) {
  const RunResult r = eval({gt_, est_});
  ASSERT_EQ(r.exit_code, 0) << describe(r);
  const std::string number = "([-+0-9.eE]+|nan|inf)";
  const std::regex line("ate_rmse_m=" + number + " rpe_trans_m_s=" + number + " rpe_rot_deg_s=" + number +
                        " matched=([0-9]+)\n");
  std::smatch m;
  ASSERT_TRUE(std::regex_match(r.out, m, line)) << describe(r);
  // The estimate is the ground truth moved rigidly: alignment undoes that exactly.
  EXPECT_LT(std::stod(m[1]), 1e-5) << r.out;
  EXPECT_LT(std::stod(m[2]), 1e-5) << r.out;
  EXPECT_LT(std::stod(m[3]), 1e-3) << r.out;
  EXPECT_EQ(m[4], "60");
}

TEST_F(EvalCli, DisplacedEstimateGivesMatchingError) {
  // Every other pose 2 cm off along z: ATE RMSE is about 1 cm, not zero.
  const std::string gt = trajectoryText(0, 0, 0);
  std::string text;
  int k = 0;
  for (std::size_t start = 0, end; (end = gt.find('\n', start)) != std::string::npos; start = end + 1) {
    std::string row = gt.substr(start, end - start);
    if (row[0] != '#' && k++ % 2 == 0) {
      double v[8];
      ASSERT_EQ(std::sscanf(row.c_str(), "%lf %lf %lf %lf %lf %lf %lf %lf", &v[0], &v[1], &v[2], &v[3], &v[4],
                            &v[5], &v[6], &v[7]),
                8);
      char line[200];
      std::snprintf(line, sizeof(line), "%.6f %.9f %.9f %.9f %.9f %.9f %.9f %.9f", v[0], v[1], v[2], v[3] + 0.02,
                    v[4], v[5], v[6], v[7]);
      row = line;
    }
    text += row + "\n";
  }
  writeFile(est_, text);
  const RunResult r = eval({gt_, est_});
  ASSERT_EQ(r.exit_code, 0) << describe(r);
  std::smatch m;
  ASSERT_TRUE(std::regex_search(r.out, m, std::regex("^ate_rmse_m=([0-9.]+) "))) << describe(r);
  EXPECT_NEAR(std::stod(m[1]), 0.01, 0.002) << r.out;
}

TEST_F(EvalCli, MapsAreAlignedEachOnItsOwnAndInOneFrame) {
  // The last 20 poses are a second map, 5 cm higher (the trajectory's jump):
  // each map aligned on its own is exact, in one frame it is not.
  std::string text = trajectoryText(0.7, 1.5, -2.0, 40);
  const std::size_t at = text.find("1002.000000");
  ASSERT_NE(at, std::string::npos);
  text.insert(at, "# map 1\n");
  writeFile(est_, text);
  const RunResult r = eval({gt_, est_});
  ASSERT_EQ(r.exit_code, 0) << describe(r);
  std::smatch m;
  ASSERT_TRUE(std::regex_search(r.out, m, std::regex("^ate_rmse_m=([0-9.]+) "))) << describe(r);
  EXPECT_LT(std::stod(m[1]), 1e-5) << r.out;
  ASSERT_TRUE(std::regex_search(r.out, m, std::regex("\nmaps=2 ate_one_frame_rmse_m=([0-9.]+) unaligned=0\n")))
      << describe(r);
  // 40 poses against 20, 5 cm apart: a shift alone leaves sqrt(2/9) * 5 cm
  // (2.4 cm); the best rigid alignment no more than that, and not nothing.
  EXPECT_LE(std::stod(m[1]), 0.0236) << r.out;
  EXPECT_GT(std::stod(m[1]), 0.005) << r.out;
}

TEST_F(EvalCli, FrameLogGivesTheDriftOfEachHealthLevel) {
  // The pose jumps 5 cm at frame 30, and frames 30-36 (those whose 0.35 s
  // window spans the jump) say `unreliable`; frame 59 is not in the log.
  writeFile(est_, trajectoryText(0.7, 1.5, -2.0, 30));
  std::string log = "# index timestamp state health\n";
  for (int k = 0; k < 59; ++k) {
    char line[100];
    std::snprintf(line, sizeof(line), "%d %.6f ok %s\n", k, 1000.0 + 0.05 * k, k >= 30 && k <= 36 ? "unreliable" : "good");
    log += line;
  }
  const std::string frames = writeScratch("frames.txt", log);
  const RunResult r = eval({gt_, est_, "--frame-log", frames});
  ASSERT_EQ(r.exit_code, 0) << describe(r);
  std::smatch m;
  const auto level = [](const std::string& name) { return driftLine("health", name); };
  ASSERT_TRUE(std::regex_search(r.out, m, level("good"))) << describe(r);
  EXPECT_EQ(m[1], "45");  // frames 7-58 with a pose 7 frames back, less the 7 unreliable ones
  EXPECT_LT(std::stod(m[4]), 1e-5) << r.out;
  ASSERT_TRUE(std::regex_search(r.out, m, level("unreliable"))) << describe(r);
  EXPECT_EQ(m[1], "7");
  EXPECT_NEAR(std::stod(m[2]), 0.05, 1e-5) << r.out;
  EXPECT_EQ(std::stod(m[5]), 1.0) << r.out;
  ASSERT_TRUE(std::regex_search(r.out, m, level("-"))) << describe(r);
  EXPECT_EQ(m[1], "1");
  EXPECT_EQ(r.out.find("health=degraded"), std::string::npos) << r.out;
  // The levels come good, unreliable, then the poses without a frame.
  EXPECT_LT(r.out.find("health=good"), r.out.find("health=unreliable"));
  EXPECT_LT(r.out.find("health=unreliable"), r.out.find("health=-"));
  EXPECT_EQ(r.out.find("cause="), std::string::npos) << "no health_causes column: " << r.out;

  writeFile(frames, "# index timestamp state\n0 1000.0 ok\n");
  const RunResult no_health = eval({gt_, est_, "--frame-log", frames});
  EXPECT_EQ(no_health.exit_code, 1) << describe(no_health);
  EXPECT_TRUE(contains(no_health.err, frames + ":1: the header names no column 'health'"));
  EXPECT_TRUE(no_health.out.empty()) << describe(no_health);
  const RunResult bad_window = eval({gt_, est_, "--frame-log", frames, "--drift-window", "0"});
  EXPECT_EQ(bad_window.exit_code, 2) << describe(bad_window);
  EXPECT_TRUE(contains(bad_window.err, "--drift-window"));
}

TEST_F(EvalCli, FrameLogGivesTheDriftOfEachHealthCause) {
  // As above: the pose jumps 5 cm at frame 30, and frames 30-36 name two
  // causes; frames 37-40 are recovering, the others have none.
  writeFile(est_, trajectoryText(0.7, 1.5, -2.0, 30));
  std::string log = "# index timestamp state health dynamic_share health_causes\n";
  for (int k = 0; k < 60; ++k) {
    const bool jump = k >= 30 && k <= 36, after = k >= 37 && k <= 40;
    char line[160];
    std::snprintf(line, sizeof(line), "%d %.6f ok %s 0.3 %s\n", k, 1000.0 + 0.05 * k,
                  jump ? "unreliable" : after ? "degraded" : "good",
                  jump ? "view_moving+masks_late" : after ? "recovering" : "none");
    log += line;
  }
  const RunResult r = eval({gt_, est_, "--frame-log", writeScratch("frames.txt", log)});
  ASSERT_EQ(r.exit_code, 0) << describe(r);
  std::smatch m;
  const auto cause = [](const std::string& name) { return driftLine("cause", name); };
  for (const char* name : {"view_moving", "masks_late"}) {
    ASSERT_TRUE(std::regex_search(r.out, m, cause(name))) << name << ": " << describe(r);
    EXPECT_EQ(m[1], "7") << name;  // each pose under both of its causes
    EXPECT_NEAR(std::stod(m[2]), 0.05, 1e-5) << r.out;
    EXPECT_EQ(std::stod(m[5]), 1.0) << r.out;
  }
  ASSERT_TRUE(std::regex_search(r.out, m, cause("recovering"))) << describe(r);
  EXPECT_EQ(m[1], "4");
  EXPECT_LT(std::stod(m[4]), 1e-5) << r.out;
  ASSERT_TRUE(std::regex_search(r.out, m, cause("none"))) << describe(r);
  EXPECT_EQ(m[1], "42");  // frames 7-59 with a pose 7 frames back, less the 11 above
  EXPECT_LT(std::stod(m[4]), 1e-5) << r.out;
  EXPECT_EQ(r.out.find("cause=view_moving+"), std::string::npos) << "a set is split: " << r.out;
  // none first, then the causes in the order of their bits.
  EXPECT_LT(r.out.find("cause=none"), r.out.find("cause=view_moving"));
  EXPECT_LT(r.out.find("cause=view_moving"), r.out.find("cause=masks_late"));
  EXPECT_LT(r.out.find("cause=masks_late"), r.out.find("cause=recovering"));
  // The health lines come first, as before.
  EXPECT_LT(r.out.find("health=unreliable"), r.out.find("cause=none"));
}

// The frame log's covariance against the drift: the pose jumps 5 cm at frame
// 30; the covariance of frames 30-36 says 5 cm (per axis) or, in a second
// log, 1 mm like every other frame's. A bad covariance field is named.
TEST_F(EvalCli, FrameLogSaysHowWellTheCovarianceCoversTheDrift) {
  writeFile(est_, trajectoryText(0.7, 1.5, -2.0, 30));
  const auto frameLog = [](double jump_sigma_m) {
    std::string log = "# index timestamp state health covariance\n";
    for (int k = 0; k < 60; ++k) {
      const bool jump = k >= 30 && k <= 36;
      const double v = jump ? jump_sigma_m * jump_sigma_m : 1e-6;
      std::string covariance;
      for (int r = 0; r < 6; ++r)
        for (int c = r; c < 6; ++c) {
          if (!covariance.empty()) covariance += ',';
          covariance += std::to_string(r == c ? v : 0.0);
        }
      log += std::to_string(k) + " " + std::to_string(1000.0 + 0.05 * k) + " ok " +
             (jump ? "unreliable " : "good ") + covariance + "\n";
    }
    return log;
  };
  const std::regex line(
      "\ncovariance=(unreliable|all) poses=([0-9]+) position_within_95=([0-9.]+) position_median=([0-9.]+) "
      "rotation_within_95=([0-9.]+) rotation_median=([0-9.]+)");
  const RunResult wide = eval({gt_, est_, "--frame-log", writeScratch("wide.txt", frameLog(0.05))});
  ASSERT_EQ(wide.exit_code, 0) << describe(wide);
  std::smatch m;
  ASSERT_TRUE(std::regex_search(wide.out, m, line)) << describe(wide);
  EXPECT_EQ(m[1], "unreliable");
  EXPECT_EQ(m[2], "7");
  EXPECT_EQ(std::stod(m[3]), 1.0) << wide.out;  // 5 cm inside a 5 cm ellipsoid
  EXPECT_NE(wide.out.find("covariance=good poses="), std::string::npos) << wide.out;
  EXPECT_NE(wide.out.find("covariance=all poses=53 "), std::string::npos) << wide.out;

  const RunResult narrow = eval({gt_, est_, "--frame-log", writeScratch("narrow.txt", frameLog(0.001))});
  ASSERT_EQ(narrow.exit_code, 0) << describe(narrow);
  ASSERT_TRUE(std::regex_search(narrow.out, m, line)) << describe(narrow);
  EXPECT_EQ(std::stod(m[3]), 0.0) << narrow.out;  // 5 cm far outside 1 mm
  EXPECT_GT(std::stod(m[4]), 100.0) << narrow.out;

  std::string bad = frameLog(0.05);
  bad.replace(bad.find(" ok good ") + 9, 3, "x,0");
  const RunResult malformed = eval({gt_, est_, "--frame-log", writeScratch("bad.txt", bad)});
  EXPECT_EQ(malformed.exit_code, 1) << describe(malformed);
  EXPECT_NE(malformed.err.find("bad.txt"), std::string::npos) << describe(malformed);
  EXPECT_NE(malformed.err.find("covariance"), std::string::npos) << describe(malformed);
}

TEST_F(EvalCli, MissingGroundTruthFileIsNamed) {
  const std::string missing = (scratch_ / "no_groundtruth.txt").string();
  const RunResult r = eval({missing, est_});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, missing + ": cannot open"));
  EXPECT_TRUE(r.out.empty()) << describe(r);
}

TEST_F(EvalCli, MalformedGroundTruthLineNamesFileAndLine) {
  writeFile(gt_, "# header\n1000.0 0 0 0 0 0 0 1\n1000.1 0 0 zero 0 0 0 1\n");
  const RunResult r = eval({gt_, est_});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, gt_ + ":3:"));
  EXPECT_TRUE(r.out.empty()) << describe(r);
}

TEST_F(EvalCli, MalformedEstimateLineNamesFileAndLine) {
  writeFile(est_, "1000.0 0 0 0 0 0 0 1\n1000.1 0 0 0 0 0 1\n");
  const RunResult r = eval({gt_, est_});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, est_ + ":2:"));
}

TEST_F(EvalCli, NoOverlapInTimeFailsWithExitOne) {
  writeFile(est_, "5000.0 0 0 0 0 0 0 1\n5000.1 1 0 0 0 0 0 1\n5000.2 2 0 0 0 0 0 1\n");
  const RunResult r = eval({gt_, est_});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_FALSE(r.err.empty());
  EXPECT_TRUE(r.out.empty()) << describe(r);
}

TEST_F(EvalCli, UsageErrorsExitTwoWithUsage) {
  RunResult r = eval({gt_, est_, "--frobnicate"});
  EXPECT_EQ(r.exit_code, 2) << describe(r);
  EXPECT_TRUE(contains(r.err, "unknown option '--frobnicate'"));
  EXPECT_TRUE(contains(r.err, "usage: stillpoint-eval"));
  r = eval({gt_});
  EXPECT_EQ(r.exit_code, 2) << describe(r);
  EXPECT_TRUE(contains(r.err, "expected GROUNDTRUTH.txt and TRAJ.txt"));
  r = eval({gt_, est_, "--max-dt", "-1"});
  EXPECT_EQ(r.exit_code, 2) << describe(r);
  EXPECT_TRUE(contains(r.err, "--max-dt"));
}

TEST_F(EvalCli, HelpExitsZero) {
  const RunResult r = eval({"--help"});
  EXPECT_EQ(r.exit_code, 0) << describe(r);
  EXPECT_TRUE(contains(r.out, "ate_rmse_m=<v> rpe_trans_m_s=<v> rpe_rot_deg_s=<v> matched=<n>"));
}

TEST_F(EvalCli, VersionExitsZero) {
  const RunResult r = eval({"--version"});
  EXPECT_EQ(r.exit_code, 0) << describe(r);
  EXPECT_TRUE(contains(r.out, "stillpoint-eval " STILLPOINT_VERSION)) << describe(r);
}

}  // namespace
}  // namespace stillpoint
