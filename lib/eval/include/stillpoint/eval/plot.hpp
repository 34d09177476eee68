#pragma once
// A PNG report of one evaluation: top view of ground truth against the
// aligned estimate, and the absolute trajectory error over time.
#include <string>
#include <vector>

#include "stillpoint/core/result.hpp"
#include "stillpoint/eval/trajectory.hpp"

namespace stillpoint::eval {

struct PlotOptions {
  int width = 1200;   // pixels
  int height = 1000;  // pixels; the top view gets about two thirds
  std::string title;  // drawn above the top view when not empty
};

// Draws the plane of the two axes along which the ground truth and estimate
// extend most (equal scale on both), and ATE per estimate pose against time
// since the first estimate pose, with the RMSE as a dashed line.
// ate_errors[k] is the error of est_aligned[k], in metres.
Status writeTrajectoryPlot(const std::string& png_path, const Trajectory& gt,
                           const Trajectory& est_aligned, const std::vector<double>& ate_errors,
                           const PlotOptions& options = {});

}  // namespace stillpoint::eval
