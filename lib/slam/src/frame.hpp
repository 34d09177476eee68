#pragma once
// A camera frame with its ORB features, per-feature depth and map matches.
#include <opencv2/core.hpp>

#include <algorithm>
#include <memory>
#include <vector>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/time.hpp"
#include "stillpoint/features/orb_extractor.hpp"

namespace stillpoint::slam {

// Why a feature is kept out of the pose and the map (Frame::dynamic).
enum DynamicCause : char {
  kNotDynamic = 0,
  kGeometryDynamic = 1,  // the geometry module's verdict (in anchor frames also the photometric test's memory)
  kSemanticDynamic = 2,  // inside a movable semantic mask, followed from one, or a known mover
};

class MapPoint;

// Pyramid constants shared by all frames of one extractor.
struct LevelInfo {
  int levels = 8;
  double scale_factor = 1.2;
  double log_scale_factor = 0;
  std::vector<double> scales, sigma2, inv_sigma2;
  static LevelInfo from(const features::OrbExtractor& orb);
};

// Keypoint indices bucketed by undistorted position for window searches.
class FeatureGrid {
 public:
  static constexpr int kCols = 64, kRows = 48;
  void build(const std::vector<cv::Point2f>& points, int width, int height);
  // Indices of features within radius r of (x, y) whose level is in
  // [min_level, max_level] (max_level < 0: any).
  std::vector<int> query(const std::vector<cv::KeyPoint>& keys, const std::vector<cv::Point2f>& un,
                         float x, float y, float r, int min_level, int max_level) const;

 private:
  float inv_cell_w_ = 0, inv_cell_h_ = 0;
  std::vector<std::vector<int>> cells_;
};

struct Frame {
  std::int64_t id = -1;
  Timestamp stamp;
  const CameraModel* camera = nullptr;
  const LevelInfo* levels = nullptr;

  std::vector<cv::KeyPoint> keys;     // as detected (distorted image)
  std::vector<cv::Point2f> un;        // undistorted pixel positions
  std::vector<float> depth;           // metres, <= 0 when unknown
  std::vector<float> u_right;         // virtual right-image u, < 0 when unknown
  cv::Mat descriptors;                // one 32-byte row per keypoint
  FeatureGrid grid;

  std::vector<std::shared_ptr<MapPoint>> points;  // matched map point or null
  std::vector<char> outlier;
  // The feature lies on a moving surface and is kept out of pose estimation
  // and mapping, and why (kNotDynamic: static).
  std::vector<DynamicCause> dynamic;
  std::vector<std::int16_t> cluster;  // depth cluster, -1 when unknown
  // For kSemanticDynamic features: the movable class whose mask they came
  // from (Map::className), 0 when unknown. Empty until the first is set.
  std::vector<std::uint8_t> movable_class;
  // Where a map starts: features a person model beside the main one paints
  // (semantic::ModelCard::person_model). Flagged as movers for the frame, they
  // still make points, which serve a mover's probation: that model also
  // paints things that stand. Empty when none.
  std::vector<char> suspect;

  SE3 T_c_w = SE3::Identity();
  // The grey image, only while the geometry module's photometric test needs
  // it (geometry.photo_release_ncc > 0); keyframes do not keep it.
  cv::Mat gray;
  // The whole view in 40x30 pixels, blurred, zero mean, unit norm (CV_32F):
  // two views of one place have a high dot product. Ranks older keyframes
  // for a map merge (map_merge.cpp).
  cv::Mat thumbnail;
  // Colour (BGR) at each keypoint; empty for a frame without colour.
  std::vector<cv::Vec3b> colour;

  int size() const { return static_cast<int>(keys.size()); }
  // Whether a semantic mask (or a known mover) keeps any feature out.
  bool hasSemanticFlags() const {
    return std::find(dynamic.begin(), dynamic.end(), kSemanticDynamic) != dynamic.end();
  }
  const std::uint8_t* descriptor(int i) const { return descriptors.ptr<std::uint8_t>(i); }
  Vec3 cameraCentre() const { return T_c_w.inverse().translation(); }
  // World point of keypoint i from its depth (requires depth[i] > 0).
  Vec3 unprojectToWorld(int i) const;
  void clearMatches();
};

// Frame::thumbnail of an 8-bit grey image; the dot product of two is their
// normalised cross-correlation, in [-1, 1].
cv::Mat viewThumbnail(const cv::Mat& gray);

// Extracts features from an 8-bit grey image and samples depth (metres,
// CV_32F, 0 = none) at each keypoint. `depth_m` may be empty (no depth).
// `sparse` and `sparse_every`: where the budget is thinned (OrbExtractor).
void buildFrame(Frame* frame, const cv::Mat& gray, const cv::Mat& depth_m, features::OrbExtractor* orb,
                const cv::Mat& sparse = cv::Mat(), int sparse_every = 1);

// Features of `frame` flagged by a semantic mask within `radius` px of the
// undistorted position `at`, on the surface at depth `z` (geometry::sameSurface).
// Masks and the features they keep out grow over those with two or more.
int maskedNeighbours(const Frame& frame, cv::Point2f at, float z, float radius);

// Marks the features inside `movers` (CV_8UC1 or CV_16UC1, the image's size,
// non-zero = moving) as kSemanticDynamic: movers known from outside are kept
// out of the pose and the map as semantic masks are.
void markKnownMovers(Frame* frame, const cv::Mat& movers);

}  // namespace stillpoint::slam
