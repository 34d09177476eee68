#include "dense_cloud.hpp"

#include <opencv2/imgproc.hpp>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <unordered_map>

namespace stillpoint::slam {
namespace {

struct Voxel {
  double x = 0, y = 0, z = 0;  // sums
  std::uint32_t r = 0, g = 0, b = 0, hits = 0;
};

std::uint64_t voxelKey(int ix, int iy, int iz) {
  constexpr std::uint64_t kMask = (1u << 21) - 1;  // +-1 M voxels per axis
  return ((static_cast<std::uint64_t>(ix) & kMask) << 42) | ((static_cast<std::uint64_t>(iy) & kMask) << 21) |
         (static_cast<std::uint64_t>(iz) & kMask);
}

}  // namespace

DenseView makeDenseView(const cv::Mat& depth_m, const cv::Mat& bgr, const cv::Mat& moving_full) {
  DenseView v;
  const int step = DenseView::kStep;
  const int w = depth_m.cols / step, h = depth_m.rows / step;
  v.depth.create(h, w, CV_32F);
  v.moving = cv::Mat::zeros(h, w, CV_8U);
  if (!bgr.empty()) v.bgr.create(h, w, CV_8UC3);
  for (int r = 0; r < h; ++r) {
    for (int c = 0; c < w; ++c) {
      v.depth.at<float>(r, c) = depth_m.at<float>(r * step, c * step);
      if (!bgr.empty()) v.bgr.at<cv::Vec3b>(r, c) = bgr.at<cv::Vec3b>(r * step, c * step);
      if (!moving_full.empty() && moving_full.at<std::uint8_t>(r * step, c * step)) v.moving.at<std::uint8_t>(r, c) = 1;
    }
  }
  return v;
}

DenseCloud fuseDenseCloud(const std::vector<PosedView>& views, const CameraModel& camera,
                          const DenseCloudOptions& options) {
  const double step = DenseView::kStep;
  const double fx = camera.fx / step, fy = camera.fy / step, cx = camera.cx / step, cy = camera.cy / step;
  const double inv_voxel = 1.0 / options.voxel_m;
  std::unordered_map<std::uint64_t, Voxel> grid;
  for (const PosedView& pv : views) {
    const DenseView& v = *pv.view;
    const SE3 T_w_c = pv.T_c_w.inverse();
    for (int r = 0; r < v.depth.rows; ++r) {
      for (int c = 0; c < v.depth.cols; ++c) {
        const float z = v.depth.at<float>(r, c);
        if (!(z > camera.min_depth && z < camera.max_depth) || v.moving.at<std::uint8_t>(r, c)) continue;
        const Vec3 pc((c - cx) * z / fx, (r - cy) * z / fy, z);
        const Vec3 pw = T_w_c * pc;
        Voxel& vox = grid[voxelKey(static_cast<int>(std::floor(pw.x() * inv_voxel)),
                                   static_cast<int>(std::floor(pw.y() * inv_voxel)),
                                   static_cast<int>(std::floor(pw.z() * inv_voxel)))];
        vox.x += pw.x();
        vox.y += pw.y();
        vox.z += pw.z();
        if (!v.bgr.empty()) {
          const cv::Vec3b& px = v.bgr.at<cv::Vec3b>(r, c);
          vox.b += px[0];
          vox.g += px[1];
          vox.r += px[2];
        } else {
          vox.r += 128;
          vox.g += 128;
          vox.b += 128;
        }
        ++vox.hits;
      }
    }
  }
  DenseCloud cloud;
  cloud.voxels = grid.size();
  cloud.points.reserve(grid.size());
  for (const auto& [key, vox] : grid) {
    const Vec3 p(vox.x / vox.hits, vox.y / vox.hits, vox.z / vox.hits);
    if (options.carve) {
      // Views that agree with the voxel (a surface there) against views that
      // looked through it (a surface well behind it).
      int agree = 0, through = 0;
      for (const PosedView& pv : views) {
        const Vec3 pc = pv.T_c_w * p;
        if (pc.z() <= camera.min_depth) continue;
        const int c = static_cast<int>(std::lround(fx * pc.x() / pc.z() + cx));
        const int r = static_cast<int>(std::lround(fy * pc.y() / pc.z() + cy));
        const DenseView& v = *pv.view;
        if (c < 0 || r < 0 || c >= v.depth.cols || r >= v.depth.rows) continue;
        const float z = v.depth.at<float>(r, c);
        if (!(z > camera.min_depth && z < camera.max_depth) || v.moving.at<std::uint8_t>(r, c)) continue;
        const double margin = options.margin_m + options.margin_rel * z;
        if (z > pc.z() + margin)
          ++through;
        else if (z > pc.z() - margin)
          ++agree;
      }
      if (through > agree) {
        ++cloud.carved;
        continue;
      }
    }
    ColouredPoint out;
    out.x = static_cast<float>(p.x());
    out.y = static_cast<float>(p.y());
    out.z = static_cast<float>(p.z());
    out.r = static_cast<std::uint8_t>(vox.r / vox.hits);
    out.g = static_cast<std::uint8_t>(vox.g / vox.hits);
    out.b = static_cast<std::uint8_t>(vox.b / vox.hits);
    cloud.points.push_back(out);
  }
  return cloud;
}

Status writePly(const std::string& path, const std::vector<ColouredPoint>& points, const std::string& comment) {
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (!file) return Error{"cannot write " + path + ": " + std::strerror(errno)};
  bool ok = std::fprintf(file,
                         "ply\nformat binary_little_endian 1.0\ncomment %s\n"
                         "element vertex %zu\nproperty float x\nproperty float y\nproperty float z\n"
                         "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
                         comment.c_str(), points.size()) > 0;
  for (const ColouredPoint& p : points) {
    if (!ok) break;
    ok = std::fwrite(&p.x, sizeof(float), 3, file) == 3 && std::fwrite(&p.r, 1, 3, file) == 3;
  }
  ok = (std::fclose(file) == 0) && ok;
  if (!ok) return Error{"writing " + path + " failed: " + std::strerror(errno)};
  return Status::success();
}

}  // namespace stillpoint::slam
