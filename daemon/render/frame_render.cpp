#include "frame_render.hpp"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <array>
#include <cstdio>

#include "stillpoint/eval/plot.hpp"

namespace stillpoint::render {
namespace {

const cv::Scalar kWhite(255, 255, 255);
const cv::Scalar kBlack(0, 0, 0);
constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;

// A caption bar at the top of a panel, white on black for any background.
void caption(cv::Mat& panel, const std::string& text, int line = 0) {
  int baseline = 0;
  const cv::Size size = cv::getTextSize(text, kFont, 0.5, 1, &baseline);
  const cv::Rect bar(0, line * 22, std::min(panel.cols, size.width + 12), 22);
  cv::rectangle(panel, bar, kBlack, cv::FILLED);
  cv::putText(panel, text, {6, line * 22 + 16}, kFont, 0.5, kWhite, 1, cv::LINE_AA);
}

cv::Mat background(const FrameInput& in, cv::Size size) {
  cv::Mat bgr;
  if (in.bgr && !in.bgr->empty() && in.bgr->type() == CV_8UC3)
    bgr = in.bgr->clone();
  else if (in.gray && !in.gray->empty() && in.gray->type() == CV_8UC1)
    cv::cvtColor(*in.gray, bgr, cv::COLOR_GRAY2BGR);
  else
    bgr = cv::Mat(size, CV_8UC3, cv::Scalar(60, 60, 60));
  if (bgr.size() != size) cv::resize(bgr, bgr, size);
  return bgr;
}

// Faded grey copy: what is drawn over it stands out.
cv::Mat faded(const FrameInput& in, cv::Size size) {
  cv::Mat bgr = background(in, size), gray;
  cv::cvtColor(bgr, gray, cv::COLOR_BGR2GRAY);
  cv::cvtColor(gray, bgr, cv::COLOR_GRAY2BGR);
  bgr.convertTo(bgr, -1, 0.5, 90);
  return bgr;
}

// Distinct colours for labels 0.. (golden-angle hues).
cv::Vec3b labelColour(int label) {
  cv::Mat hsv(1, 1, CV_8UC3, cv::Scalar((label * 137) % 180, 200, 230)), bgr;
  cv::cvtColor(hsv, bgr, cv::COLOR_HSV2BGR);
  return bgr.at<cv::Vec3b>(0, 0);
}

cv::Mat featurePanel(const FrameInput& in, cv::Size size) {
  cv::Mat panel = background(in, size);
  const slam::TrackOutput& out = *in.out;
  std::array<int, 5> counts{};
  // Unused and no-depth features first: the fates that matter are drawn on top.
  for (const slam::FeatureFate pass : {slam::FeatureFate::kUnused, slam::FeatureFate::kNoDepth,
                                       slam::FeatureFate::kInPose, slam::FeatureFate::kSemanticDynamic,
                                       slam::FeatureFate::kGeometryDynamic}) {
    for (const slam::FeatureView& f : out.fates) {
      if (f.fate != pass) continue;
      ++counts[static_cast<int>(f.fate)];
      const cv::Point p(cvRound(f.u), cvRound(f.v));
      const cv::Scalar c = fateColour(f.fate);
      switch (f.fate) {
        case slam::FeatureFate::kUnused: cv::circle(panel, p, 1, c, cv::FILLED); break;
        case slam::FeatureFate::kNoDepth: cv::drawMarker(panel, p, c, cv::MARKER_TILTED_CROSS, 5, 1); break;
        default: cv::circle(panel, p, 3, c, 2, cv::LINE_AA); break;
      }
    }
  }
  char text[160];
  std::snprintf(text, sizeof(text), "frame %zu  %s%s", in.index, slam::toString(out.state),
                out.new_keyframe ? "  new keyframe" : "");
  caption(panel, text);
  int line = 1;
  for (const slam::FeatureFate fate : {slam::FeatureFate::kInPose, slam::FeatureFate::kGeometryDynamic,
                                       slam::FeatureFate::kSemanticDynamic, slam::FeatureFate::kNoDepth,
                                       slam::FeatureFate::kUnused}) {
    std::snprintf(text, sizeof(text), "%4d %s", counts[static_cast<int>(fate)], slam::toString(fate));
    caption(panel, text, line);
    cv::circle(panel, {panel.cols - 14, line * 22 + 11}, 5, fateColour(fate), cv::FILLED);
    ++line;
  }
  return panel;
}

cv::Mat clusterPanel(const FrameInput& in, cv::Size size) {
  cv::Mat panel = faded(in, size);
  const slam::GeometryOutput& g = in.out->geometry;
  if (!in.geometry_enabled) {
    caption(panel, "depth clusters: geometry module off");
    return panel;
  }
  if (!g.labels || g.labels->labels.empty()) {
    caption(panel, g.deadline_missed ? "depth clusters: not ready in time" : "depth clusters: none (no depth?)");
    return panel;
  }
  const geometry::DepthClusters& dc = *g.labels;
  cv::Mat overlay = panel.clone();
  const int step = std::max(1, dc.step);
  for (int r = 0; r < dc.labels.rows; ++r) {
    for (int c = 0; c < dc.labels.cols; ++c) {
      const int label = dc.labels.at<std::int16_t>(r, c);
      if (label == geometry::DepthClusters::kNoLabel) continue;
      const bool dynamic = label < static_cast<int>(g.scores.size()) && g.scores[label].dynamic;
      const cv::Vec3b colour = dynamic ? cv::Vec3b(30, 30, 230) : labelColour(label);
      cv::rectangle(overlay, cv::Rect(c * step, r * step, step, step), cv::Scalar(colour[0], colour[1], colour[2]),
                    cv::FILLED);
    }
  }
  cv::addWeighted(overlay, 0.6, panel, 0.4, 0, panel);
  char text[160];
  std::snprintf(text, sizeof(text), "depth clusters: %d, %d dynamic (red)%s", g.clusters, g.dynamic_clusters,
                g.ran ? "" : ", not judged");
  caption(panel, text);
  return panel;
}

cv::Mat maskPanel(const FrameInput& in, cv::Size size) {
  cv::Mat panel = faded(in, size);
  const slam::TrackOutput& out = *in.out;
  if (!in.semantic_enabled) {
    caption(panel, "semantic masks: semantic module off");
    return panel;
  }
  if (!out.semantic_labels || out.semantic_labels->empty()) {
    caption(panel, "semantic masks: no keyframe segmented yet");
    return panel;
  }
  const cv::Mat& labels = *out.semantic_labels;
  cv::Mat overlay = panel.clone();
  int instances = 0;
  for (int r = 0; r < std::min(labels.rows, panel.rows); ++r) {
    for (int c = 0; c < std::min(labels.cols, panel.cols); ++c) {
      const int label = labels.at<std::uint8_t>(r, c);
      if (label == 0) continue;
      instances = std::max(instances, label);
      overlay.at<cv::Vec3b>(r, c) = labelColour(label + 3);
    }
  }
  cv::addWeighted(overlay, 0.6, panel, 0.4, 0, panel);
  // Where the masks acted in this frame: its features kept out by them.
  for (const slam::FeatureView& f : out.fates)
    if (f.fate == slam::FeatureFate::kSemanticDynamic)
      cv::circle(panel, {cvRound(f.u), cvRound(f.v)}, 3, fateColour(f.fate), 2, cv::LINE_AA);
  char text[160];
  std::snprintf(text, sizeof(text), "semantic masks of the keyframe at %s s (%d instances)",
                out.semantic_stamp.toSecondsString().c_str(), instances);
  caption(panel, text);
  return panel;
}

cv::Mat trajectoryPanel(const FrameInput& in, cv::Size size) {
  cv::Mat panel(size, CV_8UC3, kWhite);
  if (!in.estimate || in.estimate->empty()) {
    caption(panel, "trajectory: no pose yet");
    return panel;
  }
  const cv::Rect area(90, 30, std::max(10, size.width - 90 - 15), std::max(10, size.height - 30 - 55));
  const eval::Trajectory none;
  eval::drawTopView(panel, area, none, *in.estimate, "estimate (map frame)");
  caption(panel, "trajectory so far (" + std::to_string(in.estimate->size()) + " poses)");
  return panel;
}

}  // namespace

cv::Scalar fateColour(slam::FeatureFate fate) {
  switch (fate) {
    case slam::FeatureFate::kInPose: return {60, 200, 60};             // green
    case slam::FeatureFate::kGeometryDynamic: return {40, 40, 240};    // red
    case slam::FeatureFate::kSemanticDynamic: return {230, 60, 230};   // magenta
    case slam::FeatureFate::kNoDepth: return {0, 220, 255};            // yellow
    case slam::FeatureFate::kUnused: return {170, 170, 170};           // grey
  }
  return kWhite;
}

cv::Mat renderFrame(const FrameInput& in) {
  cv::Size size(640, 480);
  if (in.gray && !in.gray->empty()) size = in.gray->size();
  else if (in.bgr && !in.bgr->empty()) size = in.bgr->size();
  cv::Mat image(size.height * 2, size.width * 2, CV_8UC3, kWhite);
  try {
    featurePanel(in, size).copyTo(image(cv::Rect(0, 0, size.width, size.height)));
    clusterPanel(in, size).copyTo(image(cv::Rect(size.width, 0, size.width, size.height)));
    maskPanel(in, size).copyTo(image(cv::Rect(0, size.height, size.width, size.height)));
    trajectoryPanel(in, size).copyTo(image(cv::Rect(size.width, size.height, size.width, size.height)));
  } catch (const cv::Exception& e) {
    caption(image, std::string("could not draw this frame: ") + e.what());
  }
  return image;
}

}  // namespace stillpoint::render
