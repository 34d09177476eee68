// stillpoint-eval: ATE and RPE of an estimated trajectory against ground truth,
// both in TUM format. Prints one machine-readable line to stdout.
#include <charconv>
#include <cmath>
#include <cstdio>
#include <string>
#include <string_view>
#include <vector>

#include "stillpoint/core/program.hpp"
#include "stillpoint/eval/metrics.hpp"
#include "stillpoint/eval/plot.hpp"
#include "stillpoint/eval/trajectory.hpp"

namespace {

constexpr int kExitBadInput = 1;
constexpr int kExitUsage = 2;

constexpr const char* kUsage =
    "usage: stillpoint-eval GROUNDTRUTH.txt TRAJ.txt [--plot OUT.png] [--max-dt S]\n"
    "                       [--frame-log FRAMES.txt [--drift-window S]]\n"
    "\n"
    "Evaluates an estimated trajectory against ground truth (TUM format:\n"
    "'timestamp tx ty tz qx qy qz qw' per line) and prints one line:\n"
    "  ate_rmse_m=<v> rpe_trans_m_s=<v> rpe_rot_deg_s=<v> matched=<n>\n"
    "\n"
    "  ate_rmse_m     RMSE of position error after rigid (SE3) alignment [m]\n"
    "  rpe_trans_m_s  RMSE of relative translation error over 1 s pose pairs,\n"
    "                 divided by each pair's time difference [m/s]\n"
    "  rpe_rot_deg_s  same for the relative rotation angle [deg/s]\n"
    "  matched        estimate poses associated with a ground-truth pose\n"
    "RPE values are nan when the matched poses span less than 1 s.\n"
    "\n"
    "An estimate of several maps ('# map N' lines: a SLAM system that started\n"
    "a new map after a loss) is aligned map by map, each in its own frame, and\n"
    "one more line says how far off its poses are all taken in one frame, as\n"
    "a consumer that ignores the map id takes them:\n"
    "  maps=<n> ate_one_frame_rmse_m=<v> unaligned=<n>\n"
    "  unaligned      matched poses of maps too short to align on their own\n"
    "                 (counted in the one-frame error only)\n"
    "\n"
    "With --frame-log (stillpoint-replay's), one more line per pose health\n"
    "level, good, degraded, unreliable (then any other, '-' for poses with no\n"
    "frame), saying how far its poses were off:\n"
    "  health=<level> poses=<n> drift_median_m=<v> drift_p90_m=<v>\n"
    "  drift_max_m=<v> over_2cm=<share>\n"
    "  drift  translation error of the motion over the last --drift-window\n"
    "         seconds (default 0.333, 10 frames at 30 Hz) up to the pose, in\n"
    "         its map [m]; poses without a pose that far back in their map\n"
    "         are not counted\n"
    "When the frame log has the health_causes column, one more line per cause\n"
    "(none, few_inliers, view_moving, ...: docs/pose-health.md), a pose counted\n"
    "under each of its causes:\n"
    "  cause=<name> poses=<n> drift_median_m=<v> drift_p90_m=<v> drift_max_m=<v>\n"
    "  over_2cm=<share>\n"
    "When it has the covariance column, one more line per pose health level\n"
    "and one for all poses, saying how well the poses' covariances cover that\n"
    "drift (docs/pose-health.md, \"The covariance\"):\n"
    "  covariance=<level|all> poses=<n> position_within_95=<share>\n"
    "  position_median=<v> rotation_within_95=<share> rotation_median=<v>\n"
    "  within_95  share of drifts inside the covariance's 95 % ellipsoid\n"
    "  median     median squared drift over the covariance, over a\n"
    "             Gaussian's: 1 as wide as it should be, above 1 too narrow\n"
    "\n"
    "options:\n"
    "  --plot OUT.png  also write a top view and ATE-over-time plot\n"
    "  --max-dt S      association window in seconds (default 0.02)\n"
    "  --frame-log F   the replay's frame log: drift per pose health level\n"
    "  --drift-window S  the drift's time window in seconds (default 0.333)\n"
    "  --help          show this text\n"
    "  --version       print the version and architecture\n"
    "\n"
    "exit status: 0 ok, 1 bad input or evaluation failed, 2 usage error\n";

int usageError(const std::string& message) {
  std::fprintf(stderr, "stillpoint-eval: %s\n%s", message.c_str(), kUsage);
  return kExitUsage;
}

int inputError(const std::string& message) {
  std::fprintf(stderr, "stillpoint-eval: %s\n", message.c_str());
  return kExitBadInput;
}

bool parseSeconds(std::string_view text, double* out) {
  const char* end = text.data() + text.size();
  const auto [ptr, ec] = std::from_chars(text.data(), end, *out);
  return ec == std::errc() && ptr == end && std::isfinite(*out);
}

}  // namespace

static int evalMain(int argc, char** argv) {
  using namespace stillpoint::eval;

  std::vector<std::string> positional;
  std::string plot_path, frame_log;
  EvalOptions options;
  DriftOptions drift_options = poseHealthDriftOptions();
  for (int k = 1; k < argc; ++k) {
    const std::string_view arg = argv[k];
    if (arg == "--help" || arg == "-h") {
      std::fputs(kUsage, stdout);
      return 0;
    }
    if (arg == "--version") {
      std::puts("stillpoint-eval " STILLPOINT_VERSION " (" STILLPOINT_ARCH ")");
      return 0;
    }
    if (arg == "--plot" || arg == "--max-dt" || arg == "--frame-log" || arg == "--drift-window") {
      if (k + 1 >= argc) return usageError(std::string(arg) + " needs a value");
      const std::string_view value = argv[++k];
      if (arg == "--plot") {
        plot_path = value;
      } else if (arg == "--frame-log") {
        frame_log = value;
      } else if (arg == "--drift-window") {
        if (!parseSeconds(value, &drift_options.window_s) || drift_options.window_s <= 0.0)
          return usageError("--drift-window needs a number of seconds > 0, got '" + std::string(value) + "'");
      } else if (!parseSeconds(value, &options.max_dt_s) || options.max_dt_s < 0.0) {
        return usageError("--max-dt needs a number of seconds >= 0, got '" + std::string(value) +
                          "'");
      }
      continue;
    }
    if (arg.size() > 1 && arg.front() == '-') {
      return usageError("unknown option '" + std::string(arg) + "'");
    }
    positional.emplace_back(arg);
  }
  if (positional.size() != 2) {
    return usageError("expected GROUNDTRUTH.txt and TRAJ.txt, got " +
                      std::to_string(positional.size()) + " file arguments");
  }

  const auto gt = readTumTrajectory(positional[0]);
  if (!gt) return inputError(gt.error());
  const auto est = readTumTrajectory(positional[1]);
  if (!est) return inputError(est.error());

  const auto result = evaluate(*gt, *est, options);
  if (!result) return inputError(result.error());
  std::vector<LabelDrift> drift, by_cause;
  std::vector<CovarianceCoverage> coverage;
  if (!frame_log.empty()) {
    const auto health = readLabelColumn(frame_log, "health");
    if (!health) return inputError(health.error());
    drift_options.max_dt_s = options.max_dt_s;
    auto by_level = driftByLabel(*result, *health, drift_options);
    if (!by_level) return inputError(by_level.error());
    drift = std::move(*by_level);
    const auto has_causes = namesColumn(frame_log, "health_causes");
    if (!has_causes) return inputError(has_causes.error());
    if (*has_causes) {
      const auto causes = readLabelColumn(frame_log, "health_causes");
      if (!causes) return inputError(causes.error());
      DriftOptions cause_options = healthCauseDriftOptions();
      cause_options.window_s = drift_options.window_s;
      cause_options.max_dt_s = drift_options.max_dt_s;
      const auto per_pose = driftPerPose(*result, *causes, cause_options);
      if (!per_pose) return inputError(per_pose.error());
      by_cause = summariseDrift(splitLabels(*per_pose), cause_options);
    }
    const auto has_covariance = namesColumn(frame_log, "covariance");
    if (!has_covariance) return inputError(has_covariance.error());
    if (*has_covariance) {
      const auto covariances = readCovarianceColumn(frame_log);
      if (!covariances) return inputError(covariances.error());
      const auto per_pose = normalisedDriftPerPose(*result, *est, *covariances, *health, drift_options);
      if (!per_pose) return inputError(per_pose.error());
      coverage = summariseCoverage(*per_pose, drift_options);
    }
  }

  if (!plot_path.empty()) {
    std::vector<double> errors;
    errors.reserve(result->pose_errors.size());
    for (const PoseError& e : result->pose_errors) errors.push_back(e.ate_m);
    PlotOptions plot_options;
    char title[160];
    std::snprintf(title, sizeof(title), "ATE RMSE %.4f m, RPE %.4f m/s %.3f deg/s, %zu poses",
                  result->ate_rmse_m, result->rpe_trans_m_s, result->rpe_rot_deg_s,
                  result->matched);
    plot_options.title = title;
    const auto status =
        writeTrajectoryPlot(plot_path, *gt, result->est_aligned, errors, plot_options);
    if (!status) return inputError(status.error());
  }

  std::printf("ate_rmse_m=%.6f rpe_trans_m_s=%.6f rpe_rot_deg_s=%.6f matched=%zu\n",
              result->ate_rmse_m, result->rpe_trans_m_s, result->rpe_rot_deg_s, result->matched);
  if (result->maps > 1)
    std::printf("maps=%zu ate_one_frame_rmse_m=%.6f unaligned=%zu\n", result->maps, result->ate_one_frame_rmse_m,
                result->unaligned);
  for (const LabelDrift& d : drift) {
    std::printf("health=%s poses=%zu drift_median_m=%.6f drift_p90_m=%.6f drift_max_m=%.6f over_2cm=%.4f\n",
                d.label.c_str(), d.poses, d.median_m, d.p90_m, d.max_m, d.share_over_bound);
  }
  for (const LabelDrift& d : by_cause) {
    std::printf("cause=%s poses=%zu drift_median_m=%.6f drift_p90_m=%.6f drift_max_m=%.6f over_2cm=%.4f\n",
                d.label.c_str(), d.poses, d.median_m, d.p90_m, d.max_m, d.share_over_bound);
  }
  for (const CovarianceCoverage& c : coverage) {
    std::printf("covariance=%s poses=%zu position_within_95=%.4f position_median=%.3f rotation_within_95=%.4f "
                "rotation_median=%.3f\n",
                c.label.c_str(), c.poses, c.position_within, c.position_median, c.rotation_within, c.rotation_median);
  }
  return 0;
}

int main(int argc, char** argv) { return stillpoint::runProgram("stillpoint-eval", evalMain, argc, argv); }
