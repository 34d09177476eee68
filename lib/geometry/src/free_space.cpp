#include "stillpoint/geometry/free_space.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>

namespace stillpoint::geometry {

FreeSpace freeSpaceViolations(const DepthClusters& clusters, const cv::Mat& seen_depth, const SE3& T_seen_current,
                              const CameraModel& camera, const DepthTolerance& tolerance) {
  FreeSpace out;
  out.share.assign(clusters.clusters, -1.0f);
  out.violations.assign(clusters.clusters, 0);
  if (clusters.depth.empty() || clusters.labels.empty()) return out;
  out.violated = cv::Mat::zeros(clusters.labels.size(), CV_8U);
  out.points = cv::Mat::zeros(clusters.labels.size(), CV_32FC3);
  if (seen_depth.empty()) return out;
  const cv::Mat& seen = seen_depth;
  const Mat3 R = T_seen_current.linear();
  const Vec3 t = T_seen_current.translation();
  const bool distorted = camera.hasDistortion();
  std::vector<int> tested(clusters.clusters, 0);
  std::vector<int>& violated = out.violations;
  const int half = clusters.step / 2;
  for (int r = 0; r < clusters.labels.rows; ++r) {
    const auto* label = clusters.labels.ptr<std::int16_t>(r);
    const int y = r * clusters.step + half;
    for (int c = 0; c < clusters.labels.cols; ++c) {
      if (label[c] < 0) continue;
      const int x = c * clusters.step + half;
      const float z = clusters.depth.at<float>(y, x);
      Vec2 uv(x, y);
      if (distorted) uv = camera.undistortPixel(uv);
      const Vec3 p_c = camera.unproject(uv, z);
      out.points.at<cv::Vec3f>(r, c) = cv::Vec3f(p_c.x(), p_c.y(), p_c.z());
      const Vec3 p = R * p_c + t;  // in the seen camera
      if (p.z() <= camera.min_depth) continue;
      Vec2 q = camera.project(p);
      if (distorted) q = camera.distortPixel(q);
      const int qx = static_cast<int>(std::lround(q.x())), qy = static_cast<int>(std::lround(q.y()));
      if (qx < 1 || qy < 1 || qx >= seen.cols - 1 || qy >= seen.rows - 1) continue;
      // The seen depth image is cold: the sample below this one lands about
      // a step further down it, so its rows are fetched now.
      for (int ahead = qy + clusters.step - 1; ahead <= std::min(seen.rows - 1, qy + clusters.step + 1); ++ahead)
        __builtin_prefetch(seen.ptr<float>(ahead) + qx);
      // The nearest surface the seen frame had around that pixel: a point on
      // a depth edge may fall on either side of it.
      float nearest = std::numeric_limits<float>::max();
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const float d = seen.at<float>(qy + dy, qx + dx);
          if (d > camera.min_depth && d < camera.max_depth) nearest = std::min(nearest, d);
        }
      if (nearest == std::numeric_limits<float>::max()) continue;
      ++tested[label[c]];
      if (p.z() < nearest - tolerance.at(p.z())) {
        ++violated[label[c]];
        out.violated.at<std::uint8_t>(r, c) = 1;
      }
    }
  }
  for (int j = 0; j < clusters.clusters; ++j)
    if (tested[j] >= 8) out.share[j] = static_cast<float>(violated[j]) / static_cast<float>(tested[j]);
  return out;
}

cv::Mat growMovedSurface(const DepthClusters& clusters, const FreeSpace& free, const SurfaceGrowth& growth) {
  if (free.violated.empty()) return cv::Mat();
  const int rows = free.points.rows, cols = free.points.cols;
  // Unit normals of the samples from their grid neighbours (zero: unknown).
  cv::Mat normals = cv::Mat::zeros(rows, cols, CV_32FC3);
  const auto point = [&](int r, int c) {
    const cv::Vec3f& v = free.points.at<cv::Vec3f>(r, c);
    return Vec3(v[0], v[1], v[2]);
  };
  for (int r = 1; r + 1 < rows; ++r)
    for (int c = 1; c + 1 < cols; ++c) {
      const Vec3 p = point(r, c), l = point(r, c - 1), rt = point(r, c + 1), u = point(r - 1, c), d = point(r + 1, c);
      if (p.z() <= 0 || l.z() <= 0 || rt.z() <= 0 || u.z() <= 0 || d.z() <= 0) continue;
      const double jump = 0.1 * p.z();
      if (std::abs(rt.z() - l.z()) > 2 * jump || std::abs(d.z() - u.z()) > 2 * jump) continue;
      Vec3 n = (rt - l).cross(d - u);
      if (n.norm() <= 0) continue;
      n.normalize();
      normals.at<cv::Vec3f>(r, c) = cv::Vec3f(n.x(), n.y(), n.z());
    }
  const double plane_tol = growth.plane_m;
  const double min_cos = std::cos(growth.angle_deg * M_PI / 180.0);
  cv::Mat reached = free.violated.clone();
  std::vector<std::pair<int, int>> queue;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c)
      if (reached.at<std::uint8_t>(r, c)) queue.emplace_back(r, c);
  for (std::size_t k = 0; k < queue.size(); ++k) {
    const auto [r, c] = queue[k];
    const Vec3 p = point(r, c);
    const cv::Vec3f& na = normals.at<cv::Vec3f>(r, c);
    constexpr int kDr[4] = {1, -1, 0, 0}, kDc[4] = {0, 0, 1, -1};
    for (int d = 0; d < 4; ++d) {
      const int r2 = r + kDr[d], c2 = c + kDc[d];
      if (r2 < 0 || c2 < 0 || r2 >= rows || c2 >= cols || reached.at<std::uint8_t>(r2, c2)) continue;
      if (clusters.labels.at<std::int16_t>(r2, c2) < 0) continue;
      const Vec3 q = point(r2, c2);
      if (q.z() <= 0) continue;
      const cv::Vec3f& nb = normals.at<cv::Vec3f>(r2, c2);
      // Same surface: q lies on p's tangent plane and the normals agree.
      // Without normals (a depth edge next to either) the surface is not
      // followed.
      if (na == cv::Vec3f() || nb == cv::Vec3f()) continue;
      const double off = std::abs(na[0] * (q.x() - p.x()) + na[1] * (q.y() - p.y()) + na[2] * (q.z() - p.z()));
      if (off > plane_tol * (1 + p.z() * p.z()) || std::abs(na.dot(nb)) < min_cos) continue;
      reached.at<std::uint8_t>(r2, c2) = 1;
      queue.emplace_back(r2, c2);
    }
  }
  return reached;
}

}  // namespace stillpoint::geometry
