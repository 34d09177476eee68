#pragma once
// Depth sensor model for rendered depth: Gaussian noise whose sigma grows with
// the square of the range (structured-light sensors, Khoshelham & Elberink
// 2012), quantisation to the 16-bit depth_factor grid, no measurement beyond
// the range limits, and dropouts at depth discontinuities.
#include <cstdint>

#include <opencv2/core/mat.hpp>

#include "stillpoint/core/result.hpp"

namespace stillpoint::synth {

struct DepthSensorOptions {
  double depth_factor = 5000.0;  // raw value / depth_factor = metres
  double min_depth_m = 0.4;
  double max_depth_m = 5.0;
  double sigma_at_1m = 0.0015;    // noise sigma (m) at 1 m; sigma(z) = sigma_at_1m * z^2
  double edge_jump_m = 0.06;      // a 4-neighbour further than this (times z) marks a depth edge
  double edge_dropout = 0.7;      // probability that an edge pixel has no measurement
  double random_dropout = 0.002;  // probability of a missing pixel anywhere

  Status validate() const;  // names the bad field
};

// Deterministic per-pixel random numbers: a hash of (seed, pixel index).
class PixelNoise {
 public:
  explicit PixelNoise(std::uint64_t seed) : seed_(seed) {}
  double gaussian(std::uint64_t index) const;  // N(0, 1)
  double uniform(std::uint64_t index) const;   // [0, 1)

 private:
  std::uint64_t seed_;
};

// Converts the z-buffer `z_m` (CV_32FC1, metres, +inf/0 = nothing) into raw
// 16-bit depth written into `raw` (CV_16UC1, same size) at the pixels where
// `select` (CV_8UC1) is non-zero; all pixels when `select` is empty. Depth edges
// are found on `z_m` as a whole, so a rendered mover loses depth where it meets
// a real background, yet unselected pixels are never written.
void applyDepthSensor(const cv::Mat& z_m, const cv::Mat& select, const DepthSensorOptions& options,
                      std::uint64_t seed, cv::Mat* raw);

}  // namespace stillpoint::synth
