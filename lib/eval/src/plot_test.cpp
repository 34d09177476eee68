#include "stillpoint/eval/plot.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include <opencv2/imgcodecs.hpp>
#include <unistd.h>

namespace stillpoint::eval {
namespace {

namespace fs = std::filesystem;

Trajectory circle(double radius, int n) {
  Trajectory trajectory;
  for (int k = 0; k < n; ++k) {
    const double a = 0.05 * k;
    SE3 T = SE3::Identity();
    T.translation() = Vec3(radius * std::cos(a), 0.1 * std::sin(3 * a), radius * std::sin(a));
    trajectory.push_back({Timestamp::fromNanoseconds(1'000'000'000LL + k * 33'333'333LL), T});
  }
  return trajectory;
}

fs::path tempPng(const std::string& name) {
  return fs::temp_directory_path() /
         ("stillpoint_eval_plot_" + std::to_string(::getpid()) + "_" + name + ".png");
}

TEST(Plot, WritesReadablePng) {
  const Trajectory gt = circle(1.0, 200);
  const Trajectory est = circle(1.05, 200);
  std::vector<double> errors;
  for (int k = 0; k < 200; ++k) errors.push_back(0.05 + 0.01 * std::sin(0.1 * k));
  const fs::path path = tempPng("ok");
  PlotOptions options;
  options.title = "unit test";
  const Status status = writeTrajectoryPlot(path.string(), gt, est, errors, options);
  ASSERT_TRUE(status.ok()) << status.error();
  const cv::Mat image = cv::imread(path.string());
  ASSERT_FALSE(image.empty());
  EXPECT_EQ(image.cols, options.width);
  EXPECT_EQ(image.rows, options.height);
  fs::remove(path);
}

TEST(Plot, RejectsMismatchedErrorsAndBadPath) {
  const Trajectory gt = circle(1.0, 20);
  const fs::path path = tempPng("bad");
  const Status mismatch = writeTrajectoryPlot(path.string(), gt, gt, {0.1, 0.2});
  ASSERT_FALSE(mismatch.ok());
  EXPECT_NE(mismatch.error().find(path.string()), std::string::npos);

  const std::vector<double> errors(gt.size(), 0.0);
  const std::string unwritable = "/nonexistent_dir_for_stillpoint/plot.png";
  const Status bad_path = writeTrajectoryPlot(unwritable, gt, gt, errors);
  ASSERT_FALSE(bad_path.ok());
  EXPECT_NE(bad_path.error().find(unwritable), std::string::npos);
}

}  // namespace
}  // namespace stillpoint::eval
