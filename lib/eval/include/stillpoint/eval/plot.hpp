#pragma once
// A PNG report of one evaluation: top view of ground truth against the
// aligned estimate, and the absolute trajectory error over time.
#include <opencv2/core.hpp>

#include <limits>
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

// The top view alone, into `area` of a CV_8UC3 image (axes and labels take
// about 100 px left of and 50 px below it); `gt` may be empty.
void drawTopView(cv::Mat& image, cv::Rect area, const Trajectory& gt, const Trajectory& est,
                 const std::string& estimate_label);

// A line chart of one or more series against a shared x axis (e.g. time),
// with an optional dashed horizontal reference line.
struct Series {
  std::string label;
  std::vector<double> x, y;  // same length; non-finite values are gaps
};
struct SeriesPlot {
  std::string title, x_label, y_label;
  std::vector<Series> series;
  double reference = std::numeric_limits<double>::quiet_NaN();  // dashed line when finite
  std::string reference_label;
  int width = 1200, height = 500;
};
Status writeSeriesPlot(const std::string& png_path, const SeriesPlot& plot);

}  // namespace stillpoint::eval
