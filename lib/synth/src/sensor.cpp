#include "stillpoint/synth/sensor.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace stillpoint::synth {
namespace {

std::uint64_t splitmix(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ULL;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
  return x ^ (x >> 31);
}

bool valid(float z) { return z > 0 && std::isfinite(z); }

// 4096 standard normal samples (small enough to stay in L1) (Box-Muller over a fixed hash sequence), so the
// per-pixel noise costs one hash and one lookup.
const std::vector<float>& gaussianTable() {
  static const std::vector<float> table = [] {
    std::vector<float> t(1 << 12);
    for (std::size_t i = 0; i < t.size(); ++i) {
      const std::uint64_t h1 = splitmix(i * 2 + 1), h2 = splitmix(i * 2 + 2);
      const double u1 = (static_cast<double>(h1 >> 11) + 0.5) * 0x1.0p-53;
      const double u2 = static_cast<double>(h2 >> 11) * 0x1.0p-53;
      t[i] = static_cast<float>(std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2));
    }
    return t;
  }();
  return table;
}

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
  const std::vector<float>& gauss = gaussianTable();
  const auto random_drop = static_cast<std::uint32_t>(o.random_dropout * 16777216.0);
  const auto edge_drop = static_cast<std::uint32_t>(o.edge_dropout * 16777216.0);
  const float min_z = static_cast<float>(o.min_depth_m), max_z = static_cast<float>(o.max_depth_m);
  const float jump_per_m = static_cast<float>(o.edge_jump_m);
  const float sigma1 = static_cast<float>(o.sigma_at_1m);
  const float factor = static_cast<float>(o.depth_factor);
  const std::uint64_t frame_key = splitmix(seed);
  for (int y = 0; y < H; ++y) {
    const float* zr = z_m.ptr<float>(y);
    const float* up = y > 0 ? z_m.ptr<float>(y - 1) : nullptr;
    const float* down = y + 1 < H ? z_m.ptr<float>(y + 1) : nullptr;
    const std::uint8_t* sel = select.empty() ? nullptr : select.ptr<std::uint8_t>(y);
    std::uint16_t* out = raw->ptr<std::uint16_t>(y);
    for (int x = 0; x < W; ++x) {
      if (sel && !sel[x]) continue;
      const float z = zr[x];
      if (!valid(z) || z < min_z || z > max_z) {
        out[x] = 0;
        continue;
      }
      const float jump = jump_per_m * z;
      auto far = [&](float zn) { return valid(zn) && std::abs(zn - z) > jump; };
      const bool edge = (x > 0 && far(zr[x - 1])) || (x + 1 < W && far(zr[x + 1])) ||
                        (up && far(up[x])) || (down && far(down[x]));
      const std::uint64_t h = splitmix(frame_key ^ (static_cast<std::uint64_t>(y) * W + x));
      const auto u24 = static_cast<std::uint32_t>(h >> 40);
      if (u24 < random_drop || (edge && u24 < edge_drop)) {
        out[x] = 0;
        continue;
      }
      const float noisy = z + sigma1 * z * z * gauss[h & 0xFFF];
      const float q = noisy * factor + 0.5f;  // round half up; noisy > 0 in practice
      out[x] = q <= 0.0f ? 0 : (q >= 65535.0f ? 65535 : static_cast<std::uint16_t>(q));
    }
  }
}

}  // namespace stillpoint::synth
