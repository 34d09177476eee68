#pragma once
// Small GoogleTest helpers shared by the slam module's tests.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <string>

#include "frame.hpp"
#include "map.hpp"

namespace stillpoint::slam::testing {

// Passes when `text` contains `part`; the failure message shows both.
inline ::testing::AssertionResult contains(const std::string& text, const std::string& part) {
  if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "\"" << text << "\" does not contain \"" << part << "\"";
}

// Pyramid constants of a single level (scale 1, sigma 1), for hand-made frames.
inline const LevelInfo& oneLevel() {
  static const LevelInfo lv = [] {
    LevelInfo l;
    l.levels = 1;
    l.scale_factor = 1.2;
    l.log_scale_factor = std::log(1.2);
    l.scales = l.sigma2 = l.inv_sigma2 = {1.0};
    return l;
  }();
  return lv;
}

// 640x480, focal length 500 px, the principal point at the centre, no
// distortion (the default 8 cm virtual baseline).
inline CameraModel vgaCamera() {
  CameraModel camera;
  camera.width = 640;
  camera.height = 480;
  camera.fx = camera.fy = 500;
  camera.cx = 320;
  camera.cy = 240;
  return camera;
}

// A keyframe with `n` features, 1 m deep, whose image positions and
// descriptors are never looked at (hand-built maps).
inline std::unique_ptr<KeyFrame> handMadeKeyFrame(std::int64_t id, int n, const SE3& T_c_w,
                                                  const CameraModel* camera = nullptr) {
  Frame f;
  f.id = id;
  f.camera = camera;
  f.levels = &oneLevel();
  f.T_c_w = T_c_w;
  f.keys.resize(n);
  f.un.resize(n);
  f.depth.assign(n, 1.0f);
  f.u_right.assign(n, -1.0f);
  f.descriptors = cv::Mat::zeros(n, 32, CV_8U);
  f.dynamic.assign(n, DynamicCause{});
  f.clearMatches();
  return std::make_unique<KeyFrame>(id, f);
}

}  // namespace stillpoint::slam::testing
