#pragma once
// Writes small synthetic sequences in the TUM RGB-D layout for unit tests of
// any module. The scene is a fronto-parallel plane with a random colour-block
// texture; the camera translates parallel to it, so depth is constant and the
// colour images agree with the ground-truth poses (a usable tracking input).
#include <cstdint>
#include <string>
#include <vector>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/geometry.hpp"
#include "stillpoint/core/result.hpp"
#include "stillpoint/core/time.hpp"

namespace stillpoint::dataset::testing {

struct SyntheticDatasetOptions {
  int n_frames = 10;
  int width = 64;
  int height = 48;
  double rate_hz = 30.0;
  // Colour stamps jitter by up to +-jitter_s around the nominal rate, and each
  // depth stamp lies within +-jitter_s of its colour stamp. Needs 4 * jitter_s < 1 / rate_hz.
  double jitter_s = 0.002;
  double start_time_s = 1000.0;
  double plane_depth_m = 1.5;
  double depth_factor = 5000.0;
  Vec2 lateral_velocity_m_s{0.05, 0.0};  // camera x/y velocity in the world frame
  std::uint64_t seed = 42;
  bool write_ground_truth = true;  // groundtruth.txt with the pose at every colour stamp
};

struct SyntheticDataset {
  std::string directory;
  CameraModel camera;  // pinhole, no distortion, the intrinsics used to render
  std::vector<Timestamp> colour_stamps;  // as written to rgb.txt (whole microseconds)
  std::vector<Timestamp> depth_stamps;   // as written to depth.txt; [k] pairs with colour k
  std::vector<SE3> T_w_c;                // pose at colour_stamps[k]; T_w_c[0] = identity
};

// Creates `dir` (and rgb/, depth/) if needed and writes rgb.txt, depth.txt,
// the PNGs and, if asked, groundtruth.txt. Errors name the bad option or file.
Result<SyntheticDataset> writeSyntheticTumDataset(const std::string& dir,
                                                  const SyntheticDatasetOptions& options);

// Shorthand with default options otherwise.
Result<SyntheticDataset> writeSyntheticTumDataset(const std::string& dir, int n_frames, int width,
                                                  int height);

}  // namespace stillpoint::dataset::testing
