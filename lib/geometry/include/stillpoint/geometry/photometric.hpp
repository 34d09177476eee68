#pragma once
// The photometric test of the static hypothesis: a feature's image patch,
// warped pixel by pixel with its depth into an earlier frame under the pose,
// either matches the image there (the static world explains its pixels) or
// not (its texture moved). Unlike a descriptor match it cannot take another
// copy of a repeating pattern.
#include <opencv2/core.hpp>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/geometry.hpp"
#include "stillpoint/geometry/free_space.hpp"

namespace stillpoint::geometry {

struct PhotoAgreement {
  double ncc = -1;         // zero-mean NCC of the patch and the seen image there (-1: a flat patch or no verdict)
  double depth_share = 0;  // share of the patch's pixels whose depth agrees there
};

// The current frame's patch around one keypoint.
struct PatchSite {
  cv::Point2f keypoint;  // distorted image pixel
  float depth = 0;       // the keypoint's depth (m); patch pixels without depth take it
};

// An earlier frame the patch is tested against.
struct SeenView {
  const cv::Mat* gray = nullptr;   // CV_8U
  const cv::Mat* depth = nullptr;  // CV_32F metres
  SE3 T_seen_current = SE3::Identity();
};

struct PatchTest {
  int radius = 4;            // patch (2r+1)^2 pixels, r in [1, 15]
  double depth_share = 0.9;  // share of the patch's pixels whose depth must agree
  DepthTolerance tolerance;
};

// Warps the patch of `site` in `gray`/`depth` (the current frame's images)
// into `seen`. False when the patch leaves either image (untestable there).
// Else `out` holds the depth agreement, and the NCC when the depth agreed:
// a patch whose depth disagrees fails before its intensities are sampled.
bool photoAgreement(const PatchSite& site, const cv::Mat& gray, const cv::Mat& depth, const SeenView& seen,
                    const CameraModel& camera, const PatchTest& test, PhotoAgreement* out);

// The verdict over the frames a patch is tested against, their NCC added one
// at a time (a patch whose depth disagrees in a frame has no verdict and never
// gets here): it passes when every frame is above release_ncc, or when three
// or more were tested, the worst is above one_ncc (> 0) and every other above
// one_others. A frame added never turns a failure into a pass, so the test
// may stop at the first failure.
struct PhotoVoteRule {
  double release_ncc = 0.6;
  double one_ncc = 0.3;  // 0: every frame above release_ncc
  double one_others = 0.65;
};

class PhotoVote {
 public:
  explicit PhotoVote(const PhotoVoteRule& rule) : rule_(rule) {}
  void add(double ncc);
  bool failed() const { return !(worst_ > rule_.release_ncc) && !oneMayMiss(); }
  bool passed() const { return frames_ > 0 && (worst_ > rule_.release_ncc || (frames_ >= 3 && oneMayMiss())); }

 private:
  bool oneMayMiss() const { return rule_.one_ncc > 0 && worst_ > rule_.one_ncc && second_ > rule_.one_others; }
  PhotoVoteRule rule_;
  double worst_ = 1, second_ = 1;
  int frames_ = 0;
};

// Photometric detection of a cluster: at least `min_tested` of its features'
// patches were tested (their depth agreeing) and more than `share` of them
// failed. share 0: off.
constexpr bool photoDetects(int tested, int failed, double share, int min_tested) {
  return share > 0 && tested >= min_tested && failed > share * tested;
}

}  // namespace stillpoint::geometry
