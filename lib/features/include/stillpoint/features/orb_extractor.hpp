#pragma once
// ORB features (oriented FAST corners + rotated binary descriptors) over a
// scale pyramid, spread evenly over each level with a grid and an adaptive
// FAST threshold.
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "stillpoint/core/result.hpp"

namespace stillpoint::features {

struct OrbOptions {
  int num_features = 1000;
  int num_levels = 8;
  double scale_factor = 1.2;
  int fast_threshold = 20;      // preferred FAST threshold
  int min_fast_threshold = 7;   // used in grid cells where nothing passes the preferred one
  int cell_size = 32;           // grid cell edge (pixels at each level)

  Status validate() const;
  // Whether images of this size fit the pyramid: its smallest level must
  // keep room for keypoints inside the border (num_levels and scale_factor
  // are named in the error).
  Status validateFor(int width, int height) const;
};

class OrbExtractor {
 public:
  explicit OrbExtractor(const OrbOptions& options);

  // Detects keypoints on an 8-bit grey image and computes their descriptors
  // (one 32-byte row per keypoint). Keypoint coordinates are level-0 pixels;
  // `octave` holds the pyramid level, `angle` degrees, `size` the patch size.
  //
  // `sparse` (optional, CV_8UC1 of any size: it is scaled to the image) marks
  // regions, such as movers, that get a smaller share of the budget: of the
  // corners the round robin reaches in cells whose centre lies there, one in
  // `sparse_every` is kept, so those cells end up about that many times
  // sparser than the others, which get the budget they leave. Empty, or
  // sparse_every 1: every cell alike.
  void extract(const cv::Mat& gray, std::vector<cv::KeyPoint>* keypoints, cv::Mat* descriptors,
               const cv::Mat& sparse = cv::Mat(), int sparse_every = 1);

  const OrbOptions& options() const { return options_; }
  const std::vector<double>& scales() const { return scales_; }            // scale_factor^level
  const std::vector<double>& levelSigma2() const { return sigma2_; }       // scales^2
  const std::vector<double>& invLevelSigma2() const { return inv_sigma2_; }

  static constexpr int kPatchSize = 31;
  static constexpr int kHalfPatch = 15;
  static constexpr int kEdgeThreshold = 19;

 private:
  void buildPyramid(const cv::Mat& gray);
  void detectLevel(int level, const cv::Mat& sparse, int sparse_every, std::vector<cv::KeyPoint>* out) const;

  OrbOptions options_;
  std::vector<double> scales_, sigma2_, inv_sigma2_;
  std::vector<int> features_per_level_;
  std::vector<cv::Mat> pyramid_;
  std::vector<cv::Mat> blurred_;
  std::vector<int> umax_;  // half-width of the circular patch per row
};

}  // namespace stillpoint::features
