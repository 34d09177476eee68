#pragma once
// Pinhole camera with radial-tangential distortion (k1 k2 p1 p2 k3, OpenCV
// convention) and a depth image scale. Loaded from YAML or from a TUM preset.
#include <array>
#include <string>

#include "stillpoint/core/geometry.hpp"
#include "stillpoint/core/result.hpp"

namespace stillpoint {

struct CameraModel {
  std::string name = "camera";
  int width = 640;
  int height = 480;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  std::array<double, 5> dist{0, 0, 0, 0, 0};  // k1 k2 p1 p2 k3
  double depth_factor = 5000.0;  // raw depth value / depth_factor = metres
  // Virtual stereo baseline (m) used to express depth as a right-image
  // coordinate u_r = u - fx * baseline / z, so depth enters the same
  // reprojection machinery as image coordinates.
  double baseline = 0.08;
  double max_depth = 6.0;   // measurements beyond this are ignored (m)
  double min_depth = 0.1;   // and below this

  bool hasDistortion() const;
  // Whether the radial distortion maps the image one to one (validate()).
  bool radialDistortionInvertible() const;
  double bf() const { return fx * baseline; }

  // Projects a point in camera coordinates (z > 0) onto the undistorted image.
  Vec2 project(const Vec3& p_c) const { return {fx * p_c.x() / p_c.z() + cx, fy * p_c.y() / p_c.z() + cy}; }
  // Back-projects an undistorted pixel at depth z.
  Vec3 unproject(const Vec2& uv, double z) const {
    return {(uv.x() - cx) * z / fx, (uv.y() - cy) * z / fy, z};
  }
  // Distorts normalised coordinates / maps a distorted pixel back to an
  // undistorted pixel (iterative inverse, accurate to ~1e-6 px for TUM lenses).
  Vec2 distortNormalized(const Vec2& xn) const;
  Vec2 distortPixel(const Vec2& undistorted_px) const;
  Vec2 undistortPixel(const Vec2& distorted_px) const;

  // Checks every field; the message names the offending field.
  Status validate() const;
};

// "fr1", "fr2", "fr3": the TUM RGB-D benchmark's calibrations.
Result<CameraModel> cameraPreset(const std::string& name);
// Reads a YAML camera file (see config/camera_example.yaml).
Result<CameraModel> loadCameraYaml(const std::string& path);
// Preset name or YAML path.
Result<CameraModel> loadCamera(const std::string& preset_or_path);

}  // namespace stillpoint
