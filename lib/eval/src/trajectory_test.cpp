#include "stillpoint/eval/trajectory.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <numbers>
#include <random>

#include <unistd.h>

namespace stillpoint::eval {
namespace {

namespace fs = std::filesystem;

class TrajectoryIoTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() /
           (std::string("stillpoint_eval_") + info->name() + "_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string writeFile(const std::string& name, const std::string& content) {
    const std::string path = (dir_ / name).string();
    std::ofstream(path) << content;
    return path;
  }

  // Expects reading `content` to fail with "path:line: ..." containing `what`.
  void expectLineError(const std::string& content, int line, const std::string& what) {
    const std::string path = writeFile("bad.txt", content);
    const auto result = readTumTrajectory(path);
    ASSERT_FALSE(result.ok()) << content;
    EXPECT_NE(result.error().find(path + ":" + std::to_string(line) + ":"), std::string::npos)
        << result.error();
    EXPECT_NE(result.error().find(what), std::string::npos) << result.error();
  }

  fs::path dir_;
};

TEST_F(TrajectoryIoTest, ReadsCommentsBlankLinesAndExactStamps) {
  const std::string path = writeFile("gt.txt",
                                     "# ground truth trajectory\n"
                                     "# timestamp tx ty tz qx qy qz qw\n"
                                     "\n"
                                     "1341841873.4151 -2.1837 0.6821 1.4854 0 0 0 1\n"
                                     "   \r\n"
                                     "1341841873.425100\t1\t2\t3\t0\t0\t0.7071068\t0.7071068\r\n");
  const auto trajectory = readTumTrajectory(path);
  ASSERT_TRUE(trajectory.ok()) << trajectory.error();
  ASSERT_EQ(trajectory->size(), 2u);
  EXPECT_EQ((*trajectory)[0].stamp.nanoseconds(), 1341841873415100000LL);
  EXPECT_EQ((*trajectory)[1].stamp.nanoseconds(), 1341841873425100000LL);
  EXPECT_TRUE((*trajectory)[0].T_w_c.translation().isApprox(Vec3(-2.1837, 0.6821, 1.4854)));
  const Mat3 yaw90 = expSO3(Vec3(0, 0, std::numbers::pi / 2));
  EXPECT_TRUE((*trajectory)[1].T_w_c.linear().isApprox(yaw90, 1e-6));
}

// A stamp that would overflow, and a position whose square would (the ATE
// came out as inf with exit 0).
TEST_F(TrajectoryIoTest, OutOfRangeStampsAndPositionsAreErrors) {
  expectLineError("9341841873.2 0 0 0 0 0 0 1\n", 1, "bad timestamp");
  expectLineError("1.0 0 0 0 0 0 0 1\n2.0 1e300 0 0 0 0 0 1\n", 2, "position field 2 is out of range");
  expectLineError("1.0 0 0 -2e6 0 0 0 1\n", 1, "position field 4 is out of range");
}

TEST_F(TrajectoryIoTest, NormalisesNearlyUnitQuaternion) {
  const std::string path = writeFile("t.txt", "1.0 0 0 0 0 0 0 1.005\n");
  const auto trajectory = readTumTrajectory(path);
  ASSERT_TRUE(trajectory.ok()) << trajectory.error();
  EXPECT_TRUE((*trajectory)[0].T_w_c.linear().isApprox(Mat3::Identity(), 1e-12));
}

TEST_F(TrajectoryIoTest, RoundTripKeepsStampsAndPoses) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> uniform(-3.0, 3.0);
  Trajectory original;
  std::int64_t ns = 1341841873'273798000LL;
  for (int k = 0; k < 50; ++k) {
    ns += 33'333'000 + k;  // microsecond resolution, as the format stores it
    ns -= ns % 1000;
    SE3 T = SE3::Identity();
    T.linear() = expSO3(Vec3(uniform(rng), uniform(rng), uniform(rng)));
    T.translation() = Vec3(uniform(rng), uniform(rng), uniform(rng));
    original.push_back({Timestamp::fromNanoseconds(ns), T});
  }
  const std::string path = (dir_ / "round.txt").string();
  ASSERT_TRUE(writeTumTrajectory(path, original).ok());
  const auto loaded = readTumTrajectory(path);
  ASSERT_TRUE(loaded.ok()) << loaded.error();
  ASSERT_EQ(loaded->size(), original.size());
  for (std::size_t k = 0; k < original.size(); ++k) {
    EXPECT_EQ((*loaded)[k].stamp, original[k].stamp);
    EXPECT_LT(((*loaded)[k].T_w_c.translation() - original[k].T_w_c.translation()).norm(), 1e-8);
    EXPECT_LT(((*loaded)[k].T_w_c.linear() - original[k].T_w_c.linear()).norm(), 1e-8);
  }
}

TEST_F(TrajectoryIoTest, MapIdsRoundTripAsCommentLines) {
  Trajectory original;
  for (int k = 0; k < 6; ++k)
    original.push_back({Timestamp::fromNanoseconds(1'000'000'000LL * (k + 1)), SE3::Identity(),
                        static_cast<std::uint32_t>(k < 2 ? 0 : k < 5 ? 1 : 3)});
  const std::string path = (dir_ / "maps.txt").string();
  ASSERT_TRUE(writeTumTrajectory(path, original).ok());
  std::ifstream in(path);
  const std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  EXPECT_NE(text.find("\n# map 1\n"), std::string::npos) << text;
  EXPECT_NE(text.find("\n# map 3\n"), std::string::npos) << text;
  EXPECT_EQ(text.find("# map 0"), std::string::npos) << text;  // a one-map file is plain TUM
  const auto loaded = readTumTrajectory(path);
  ASSERT_TRUE(loaded.ok()) << loaded.error();
  ASSERT_EQ(loaded->size(), original.size());
  for (std::size_t k = 0; k < original.size(); ++k) EXPECT_EQ((*loaded)[k].map_id, original[k].map_id) << k;
}

TEST_F(TrajectoryIoTest, WritesPositiveQw) {
  SE3 T = SE3::Identity();
  T.linear() = Eigen::Quaterniond(-0.5, 0.5, 0.5, 0.5).toRotationMatrix();
  const std::string path = (dir_ / "qw.txt").string();
  ASSERT_TRUE(writeTumTrajectory(path, {{Timestamp::fromNanoseconds(1'500'000'000), T}}).ok());
  std::ifstream in(path);
  std::string header;
  std::string line;
  std::getline(in, header);
  std::getline(in, line);
  EXPECT_EQ(line, "1.500000 0 0 0 -0.5 -0.5 -0.5 0.5");
}

TEST_F(TrajectoryIoTest, MissingFileNamesPath) {
  const std::string path = (dir_ / "does_not_exist.txt").string();
  const auto result = readTumTrajectory(path);
  ASSERT_FALSE(result.ok());
  EXPECT_NE(result.error().find(path), std::string::npos) << result.error();
}

TEST_F(TrajectoryIoTest, BadContentNamesFileAndLine) {
  const std::string good = "# header\n1.0 0 0 0 0 0 0 1\n";
  expectLineError(good + "2.0 0 0 0 0 0 1\n", 3, "expected 8 fields");
  expectLineError(good + "2.0 0 0 0 0 0 0 1 9\n", 3, "expected 8 fields");
  expectLineError(good + "2.0 0 abc 0 0 0 0 1\n", 3, "not a finite number");
  expectLineError(good + "2.0 0 0 0 0 0 0 nan\n", 3, "not a finite number");
  expectLineError(good + "2.x 0 0 0 0 0 0 1\n", 3, "bad timestamp");
  expectLineError(good + "2.0 0 0 0 0 0 0 0\n", 3, "zero quaternion");
  expectLineError(good + "2.0 0 0 0 0 0 0 1.5\n", 3, "not unit length");
  expectLineError(good + "\n1.0 0 0 0 0 0 0 1\n", 4, "not after the previous");
  expectLineError(good + "0.5 0 0 0 0 0 0 1\n", 3, "not after the previous");
}

TEST_F(TrajectoryIoTest, ReadsTheNamedColumnOfAFrameLog) {
  const std::string path = writeFile("frames.txt",
                                     "# index timestamp state health share\n"
                                     "0 1.000000 ok good 0.1\n"
                                     "\n"
                                     "1 1.033333 lost lost 0\n"
                                     "2 1.066667 ok unreliable 0.7\n");
  const auto health = readLabelColumn(path, "health");
  ASSERT_TRUE(health.ok()) << health.error();
  ASSERT_EQ(health->size(), 3u);
  EXPECT_EQ((*health)[0].label, "good");
  EXPECT_EQ((*health)[2].label, "unreliable");
  EXPECT_EQ((*health)[1].stamp, *Timestamp::parseSeconds("1.033333"));
  const auto state = readLabelColumn(path, "state");
  ASSERT_TRUE(state.ok()) << state.error();
  EXPECT_EQ((*state)[1].label, "lost");
}

TEST_F(TrajectoryIoTest, SaysWhetherAFrameLogNamesAColumn) {
  const std::string path = writeFile("frames.txt", "# index timestamp state health\n0 1.0 ok good\n");
  ASSERT_TRUE(namesColumn(path, "health").ok());
  EXPECT_TRUE(*namesColumn(path, "health"));
  EXPECT_FALSE(*namesColumn(path, "health_causes")) << "a log from before that column";
  EXPECT_FALSE(*namesColumn(path, "heal")) << "whole names only";
  const auto headless = namesColumn(writeFile("rows.txt", "0 1.0 ok good\n"), "health");
  ASSERT_FALSE(headless.ok());
  EXPECT_NE(headless.error().find("no header"), std::string::npos) << headless.error();
  EXPECT_FALSE(namesColumn((dir_ / "none.txt").string(), "health").ok());
}

TEST_F(TrajectoryIoTest, LabelTableErrorsNameFileAndLine) {
  const std::string header = "# index timestamp health\n";
  const auto expect = [&](const std::string& content, const std::string& where, const std::string& what) {
    const std::string path = writeFile("labels.txt", content);
    const auto result = readLabelColumn(path, "health");
    ASSERT_FALSE(result.ok()) << content;
    EXPECT_NE(result.error().find(path + where), std::string::npos) << result.error();
    EXPECT_NE(result.error().find(what), std::string::npos) << result.error();
  };
  expect("# index timestamp state\n0 1.0 ok\n", ":1:", "no column 'health'");
  expect("# index stamp health\n", ":1:", "no column 'timestamp'");
  expect("0 1.0 good\n", ":1:", "before the header");
  expect(header + "0 1.0\n", ":2:", "expected at least 3 fields");
  expect(header + "0 x1.0 good\n", ":2:", "bad timestamp");
  expect("", ":", "no header");
  const auto missing = readLabelColumn((dir_ / "none.txt").string(), "health");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().find("none.txt"), std::string::npos);
}

TEST_F(TrajectoryIoTest, WriteToBadPathFails) {
  const std::string path = (dir_ / "no_such_dir" / "t.txt").string();
  const Status status = writeTumTrajectory(path, {});
  ASSERT_FALSE(status.ok());
  EXPECT_NE(status.error().find(path), std::string::npos);
}

}  // namespace
}  // namespace stillpoint::eval
