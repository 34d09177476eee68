#pragma once
// Pictures of a run (stillpoint-replay --render): one image per frame with
// four panels: the colour image with every feature drawn by its fate, the
// depth clusters with the dynamic ones marked, the newest semantic masks, and
// the trajectory so far.
#include <opencv2/core.hpp>

#include <string>

#include "stillpoint/eval/trajectory.hpp"
#include "stillpoint/slam/outputs.hpp"

namespace stillpoint::render {

struct FrameInput {
  const cv::Mat* bgr = nullptr;  // CV_8UC3, or empty: `gray` is drawn
  const cv::Mat* gray = nullptr;  // CV_8UC1
  const slam::TrackOutput* out = nullptr;
  std::size_t index = 0;           // frame number in the sequence
  const eval::Trajectory* estimate = nullptr;  // live poses so far (map frame)
  bool geometry_enabled = false;
  bool semantic_enabled = false;
};

// The picture (2 x 2 panels, each the camera's size). Never throws: a panel
// that cannot be drawn says so in its caption.
cv::Mat renderFrame(const FrameInput& in);

// The colour of a fate in the pictures (BGR) and its legend name.
cv::Scalar fateColour(slam::FeatureFate fate);

}  // namespace stillpoint::render
