#include "stillpoint/core/camera.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <set>

#include "stillpoint/core/yaml_file.hpp"

namespace stillpoint {

bool CameraModel::hasDistortion() const {
  for (double d : dist)
    if (d != 0.0) return true;
  return false;
}

Vec2 CameraModel::distortNormalized(const Vec2& xn) const {
  const double x = xn.x(), y = xn.y();
  const double r2 = x * x + y * y;
  const double radial = 1 + r2 * (dist[0] + r2 * (dist[1] + r2 * dist[4]));
  const double p1 = dist[2], p2 = dist[3];
  return {x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
          y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y};
}

Vec2 CameraModel::distortPixel(const Vec2& px) const {
  const Vec2 xn((px.x() - cx) / fx, (px.y() - cy) / fy);
  const Vec2 xd = distortNormalized(xn);
  return {fx * xd.x() + cx, fy * xd.y() + cy};
}

Vec2 CameraModel::undistortPixel(const Vec2& px) const {
  if (!hasDistortion()) return px;
  const Vec2 xd((px.x() - cx) / fx, (px.y() - cy) / fy);
  // Gauss-Newton on distort(x) = xd with a numeric Jacobian; converges in a
  // few steps for lens distortions of consumer RGB-D cameras.
  Vec2 x = xd;
  for (int it = 0; it < 20; ++it) {
    const Vec2 r = distortNormalized(x) - xd;
    if (r.squaredNorm() < 1e-24) break;
    constexpr double h = 1e-7;
    Eigen::Matrix2d J;
    J.col(0) = (distortNormalized(x + Vec2(h, 0)) - distortNormalized(x)) / h;
    J.col(1) = (distortNormalized(x + Vec2(0, h)) - distortNormalized(x)) / h;
    x -= J.lu().solve(r);
  }
  return {fx * x.x() + cx, fy * x.y() + cy};
}

bool CameraModel::radialDistortionInvertible() const {
  if (!hasDistortion()) return true;
  // The distorted radius r (1 + k1 r^2 + k2 r^4 + k3 r^6) must grow with r
  // until it reaches the farthest corner's: undistortPixel has one answer.
  double corner = 0;
  for (double u : {0.0, double(width)})
    for (double v : {0.0, double(height)}) corner = std::max(corner, std::hypot((u - cx) / fx, (v - cy) / fy));
  const double k1 = dist[0], k2 = dist[1], k3 = dist[4];
  for (double r = 0; r <= 20; r += 1e-3) {
    const double r2 = r * r;
    if (r * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) >= corner) return true;
    if (1 + r2 * (3 * k1 + r2 * (5 * k2 + r2 * 7 * k3)) <= 0) return false;
  }
  return false;
}

Status CameraModel::validate() const {
  auto bad = [&](const std::string& field, const std::string& why) {
    return Error{"camera '" + name + "': field '" + field + "' " + why};
  };
  if (width <= 0 || width > 16384) return bad("width", "must be in 1..16384");
  if (height <= 0 || height > 16384) return bad("height", "must be in 1..16384");
  if (!(fx > 0) || !std::isfinite(fx)) return bad("fx", "must be a positive number");
  if (!(fy > 0) || !std::isfinite(fy)) return bad("fy", "must be a positive number");
  if (!std::isfinite(cx) || cx < 0 || cx > width) return bad("cx", "must lie inside the image");
  if (!std::isfinite(cy) || cy < 0 || cy > height) return bad("cy", "must lie inside the image");
  for (double d : dist)
    if (!std::isfinite(d) || std::abs(d) > 100) return bad("distortion", "must be finite and |k| < 100");
  if (!radialDistortionInvertible())
    return bad("distortion", "does not map the image one to one (its radial part turns back before the corners)");
  if (!(depth_factor > 0) || !std::isfinite(depth_factor)) return bad("depth_factor", "must be positive");
  if (!(baseline > 0) || baseline > 1) return bad("baseline", "must be in (0, 1] m");
  if (!(min_depth >= 0) || !(max_depth > min_depth)) return bad("max_depth", "must exceed min_depth >= 0");
  return Status::success();
}

Result<CameraModel> cameraPreset(const std::string& name) {
  CameraModel c;
  c.name = name;
  if (name == "fr1") {
    c.fx = 517.3; c.fy = 516.5; c.cx = 318.6; c.cy = 255.3;
    c.dist = {0.2624, -0.9531, -0.0054, 0.0026, 1.1633};
  } else if (name == "fr2") {
    c.fx = 520.9; c.fy = 521.0; c.cx = 325.1; c.cy = 249.7;
    c.dist = {0.2312, -0.7849, -0.0033, -0.0001, 0.9172};
  } else if (name == "fr3") {
    c.fx = 535.4; c.fy = 539.2; c.cx = 320.1; c.cy = 247.6;
  } else {
    return Error{"unknown camera preset '" + name + "' (expected fr1, fr2, fr3 or a .yaml file)"};
  }
  return c;
}

Result<CameraModel> loadCameraYaml(const std::string& path) {
  auto loaded = loadYamlFile(path, "camera file '" + path + "'");
  if (!loaded) return Error{loaded.error()};
  const YAML::Node root = *loaded;
  if (!root.IsMap()) return Error{"camera file '" + path + "': expected a mapping at the top level"};
  // Unknown keys are typos ("depth_factr: 1000" would keep 5000), keys given
  // twice would keep the first silently: both are errors.
  static const std::set<std::string> kKnown = {"width",        "height",   "fx",        "fy",        "cx",   "cy",
                                               "depth_factor", "baseline", "max_depth", "min_depth", "name", "distortion"};
  std::set<std::string> seen;
  for (const auto& kv : root) {
    const std::string line = "camera file '" + path + "': line " + std::to_string(kv.first.Mark().line + 1);
    if (!kv.first.IsScalar()) return Error{line + ": keys must be plain names"};
    const std::string& key = kv.first.Scalar();
    if (!seen.insert(key).second) return Error{line + ": duplicate field '" + key + "'"};
    if (!kKnown.count(key)) return Error{line + ": unknown field '" + key + "'"};
  }
  CameraModel c;
  c.name = std::filesystem::path(path).stem().string();
  auto read = [&](const char* key, auto* out, bool required) -> Status {
    const YAML::Node n = root[key];
    if (!n) {
      if (required) return Error{"camera file '" + path + "': missing field '" + key + "'"};
      return Status::success();
    }
    try {
      *out = n.as<std::remove_pointer_t<decltype(out)>>();
    } catch (const YAML::Exception&) {
      return Error{"camera file '" + path + "': line " + std::to_string(n.Mark().line + 1) +
                   ": field '" + key + "' has the wrong type"};
    }
    return Status::success();
  };
  for (auto s : {read("width", &c.width, true), read("height", &c.height, true), read("fx", &c.fx, true),
                 read("fy", &c.fy, true), read("cx", &c.cx, true), read("cy", &c.cy, true),
                 read("depth_factor", &c.depth_factor, false), read("baseline", &c.baseline, false),
                 read("max_depth", &c.max_depth, false), read("min_depth", &c.min_depth, false),
                 read("name", &c.name, false)}) {
    if (!s) return Error{s.error()};
  }
  if (const YAML::Node d = root["distortion"]) {
    if (!d.IsSequence() || (d.size() != 4 && d.size() != 5))
      return Error{"camera file '" + path + "': line " + std::to_string(d.Mark().line + 1) +
                   ": field 'distortion' must be a list [k1, k2, p1, p2] or [k1, k2, p1, p2, k3]"};
    for (std::size_t i = 0; i < d.size(); ++i) {
      try {
        c.dist[i] = d[i].as<double>();
      } catch (const YAML::Exception&) {
        return Error{"camera file '" + path + "': line " + std::to_string(d.Mark().line + 1) +
                     ": distortion entry " + std::to_string(i) + " is not a number"};
      }
    }
  }
  if (Status s = c.validate(); !s) return Error{"camera file '" + path + "': " + s.error()};
  return c;
}

Result<CameraModel> loadCamera(const std::string& preset_or_path) {
  if (preset_or_path == "fr1" || preset_or_path == "fr2" || preset_or_path == "fr3")
    return cameraPreset(preset_or_path);
  return loadCameraYaml(preset_or_path);
}

}  // namespace stillpoint
