#include "frame.hpp"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "stillpoint/geometry/rules.hpp"

namespace stillpoint::slam {

int maskedNeighbours(const Frame& frame, cv::Point2f at, float z, float radius) {
  int n = 0;
  for (int s : frame.grid.query(frame.keys, frame.un, at.x, at.y, radius, 0, -1))
    n += frame.dynamic[s] == kSemanticDynamic && frame.depth[s] > 0 && geometry::sameSurface(frame.depth[s], z);
  return n;
}

LevelInfo LevelInfo::from(const features::OrbExtractor& orb) {
  LevelInfo info;
  info.levels = orb.options().num_levels;
  info.scale_factor = orb.options().scale_factor;
  info.log_scale_factor = std::log(info.scale_factor);
  info.scales = orb.scales();
  info.sigma2 = orb.levelSigma2();
  info.inv_sigma2 = orb.invLevelSigma2();
  return info;
}

void FeatureGrid::build(const std::vector<cv::Point2f>& points, int width, int height) {
  inv_cell_w_ = static_cast<float>(kCols) / static_cast<float>(width);
  inv_cell_h_ = static_cast<float>(kRows) / static_cast<float>(height);
  cells_.assign(kCols * kRows, {});
  for (std::size_t i = 0; i < points.size(); ++i) {
    const int c = static_cast<int>(std::floor(points[i].x * inv_cell_w_));
    const int r = static_cast<int>(std::floor(points[i].y * inv_cell_h_));
    if (c < 0 || c >= kCols || r < 0 || r >= kRows) continue;  // undistorted outside image
    cells_[r * kCols + c].push_back(static_cast<int>(i));
  }
}

std::vector<int> FeatureGrid::query(const std::vector<cv::KeyPoint>& keys, const std::vector<cv::Point2f>& un,
                                    float x, float y, float r, int min_level, int max_level) const {
  std::vector<int> out;
  if (cells_.empty()) return out;
  const int c0 = std::max(0, static_cast<int>(std::floor((x - r) * inv_cell_w_)));
  const int c1 = std::min(kCols - 1, static_cast<int>(std::floor((x + r) * inv_cell_w_)));
  const int r0 = std::max(0, static_cast<int>(std::floor((y - r) * inv_cell_h_)));
  const int r1 = std::min(kRows - 1, static_cast<int>(std::floor((y + r) * inv_cell_h_)));
  if (c0 > c1 || r0 > r1) return out;
  const float r2 = r * r;
  for (int row = r0; row <= r1; ++row) {
    for (int col = c0; col <= c1; ++col) {
      for (int i : cells_[row * kCols + col]) {
        const int level = keys[i].octave;
        if (level < min_level || (max_level >= 0 && level > max_level)) continue;
        const float dx = un[i].x - x, dy = un[i].y - y;
        if (dx * dx + dy * dy <= r2) out.push_back(i);
      }
    }
  }
  return out;
}

Vec3 Frame::unprojectToWorld(int i) const {
  const Vec3 p_c = camera->unproject(Vec2(un[i].x, un[i].y), depth[i]);
  return T_c_w.inverse() * p_c;
}

void Frame::clearMatches() {
  points.assign(keys.size(), nullptr);
  outlier.assign(keys.size(), 0);
}

cv::Mat viewThumbnail(const cv::Mat& gray) {
  cv::Mat small, f;
  cv::resize(gray, small, cv::Size(40, 30), 0, 0, cv::INTER_AREA);
  small.convertTo(f, CV_32F);
  cv::GaussianBlur(f, f, cv::Size(3, 3), 0);
  f -= cv::mean(f)[0];
  const double norm = cv::norm(f);
  if (norm > 1e-6) f /= norm;
  return f;
}

void buildFrame(Frame* frame, const cv::Mat& gray, const cv::Mat& depth_m, features::OrbExtractor* orb,
                const cv::Mat& sparse, int sparse_every) {
  orb->extract(gray, &frame->keys, &frame->descriptors, sparse, sparse_every);
  const CameraModel& cam = *frame->camera;
  const int n = frame->size();
  frame->un.resize(n);
  frame->depth.assign(n, -1.0f);
  frame->u_right.assign(n, -1.0f);
  const bool undistort = cam.hasDistortion();
  for (int i = 0; i < n; ++i) {
    const cv::Point2f& p = frame->keys[i].pt;
    if (undistort) {
      const Vec2 u = cam.undistortPixel(Vec2(p.x, p.y));
      frame->un[i] = cv::Point2f(static_cast<float>(u.x()), static_cast<float>(u.y()));
    } else {
      frame->un[i] = p;
    }
    if (depth_m.empty()) continue;
    // Depth is registered to the (distorted) colour image: sample at the
    // detected position.
    const int x = cvRound(p.x), y = cvRound(p.y);
    if (x < 0 || y < 0 || x >= depth_m.cols || y >= depth_m.rows) continue;
    const float z = depth_m.at<float>(y, x);
    if (!(z > cam.min_depth) || !(z < cam.max_depth)) continue;
    frame->depth[i] = z;
    frame->u_right[i] = frame->un[i].x - static_cast<float>(cam.bf()) / z;
  }
  frame->grid.build(frame->un, cam.width, cam.height);
  frame->clearMatches();
  frame->dynamic.assign(n, kNotDynamic);
  frame->cluster.assign(n, -1);
}

void markKnownMovers(Frame* frame, const cv::Mat& movers) {
  const bool wide = movers.type() == CV_16UC1;
  for (int i = 0; i < frame->size(); ++i) {
    const int x = std::clamp(cvRound(frame->keys[i].pt.x), 0, movers.cols - 1);
    const int y = std::clamp(cvRound(frame->keys[i].pt.y), 0, movers.rows - 1);
    if (wide ? movers.at<std::uint16_t>(y, x) != 0 : movers.at<std::uint8_t>(y, x) != 0)
      frame->dynamic[i] = kSemanticDynamic;
  }
}

}  // namespace stillpoint::slam
