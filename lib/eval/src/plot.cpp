#include "stillpoint/eval/plot.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace stillpoint::eval {
namespace {

const cv::Scalar kWhite(255, 255, 255);
const cv::Scalar kBlack(0, 0, 0);
const cv::Scalar kGrid(225, 225, 225);
const cv::Scalar kGroundTruthColor(40, 40, 40);
const cv::Scalar kEstimateColor(200, 90, 20);  // BGR: blue
const cv::Scalar kErrorColor(30, 30, 210);     // BGR: red
constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;
constexpr double kTextScale = 0.5;
constexpr double kTitleScale = 0.65;
// Lines are not drawn across gaps longer than this (e.g. tracking lost).
constexpr double kMaxGapS = 1.0;

struct Range {
  double lo = std::numeric_limits<double>::infinity();
  double hi = -std::numeric_limits<double>::infinity();
  void add(double v) {
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  double span() const { return hi - lo; }
  double mid() const { return 0.5 * (lo + hi); }
};

// Data window mapped onto a pixel rectangle; y grows upwards in data space.
struct Axes {
  cv::Rect area;
  Range x;
  Range y;
  cv::Point toPixel(double vx, double vy) const {
    const double u = area.x + (vx - x.lo) / x.span() * area.width;
    const double v = area.y + area.height - (vy - y.lo) / y.span() * area.height;
    return {static_cast<int>(std::lround(u)), static_cast<int>(std::lround(v))};
  }
};

// Round step (1, 2 or 5 times a power of ten) giving about `target` ticks.
double niceStep(double span, int target) {
  const double raw = span / target;
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw)));
  const double fraction = raw / magnitude;
  const double nice = fraction < 1.5 ? 1.0 : fraction < 3.5 ? 2.0 : fraction < 7.5 ? 5.0 : 10.0;
  return nice * magnitude;
}

std::string formatTick(double value, double step) {
  const int decimals = std::max(0, static_cast<int>(-std::floor(std::log10(step) + 1e-9)));
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.*f", decimals, std::abs(value) < step * 1e-6 ? 0.0 : value);
  return buf;
}

void putText(cv::Mat& image, const std::string& text, cv::Point origin, double scale = kTextScale,
             const cv::Scalar& color = kBlack, int thickness = 1) {
  cv::putText(image, text, origin, kFont, scale, color, thickness, cv::LINE_AA);
}

cv::Size textSize(const std::string& text, double scale = kTextScale, int thickness = 1) {
  int baseline = 0;
  return cv::getTextSize(text, kFont, scale, thickness, &baseline);
}

// Text rotated by 90 degrees (reading upwards), centred on `centre`.
void putVerticalText(cv::Mat& image, const std::string& text, cv::Point centre) {
  const cv::Size size = textSize(text);
  cv::Mat strip(size.height + 8, size.width + 4, image.type(), kWhite);
  putText(strip, text, {2, size.height + 2});
  cv::Mat rotated;
  cv::rotate(strip, rotated, cv::ROTATE_90_COUNTERCLOCKWISE);
  cv::Rect target(centre.x - rotated.cols / 2, centre.y - rotated.rows / 2, rotated.cols,
                  rotated.rows);
  target &= cv::Rect(0, 0, image.cols, image.rows);
  if (target.area() > 0) {
    rotated(cv::Rect(0, 0, target.width, target.height)).copyTo(image(target));
  }
}

void drawAxes(cv::Mat& image, const Axes& axes, const std::string& x_label,
              const std::string& y_label) {
  const double x_step = niceStep(axes.x.span(), std::max(3, axes.area.width / 110));
  const double y_step = niceStep(axes.y.span(), std::max(3, axes.area.height / 70));
  const int bottom = axes.area.y + axes.area.height;
  const int left = axes.area.x;
  for (double v = std::ceil(axes.x.lo / x_step) * x_step; v <= axes.x.hi + 1e-9 * x_step;
       v += x_step) {
    const int px = axes.toPixel(v, axes.y.lo).x;
    cv::line(image, {px, axes.area.y}, {px, bottom}, kGrid, 1);
    cv::line(image, {px, bottom}, {px, bottom + 5}, kBlack, 1);
    const std::string label = formatTick(v, x_step);
    putText(image, label, {px - textSize(label).width / 2, bottom + 20});
  }
  int widest_y_label = 0;
  for (double v = std::ceil(axes.y.lo / y_step) * y_step; v <= axes.y.hi + 1e-9 * y_step;
       v += y_step) {
    const int py = axes.toPixel(axes.x.lo, v).y;
    cv::line(image, {left, py}, {left + axes.area.width, py}, kGrid, 1);
    cv::line(image, {left - 5, py}, {left, py}, kBlack, 1);
    const std::string label = formatTick(v, y_step);
    const cv::Size size = textSize(label);
    widest_y_label = std::max(widest_y_label, size.width);
    putText(image, label, {left - 8 - size.width, py + size.height / 2});
  }
  cv::rectangle(image, axes.area, kBlack, 1);
  putText(image, x_label,
          {left + axes.area.width / 2 - textSize(x_label).width / 2, bottom + 42});
  putVerticalText(image, y_label, {left - widest_y_label - 24, axes.area.y + axes.area.height / 2});
}

// Polyline through consecutive points, broken across time gaps.
void drawSeries(cv::Mat& image, const std::vector<cv::Point>& points,
                const std::vector<double>& times, const cv::Scalar& color, int thickness) {
  for (std::size_t k = 1; k < points.size(); ++k) {
    if (times[k] - times[k - 1] > kMaxGapS) continue;
    cv::line(image, points[k - 1], points[k], color, thickness, cv::LINE_AA);
  }
  if (points.size() == 1) cv::circle(image, points[0], 2, color, cv::FILLED, cv::LINE_AA);
}

void drawDashedLine(cv::Mat& image, cv::Point a, cv::Point b, const cv::Scalar& color) {
  const double length = std::hypot(b.x - a.x, b.y - a.y);
  const int dashes = std::max(1, static_cast<int>(length / 12.0));
  for (int k = 0; k < dashes; k += 2) {
    const double s0 = static_cast<double>(k) / dashes;
    const double s1 = std::min(1.0, static_cast<double>(k + 1) / dashes);
    cv::line(image, a + (b - a) * s0, a + (b - a) * s1, color, 1, cv::LINE_AA);
  }
}

struct LegendEntry {
  enum class Style { kLine, kDashed, kCircle };
  std::string label;
  cv::Scalar color;
  Style style = Style::kLine;
};

void drawLegend(cv::Mat& image, cv::Point top_left, const std::vector<LegendEntry>& entries) {
  int width = 0;
  for (const LegendEntry& entry : entries) width = std::max(width, textSize(entry.label).width);
  const cv::Rect box(top_left.x, top_left.y, width + 56, static_cast<int>(entries.size()) * 22 + 10);
  cv::rectangle(image, box, kWhite, cv::FILLED);
  cv::rectangle(image, box, kBlack, 1);
  for (std::size_t k = 0; k < entries.size(); ++k) {
    const LegendEntry& entry = entries[k];
    const int y = box.y + 18 + static_cast<int>(k) * 22;
    const cv::Point a(box.x + 8, y - 4);
    const cv::Point b(box.x + 38, y - 4);
    switch (entry.style) {
      case LegendEntry::Style::kLine: cv::line(image, a, b, entry.color, 2, cv::LINE_AA); break;
      case LegendEntry::Style::kDashed: drawDashedLine(image, a, b, entry.color); break;
      case LegendEntry::Style::kCircle:
        cv::circle(image, (a + b) / 2, 5, entry.color, 2, cv::LINE_AA);
        break;
    }
    putText(image, entry.label, {box.x + 46, y});
  }
}

Status writePng(const std::string& png_path, const cv::Mat& image) {
  try {
    if (!cv::imwrite(png_path, image)) return Error{png_path + ": could not write image"};
  } catch (const cv::Exception& e) {
    return Error{png_path + ": could not write image: " + e.what()};
  }
  return Status::success();
}

// Pads a range by `fraction` of its span, and gives an empty range a span.
Range padded(Range r, double fraction, double min_span) {
  if (!(r.span() > min_span)) {
    const double mid = std::isfinite(r.mid()) ? r.mid() : 0.0;
    return {mid - 0.5 * min_span, mid + 0.5 * min_span};
  }
  const double pad = fraction * r.span();
  return {r.lo - pad, r.hi + pad};
}

}  // namespace

void drawTopView(cv::Mat& image, cv::Rect area, const Trajectory& gt, const Trajectory& est,
                 const std::string& estimate_label) {
  // The two axes of largest extent form the viewing plane.
  std::array<Range, 3> extent;
  for (const Trajectory* trajectory : {&gt, &est}) {
    for (const StampedPose& pose : *trajectory) {
      for (int a = 0; a < 3; ++a) extent[a].add(pose.T_w_c.translation()[a]);
    }
  }
  std::array<int, 3> order{0, 1, 2};
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
    return extent[a].span() > extent[b].span();
  });
  const int ax = std::min(order[0], order[1]);
  const int ay = std::max(order[0], order[1]);

  Axes axes;
  axes.area = area;
  axes.x = padded(extent[ax], 0.05, 1e-3);
  axes.y = padded(extent[ay], 0.05, 1e-3);
  // Equal metres per pixel on both axes: widen the tighter range.
  const double scale = std::max(axes.x.span() / area.width, axes.y.span() / area.height);
  const double half_x = 0.5 * scale * area.width;
  const double half_y = 0.5 * scale * area.height;
  axes.x = {axes.x.mid() - half_x, axes.x.mid() + half_x};
  axes.y = {axes.y.mid() - half_y, axes.y.mid() + half_y};

  const char* names[3] = {"x", "y", "z"};
  drawAxes(image, axes, std::string(names[ax]) + " [m]", std::string(names[ay]) + " [m]");
  for (const auto& [trajectory, color, thickness] :
       {std::tuple{&gt, kGroundTruthColor, 2}, std::tuple{&est, kEstimateColor, 1}}) {
    std::vector<cv::Point> points;
    std::vector<double> times;
    for (const StampedPose& pose : *trajectory) {
      const Vec3 p = pose.T_w_c.translation();
      points.push_back(axes.toPixel(p[ax], p[ay]));
      times.push_back(pose.stamp.seconds());
    }
    drawSeries(image, points, times, color, thickness);
    if (!points.empty()) cv::circle(image, points.front(), 5, color, 2, cv::LINE_AA);
  }
  std::vector<LegendEntry> legend;
  if (!gt.empty()) legend.push_back({"ground truth", kGroundTruthColor});
  legend.push_back({estimate_label, kEstimateColor});
  legend.push_back({"start", kBlack, LegendEntry::Style::kCircle});
  drawLegend(image, {area.x + 10, area.y + 10}, legend);
}

namespace {

void drawErrorPanel(cv::Mat& image, cv::Rect area, const Trajectory& est,
                    const std::vector<double>& errors) {
  Range t_range;
  Range e_range;
  e_range.add(0.0);
  double sum_sq = 0.0;
  const double t0 = est.empty() ? 0.0 : est.front().stamp.seconds();
  std::vector<double> times;
  for (std::size_t k = 0; k < est.size(); ++k) {
    times.push_back(est[k].stamp.seconds() - t0);
    t_range.add(times.back());
    e_range.add(errors[k]);
    sum_sq += errors[k] * errors[k];
  }
  Axes axes;
  axes.area = area;
  axes.x = padded(t_range, 0.0, 1.0);
  axes.y = {0.0, e_range.hi > 0.0 ? 1.1 * e_range.hi : 1e-3};
  drawAxes(image, axes, "time since first estimate pose [s]", "ATE [m]");

  std::vector<cv::Point> points;
  for (std::size_t k = 0; k < est.size(); ++k) points.push_back(axes.toPixel(times[k], errors[k]));
  drawSeries(image, points, times, kErrorColor, 1);
  if (!errors.empty()) {
    const double rmse = std::sqrt(sum_sq / static_cast<double>(errors.size()));
    drawDashedLine(image, axes.toPixel(axes.x.lo, rmse), axes.toPixel(axes.x.hi, rmse), kBlack);
    char label[64];
    std::snprintf(label, sizeof(label), "RMSE %.4f m", rmse);
    drawLegend(image, {area.x + 10, area.y + 10},
               {{"ATE per pose", kErrorColor}, {label, kBlack, LegendEntry::Style::kDashed}});
  }
}

}  // namespace

Status writeTrajectoryPlot(const std::string& png_path, const Trajectory& gt,
                           const Trajectory& est_aligned, const std::vector<double>& ate_errors,
                           const PlotOptions& options) {
  if (ate_errors.size() != est_aligned.size()) {
    return Error{png_path + ": plot needs one ATE value per estimate pose (" +
                 std::to_string(ate_errors.size()) + " for " +
                 std::to_string(est_aligned.size()) + " poses)"};
  }
  if (gt.empty() && est_aligned.empty()) return Error{png_path + ": nothing to plot"};
  if (options.width < 400 || options.height < 400) {
    return Error{png_path + ": plot must be at least 400x400 pixels"};
  }
  for (double e : ate_errors) {
    if (!std::isfinite(e)) return Error{png_path + ": non-finite ATE value"};
  }

  cv::Mat image(options.height, options.width, CV_8UC3, kWhite);
  constexpr int kLeft = 95;
  constexpr int kRight = 25;
  const int title_height = options.title.empty() ? 15 : 40;
  const int top_height = options.height * 2 / 3;
  if (!options.title.empty()) {
    putText(image, options.title,
            {options.width / 2 - textSize(options.title, kTitleScale).width / 2, 27},
            kTitleScale);
  }
  const cv::Rect top_area(kLeft, title_height, options.width - kLeft - kRight,
                          top_height - title_height - 55);
  const cv::Rect bottom_area(kLeft, top_height + 15, options.width - kLeft - kRight,
                             options.height - top_height - 15 - 55);
  drawTopView(image, top_area, gt, est_aligned, "estimate (aligned)");
  drawErrorPanel(image, bottom_area, est_aligned, ate_errors);

  return writePng(png_path, image);
}

Status writeSeriesPlot(const std::string& png_path, const SeriesPlot& plot) {
  if (plot.width < 400 || plot.height < 300) return Error{png_path + ": plot must be at least 400x300 pixels"};
  Range x_range, y_range;
  for (const Series& s : plot.series) {
    if (s.x.size() != s.y.size())
      return Error{png_path + ": series '" + s.label + "' has " + std::to_string(s.x.size()) + " x and " +
                   std::to_string(s.y.size()) + " y values"};
    for (std::size_t k = 0; k < s.x.size(); ++k) {
      if (!std::isfinite(s.x[k]) || !std::isfinite(s.y[k])) continue;
      x_range.add(s.x[k]);
      y_range.add(s.y[k]);
    }
  }
  if (!(x_range.span() >= 0)) return Error{png_path + ": nothing to plot"};
  if (std::isfinite(plot.reference)) y_range.add(plot.reference);
  y_range.add(0.0);

  static const cv::Scalar kPalette[] = {kEstimateColor, kErrorColor, cv::Scalar(40, 150, 40), cv::Scalar(150, 40, 150),
                                        cv::Scalar(20, 140, 200), kGroundTruthColor};
  cv::Mat image(plot.height, plot.width, CV_8UC3, kWhite);
  const int title_height = plot.title.empty() ? 15 : 40;
  if (!plot.title.empty())
    putText(image, plot.title, {plot.width / 2 - textSize(plot.title, kTitleScale).width / 2, 27}, kTitleScale);
  Axes axes;
  axes.area = cv::Rect(95, title_height, plot.width - 95 - 25, plot.height - title_height - 55);
  axes.x = padded(x_range, 0.0, 1.0);
  axes.y = {std::min(0.0, y_range.lo), y_range.hi > 0.0 ? 1.1 * y_range.hi : 1.0};
  drawAxes(image, axes, plot.x_label, plot.y_label);
  std::vector<LegendEntry> legend;
  for (std::size_t k = 0; k < plot.series.size(); ++k) {
    const Series& s = plot.series[k];
    const cv::Scalar color = kPalette[k % std::size(kPalette)];
    // Non-finite values break the line, as a gap in time does.
    std::vector<cv::Point> points;
    std::vector<double> times;
    auto flush = [&] {
      drawSeries(image, points, times, color, 1);
      points.clear();
      times.clear();
    };
    for (std::size_t i = 0; i < s.x.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) {
        flush();
        continue;
      }
      points.push_back(axes.toPixel(s.x[i], s.y[i]));
      times.push_back(0.0);  // only non-finite values break a series here
    }
    flush();
    legend.push_back({s.label, color});
  }
  if (std::isfinite(plot.reference)) {
    drawDashedLine(image, axes.toPixel(axes.x.lo, plot.reference), axes.toPixel(axes.x.hi, plot.reference), kBlack);
    legend.push_back({plot.reference_label, kBlack, LegendEntry::Style::kDashed});
  }
  if (!legend.empty()) drawLegend(image, {axes.area.x + 10, axes.area.y + 10}, legend);
  return writePng(png_path, image);
}

}  // namespace stillpoint::eval
