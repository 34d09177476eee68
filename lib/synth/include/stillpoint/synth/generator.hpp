#pragma once
// Sequence generation: movers composited into a real TUM sequence (overlay) or
// a fully rendered room, written in the TUM layout plus ground-truth masks:
//   rgb/ depth/ rgb.txt depth.txt groundtruth.txt
//   mask/<colour stamp>.png  16-bit, 0 = static, k = mover k (movers.yaml ids)
//   mask.txt                 `timestamp mask/<stamp>.png` per colour frame
//   movers.yaml              what was placed, and per-mover coverage
// Frames are independent (per-frame noise seeds), so the output is identical
// for a given seed whatever the thread count.
#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/geometry.hpp"
#include "stillpoint/core/result.hpp"
#include "stillpoint/synth/config.hpp"
#include "stillpoint/synth/movers.hpp"
#include "stillpoint/synth/raster.hpp"

namespace stillpoint::synth {

// The configured movers with their textures, ready to draw at any time.
class MoverRenderer {
 public:
  // T_w_s: stage frame (stageFromCamera of the first pose).
  static Result<MoverRenderer> create(const SynthConfig& config, const SE3& T_w_s);

  // Draws every mover at time t into `target` (z-tested against its depth).
  // With motion blur on, colour is averaged over the exposure, `id` marks every
  // pixel any sub-frame touched, and depth is the centre sub-frame's.
  void render(double t, const SE3& T_w_c, const CameraModel& camera, RenderTarget* target) const;

  std::size_t size() const { return specs_.size(); }

 private:
  void drawAt(double t, const SE3& T_w_c, const CameraModel& camera, RenderTarget* target) const;

  std::vector<MoverSpec> specs_;
  std::vector<MoverTextures> textures_;
  BlurOptions blur_;
  SE3 T_w_s_ = SE3::Identity();
};

struct CompositeFrame {
  cv::Mat bgr;    // CV_8UC3
  cv::Mat depth;  // CV_16UC1 raw
  cv::Mat mask;   // CV_16UC1 mover ids
};

// Renders the movers onto one real frame: colour and depth change only where
// the returned mask is non-zero; the movers' depth goes through the sensor
// model (noise seeded by noise_seed).
CompositeFrame composeOverlay(const MoverRenderer& movers, const cv::Mat& bgr, const cv::Mat& depth_raw,
                              double t, const SE3& T_w_c, const CameraModel& camera,
                              const DepthSensorOptions& sensor, std::uint64_t noise_seed);

struct GenerateOptions {
  int threads = 2;
  int max_frames = 0;         // 0 = all
  // 0: our stored-block writer (fast, large files); 1-9: OpenCV's zlib level.
  int png_compression = 0;
  bool write_images = true;   // false: decode and render only (speed measurement)
  // Overlay: a TUM trajectory of the input's camera to place the movers by
  // instead of groundtruth.txt, rigidly aligned onto it (e.g. the input's own
  // replay). Motion capture is off the images by up to a degree, so an object
  // placed by it drifts against the real scene although it stands still; poses
  // fitted to the images keep it in place. groundtruth.txt is still what the
  // output is scored against, and only frames it has a pose for are written.
  // Empty: groundtruth.txt.
  std::string render_poses;
};

struct MoverStats {
  std::string name;
  int frames_visible = 0;
  double mean_coverage = 0;  // over all frames
  double max_coverage = 0;
};

struct GenerationReport {
  int frames = 0;               // frames generated
  int skipped_no_pose = 0;      // overlay: colour frames outside the ground truth (or the render poses)
  int frames_with_movers = 0;
  double coverage_mean = 0, coverage_max = 0;  // fraction of pixels on any mover
  std::vector<MoverStats> movers;
  double wall_s = 0;
  // Summed over all frames (thread time), milliseconds.
  double load_ms = 0, render_ms = 0, write_ms = 0;
};

// Overlay mode: input_dir is a TUM sequence with groundtruth.txt whose images
// match `camera`. Errors name the missing or bad file.
Result<GenerationReport> generateOverlay(const std::string& input_dir, const std::string& output_dir,
                                         const CameraModel& camera, const SynthConfig& config,
                                         const GenerateOptions& options);

// Fully synthetic mode (config.room).
Result<GenerationReport> generateRoom(const std::string& output_dir, const SynthConfig& config,
                                      const GenerateOptions& options);

// Per-frame noise seed of frame `index`.
std::uint64_t frameSeed(std::uint64_t seed, std::size_t index);

}  // namespace stillpoint::synth
