#include "stillpoint/geometry/depth_clustering.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace stillpoint::geometry {
namespace {

struct Sample {
  float x, y, z;
  int cell;  // index into the label grid
};

float squaredDistance(const Sample& s, const float* c) {
  const float dx = s.x - c[0], dy = s.y - c[1], dz = s.z - c[2];
  return dx * dx + dy * dy + dz * dz;
}

double pixelScale(int width, int height) { return static_cast<double>(width) * height / (640.0 * 480.0); }

}  // namespace

Status ClusteringOptions::validate() const {
  if (clusters_at_vga < 2 || clusters_at_vga > 255) return Error{"geometry.clusters must be in 2..255"};
  if (sample_step_at_vga < 1 || sample_step_at_vga > 32) return Error{"geometry.sample_step must be in 1..32"};
  if (max_iterations < 1 || max_iterations > 100) return Error{"geometry.kmeans_iterations must be in 1..100"};
  if (!(converged_fraction >= 0 && converged_fraction < 1))
    return Error{"geometry.kmeans_converged_fraction must be in [0, 1)"};
  return Status::success();
}

int DepthClusterer::clustersFor(const ClusteringOptions& options, int width, int height) {
  const int n = static_cast<int>(std::lround(options.clusters_at_vga * pixelScale(width, height)));
  return std::clamp(n, 2, 255);
}

int DepthClusterer::stepFor(const ClusteringOptions& options, int width, int height) {
  // Same number of samples per cluster at every resolution: the step scales
  // with the linear size.
  const int step = static_cast<int>(std::lround(options.sample_step_at_vga * std::sqrt(pixelScale(width, height))));
  return std::max(1, step);
}

DepthClusterer::DepthClusterer(ClusteringOptions options) : options_(options) {}

Result<DepthClusters> DepthClusterer::cluster(const cv::Mat& depth_m, const CameraModel& camera) {
  if (depth_m.empty()) return Error{"depth image is empty"};
  if (depth_m.type() != CV_32FC1) return Error{"depth image must be CV_32FC1 metres"};
  if (depth_m.cols != camera.width || depth_m.rows != camera.height)
    return Error{"depth image is " + std::to_string(depth_m.cols) + "x" + std::to_string(depth_m.rows) +
                 ", camera expects " + std::to_string(camera.width) + "x" + std::to_string(camera.height)};

  DepthClusters out;
  out.depth = depth_m;
  out.step = stepFor(options_, camera.width, camera.height);
  const int k = clustersFor(options_, camera.width, camera.height);
  const int grid_cols = camera.width / out.step, grid_rows = camera.height / out.step;
  out.labels = cv::Mat(grid_rows, grid_cols, CV_16S, cv::Scalar(DepthClusters::kNoLabel));

  // Back-project the sample grid (cell centres). Depth is registered to the
  // distorted colour image, so undistort before back-projecting.
  std::vector<Sample> samples;
  samples.reserve(static_cast<std::size_t>(grid_cols) * grid_rows);
  const bool distorted = camera.hasDistortion();
  const int half = out.step / 2;
  for (int r = 0; r < grid_rows; ++r) {
    const float* row = depth_m.ptr<float>(r * out.step + half);
    for (int c = 0; c < grid_cols; ++c) {
      const int x = c * out.step + half;
      const float z = row[x];
      if (!(z > camera.min_depth) || !(z < camera.max_depth)) continue;
      Vec2 uv(x, r * out.step + half);
      if (distorted) uv = camera.undistortPixel(uv);
      const Vec3 p = camera.unproject(uv, z);
      samples.push_back({static_cast<float>(p.x()), static_cast<float>(p.y()), z, r * grid_cols + c});
    }
  }
  if (static_cast<int>(samples.size()) < k) {
    previous_.clear();
    return out;  // too little depth to cluster: zero clusters
  }

  // Initial centres: the previous frame's (warm start), else one seed per cell
  // of a coarse image grid — deterministic and spread over the whole view.
  std::vector<float> centres(3 * k);
  if (options_.warm_start && static_cast<int>(previous_.size()) == k) {
    for (int j = 0; j < k; ++j)
      for (int d = 0; d < 3; ++d) centres[3 * j + d] = static_cast<float>(previous_[j][d]);
    out.warm_started = true;
  } else {
    const int seed_rows = std::max(1, static_cast<int>(std::lround(std::sqrt(k * double(grid_rows) / grid_cols))));
    const int seed_cols = (k + seed_rows - 1) / seed_rows;
    std::vector<int> best(k, -1);
    std::vector<float> best_d(k, std::numeric_limits<float>::max());
    for (std::size_t i = 0; i < samples.size(); ++i) {
      const int r = samples[i].cell / grid_cols, c = samples[i].cell % grid_cols;
      const int sr = std::min(seed_rows - 1, r * seed_rows / grid_rows);
      const int sc = std::min(seed_cols - 1, c * seed_cols / grid_cols);
      const int j = sr * seed_cols + sc;
      if (j >= k) continue;
      const float cy = (sr + 0.5f) * grid_rows / seed_rows, cx = (sc + 0.5f) * grid_cols / seed_cols;
      const float d = (r - cy) * (r - cy) + (c - cx) * (c - cx);
      if (d < best_d[j]) best_d[j] = d, best[j] = static_cast<int>(i);
    }
    // Cells without depth: farthest-point seeding from the seeds so far.
    std::vector<float> nearest(samples.size(), std::numeric_limits<float>::max());
    for (int j = 0; j < k; ++j) {
      if (best[j] < 0) {
        const auto far = std::max_element(nearest.begin(), nearest.end());
        best[j] = static_cast<int>(far - nearest.begin());
      }
      const Sample& s = samples[best[j]];
      centres[3 * j] = s.x, centres[3 * j + 1] = s.y, centres[3 * j + 2] = s.z;
      for (std::size_t i = 0; i < samples.size(); ++i)
        nearest[i] = std::min(nearest[i], squaredDistance(samples[i], &centres[3 * j]));
    }
  }

  // Lloyd iterations. The assignment runs centre by centre over all samples
  // (coordinates in separate arrays), which the compiler vectorises; each
  // sample still meets the centres in order and keeps the first nearest.
  const std::size_t n = samples.size();
  std::vector<float> xs(n), ys(n), zs(n);
  for (std::size_t i = 0; i < n; ++i) xs[i] = samples[i].x, ys[i] = samples[i].y, zs[i] = samples[i].z;
  std::vector<int> assign(n, -1), nearest(n);
  std::vector<float> dist(n);
  std::vector<double> sums(3 * k);
  std::vector<int> counts(k);
  const std::size_t converged = static_cast<std::size_t>(options_.converged_fraction * n);
  for (int it = 0; it < options_.max_iterations; ++it) {
    std::fill(nearest.begin(), nearest.end(), 0);
    std::fill(dist.begin(), dist.end(), std::numeric_limits<float>::infinity());
    for (int j = 0; j < k; ++j) {
      const float cx = centres[3 * j], cy = centres[3 * j + 1], cz = centres[3 * j + 2];
      const float* __restrict x = xs.data();
      const float* __restrict y = ys.data();
      const float* __restrict z = zs.data();
      float* __restrict best_d = dist.data();
      int* __restrict best = nearest.data();
      for (std::size_t i = 0; i < n; ++i) {
        const float dx = x[i] - cx, dy = y[i] - cy, dz = z[i] - cz;
        const float d = dx * dx + dy * dy + dz * dz;
        const int nearer = -static_cast<int>(d < best_d[i]);  // all ones or zero
        best[i] = (j & nearer) | (best[i] & ~nearer);
        best_d[i] = std::min(best_d[i], d);
      }
    }
    std::size_t changed = 0;
    for (std::size_t i = 0; i < n; ++i) changed += assign[i] != nearest[i];
    assign.swap(nearest);
    out.iterations = it + 1;
    std::fill(sums.begin(), sums.end(), 0.0);
    std::fill(counts.begin(), counts.end(), 0);
    for (std::size_t i = 0; i < samples.size(); ++i) {
      const int j = assign[i];
      sums[3 * j] += samples[i].x, sums[3 * j + 1] += samples[i].y, sums[3 * j + 2] += samples[i].z;
      ++counts[j];
    }
    for (int j = 0; j < k; ++j) {
      if (counts[j] == 0) {
        // Empty cluster: move it to the sample worst served by its centre.
        const auto far = std::max_element(dist.begin(), dist.end());
        const Sample& s = samples[far - dist.begin()];
        centres[3 * j] = s.x, centres[3 * j + 1] = s.y, centres[3 * j + 2] = s.z;
        *far = 0;
        changed = samples.size();  // not converged
        continue;
      }
      for (int d = 0; d < 3; ++d) centres[3 * j + d] = static_cast<float>(sums[3 * j + d] / counts[j]);
    }
    if (changed <= converged) break;
  }

  out.clusters = k;
  out.centres.resize(k);
  out.sizes.assign(k, 0);
  for (int j = 0; j < k; ++j) out.centres[j] = Vec3(centres[3 * j], centres[3 * j + 1], centres[3 * j + 2]);
  auto* labels = out.labels.ptr<std::int16_t>();
  for (std::size_t i = 0; i < samples.size(); ++i) {
    labels[samples[i].cell] = static_cast<std::int16_t>(assign[i]);
    ++out.sizes[assign[i]];
  }
  previous_ = out.centres;
  return out;
}

int DepthClusters::labelAt(const CameraModel& camera, float x, float y, float z) const {
  if (clusters == 0) return kNoLabel;
  if (z > 0) {
    Vec2 uv(x, y);
    if (camera.hasDistortion()) uv = camera.undistortPixel(uv);
    const Vec3 p = camera.unproject(uv, z);
    int best = 0;
    double best_d = (p - centres[0]).squaredNorm();
    for (int j = 1; j < clusters; ++j) {
      const double d = (p - centres[j]).squaredNorm();
      if (d < best_d) best_d = d, best = j;
    }
    return best;
  }
  const int c = static_cast<int>(std::floor(x / step)), r = static_cast<int>(std::floor(y / step));
  if (c < 0 || r < 0 || c >= labels.cols || r >= labels.rows) return kNoLabel;
  return labels.at<std::int16_t>(r, c);
}

cv::Mat DepthClusters::fullResolutionLabels(cv::Size size) const {
  cv::Mat full(size, CV_16S, cv::Scalar(kNoLabel));
  if (labels.empty()) return full;
  for (int y = 0; y < size.height; ++y) {
    const int r = std::min(labels.rows - 1, y / step);
    auto* dst = full.ptr<std::int16_t>(y);
    const auto* src = labels.ptr<std::int16_t>(r);
    for (int x = 0; x < size.width; ++x) dst[x] = src[std::min(labels.cols - 1, x / step)];
  }
  return full;
}

}  // namespace stillpoint::geometry
