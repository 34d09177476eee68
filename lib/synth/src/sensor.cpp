#include "stillpoint/synth/sensor.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

namespace stillpoint::synth {
namespace {

std::uint64_t splitmix(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ULL;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
  return x ^ (x >> 31);
}

bool valid(float z) { return z > 0 && std::isfinite(z); }

}  // namespace

Status DepthSensorOptions::validate() const {
  auto bad = [](const std::string& f, const std::string& rule) {
    return Status(Error{"sensor." + f + " " + rule});
  };
  if (!(depth_factor > 0) || !std::isfinite(depth_factor)) return bad("depth_factor", "must be > 0");
  if (!(min_depth_m >= 0)) return bad("min_depth_m", "must be >= 0");
  if (!(max_depth_m > min_depth_m) || max_depth_m * depth_factor > 65535) {
    return bad("max_depth_m", "must be > min_depth_m and fit 16 bits times depth_factor");
  }
  if (!(sigma_at_1m >= 0 && sigma_at_1m < 1)) return bad("sigma_at_1m", "must be in [0, 1)");
  if (!(edge_jump_m > 0)) return bad("edge_jump_m", "must be > 0");
  if (!(edge_dropout >= 0 && edge_dropout <= 1)) return bad("edge_dropout", "must be in [0, 1]");
  if (!(random_dropout >= 0 && random_dropout <= 1)) return bad("random_dropout", "must be in [0, 1]");
  return Status::success();
}

double PixelNoise::uniform(std::uint64_t index) const {
  return static_cast<double>(splitmix(seed_ ^ splitmix(index)) >> 11) * 0x1.0p-53;
}

double PixelNoise::gaussian(std::uint64_t index) const {
  // Box-Muller from two independent hashes.
  const std::uint64_t h1 = splitmix(seed_ ^ splitmix(index ^ 0xA5A5A5A5ULL));
  const std::uint64_t h2 = splitmix(h1);
  const double u1 = (static_cast<double>(h1 >> 11) + 0.5) * 0x1.0p-53;
  const double u2 = static_cast<double>(h2 >> 11) * 0x1.0p-53;
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2);
}

void applyDepthSensor(const cv::Mat& z_m, const cv::Mat& select, const DepthSensorOptions& o,
                      std::uint64_t seed, cv::Mat* raw) {
  const int W = z_m.cols, H = z_m.rows;
  if (raw->empty() || raw->size() != z_m.size() || raw->type() != CV_16UC1) {
    *raw = cv::Mat(H, W, CV_16UC1, cv::Scalar(0));
  }
  const PixelNoise noise(seed);
  for (int y = 0; y < H; ++y) {
    const float* zr = z_m.ptr<float>(y);
    const std::uint8_t* sel = select.empty() ? nullptr : select.ptr<std::uint8_t>(y);
    std::uint16_t* out = raw->ptr<std::uint16_t>(y);
    for (int x = 0; x < W; ++x) {
      if (sel && !sel[x]) continue;
      const float z = zr[x];
      const std::uint64_t index = static_cast<std::uint64_t>(y) * W + x;
      if (!valid(z) || z < o.min_depth_m || z > o.max_depth_m) {
        out[x] = 0;
        continue;
      }
      const double jump = o.edge_jump_m * z;
      bool edge = false;
      auto check = [&](int xx, int yy) {
        if (xx < 0 || yy < 0 || xx >= W || yy >= H) return;
        const float zn = z_m.ptr<float>(yy)[xx];
        if (valid(zn) && std::abs(zn - z) > jump) edge = true;
      };
      check(x - 1, y);
      check(x + 1, y);
      check(x, y - 1);
      check(x, y + 1);
      const double u = noise.uniform(index);
      if (u < o.random_dropout || (edge && u < o.edge_dropout)) {
        out[x] = 0;
        continue;
      }
      const double sigma = o.sigma_at_1m * z * z;
      const double noisy = z + sigma * noise.gaussian(index);
      const long q = std::lround(noisy * o.depth_factor);
      out[x] = static_cast<std::uint16_t>(std::clamp(q, 0L, 65535L));
    }
  }
}

}  // namespace stillpoint::synth
