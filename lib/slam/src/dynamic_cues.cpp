// The detector's dense cues: free space and the moved surface, and the
// photometric test (detection of unanchored movers, release of static
// features). The tests themselves are lib/geometry's; this is how a frame
// uses them.
#include <algorithm>
#include <cmath>

#include "dynamic_detector.hpp"
#include "dynamic_judgement.hpp"
#include "stillpoint/geometry/rules.hpp"

namespace stillpoint::slam {

geometry::FreeSpace DynamicDetector::freeSpace(const Frame& frame, const geometry::DepthClusters& clusters) const {
  // Against the depth image freespace_frames back (or the oldest kept).
  const geometry::DepthTolerance tolerance{options_.freespace_tolerance_m, options_.freespace_tolerance_z2};
  if (seen_.empty()) return geometry::freeSpaceViolations(clusters, cv::Mat(), SE3::Identity(), camera_, tolerance);
  const auto back = static_cast<std::size_t>(options_.freespace_frames);
  const SeenFrame& seen = seen_[seen_.size() >= back ? seen_.size() - back : 0];
  return geometry::freeSpaceViolations(clusters, seen.depth, seen.T_c_w * frame.T_c_w.inverse(), camera_, tolerance);
}

void DynamicDetector::addFreeSpace(FrameJudgement& j, geometry::ClusterVerdict* verdict) const {
  // Dense evidence: a cluster a good share of whose depth samples lie in
  // space the anchor frame saw empty has moved, whatever its features say;
  // unless that would make most of the view dynamic (then the pose is wrong).
  const double share = options_.freespace_flag;
  if (share <= 0) return;
  std::vector<std::size_t> added;
  int samples = 0, dynamic_samples = 0;
  for (std::size_t c = 0; c < verdict->clusters.size(); ++c) {
    samples += j.clusters->sizes[c];
    if (!verdict->clusters[c].dynamic && j.out.freespace[c] >= share) added.push_back(c);
    if (verdict->clusters[c].dynamic || j.out.freespace[c] >= share) dynamic_samples += j.clusters->sizes[c];
  }
  if (geometry::mostOfViewDynamic(dynamic_samples, samples, options_.max_dynamic_fraction)) {
    j.out.freespace_vetoed = !added.empty();
    return;
  }
  for (std::size_t c : added) verdict->clusters[c].dynamic = true;
  verdict->dynamic_clusters += static_cast<int>(added.size());
}

void DynamicDetector::splitByMovedSurface(FrameJudgement& j, const geometry::ClusterVerdict& verdict) const {
  // The moved surface grown from the free-space violations: in a dynamic
  // cluster that holds violations but whose features mostly lie off that
  // surface (a walker's legs and the floor they stand on), the features off
  // it whose own evidence agrees with the pose are static.
  for (FeatureEvidence& e : j.ev) e.released = false;
  const double keep = options_.freespace_split_keep;
  if (keep <= 0) return;
  const cv::Mat moved =
      geometry::growMovedSurface(*j.clusters, j.free, {options_.freespace_grow_plane_m, options_.freespace_grow_angle_deg});
  if (moved.empty()) return;
  const Frame& frame = j.frame;
  const auto onMoved = [&](int i) {
    const int step = j.clusters->step;
    const int c0 = static_cast<int>(frame.keys[i].pt.x) / step, r0 = static_cast<int>(frame.keys[i].pt.y) / step;
    const double radius2 = options_.freespace_split_radius_m * options_.freespace_split_radius_m;
    const float z = frame.depth[i];
    const Vec3 p = z > 0 ? camera_.unproject(Vec2(frame.un[i].x, frame.un[i].y), z) : Vec3::Zero();
    for (int r = std::max(0, r0 - 3); r <= std::min(moved.rows - 1, r0 + 3); ++r)
      for (int c = std::max(0, c0 - 3); c <= std::min(moved.cols - 1, c0 + 3); ++c) {
        if (!moved.at<std::uint8_t>(r, c)) continue;
        if (std::abs(r - r0) + std::abs(c - c0) <= 1) return true;  // its own cell or a 4-neighbour
        const cv::Vec3f& q = j.free.points.at<cv::Vec3f>(r, c);
        if (z > 0 && (Vec3(q[0], q[1], q[2]) - p).squaredNorm() < radius2) return true;
      }
    return false;
  };
  const int n_clusters = j.clusters->clusters;
  std::vector<int> on(n_clusters, 0), off(n_clusters, 0);
  std::vector<char> off_moved(frame.size(), 0);
  for (int i = 0; i < frame.size(); ++i) {
    const int c = frame.cluster[i];
    if (c < 0 || !verdict.clusters[c].dynamic || j.free.violations[c] < options_.freespace_split_min_samples) continue;
    off_moved[i] = !onMoved(i);
    ++(off_moved[i] ? off : on)[c];
  }
  // Only a feature whose own evidence agrees with the pose goes back into
  // it: one that disagrees is a part of the mover the growth did not reach,
  // and one without evidence keeps its cluster's verdict.
  std::vector<char> agrees(frame.size(), 0);
  for (std::size_t k = 0; k < j.judged.size(); ++k)
    agrees[j.judged[k].feature] = j.residuals[k].chi2 <= options_.freespace_split_protect_chi2;
  for (int i = 0; i < frame.size(); ++i) {
    const int c = frame.cluster[i];
    if (off_moved[i] && agrees[i] && on[c] < keep * (on[c] + off[c])) j.ev[i].released = true;
  }
}

int DynamicDetector::photoVerdict(const FrameJudgement& j, int i) const {
  // 1: the static hypothesis explains the patch; 0: its depth agrees but its
  // pixels do not match; -1: no verdict on its pixels (untestable, or its
  // depth disagrees in a frame).
  const Frame& frame = j.frame;
  if (frame.depth[i] <= 0) return -1;
  const geometry::PhotoVoteRule rule{options_.photo_release_ncc, options_.photo_one_ncc, options_.photo_one_others};
  const geometry::PatchTest test{options_.photo_patch_radius, options_.photo_depth_share,
                                 {options_.freespace_tolerance_m, options_.freespace_tolerance_z2}};
  const geometry::PatchSite site{frame.keys[i].pt, frame.depth[i]};
  for (const std::vector<std::size_t>& frames : j.photo_tries) {
    geometry::PhotoVote vote(rule);
    bool testable = true;
    for (std::size_t f : frames) {
      geometry::PhotoAgreement a;
      testable = f < seen_.size();
      if (testable) {
        const SeenFrame& s = seen_[f];
        const geometry::SeenView view{&s.gray, &s.depth, s.T_c_w * frame.T_c_w.inverse()};
        testable = geometry::photoAgreement(site, frame.gray, j.clusters->depth, view, camera_, test, &a);
      }
      if (!testable) break;
      // Failed (or depth disagrees): the other frames cannot change the
      // verdict. Most dropped features are movers and stop here.
      if (a.depth_share < options_.photo_depth_share) return -1;
      vote.add(a.ncc);
      if (vote.failed()) break;
    }
    if (testable) return vote.passed() ? 1 : 0;
  }
  return -1;
}

void DynamicDetector::detectPhotometrically(FrameJudgement& j, const PoseRefit& refit) const {
  // The photometric test, from the frame photo_frames_back back and, with
  // photo_frames 2 or 3, half as far each time (10, 5, 3), all of which must
  // pass (or all but one, which must still come near: PhotoVote): a mover
  // whose texture matches by chance in one frame seldom does in all. A patch
  // that cannot be tested that far back (it leaves the image there, or the
  // history is shorter) is tested at half the distance instead, once
  // (geometry.photo_fallback).
  const std::size_t seen = seen_.size();
  j.photo_tries.clear();
  for (int far = options_.photo_frames_back, tries = options_.photo_fallback ? 2 : 1; tries > 0 && far >= 2;
       far /= 2, --tries) {
    std::vector<std::size_t>& frames = j.photo_tries.emplace_back();
    // Too short a history: out of range, the patch cannot be tested there.
    for (int k = far; static_cast<int>(frames.size()) < options_.photo_frames; k = (k + 1) / 2) {
      frames.push_back(seen >= static_cast<std::size_t>(k) ? seen - k : seen);
      if (k <= 2) break;
    }
  }
  // Photometric detection: a cluster with too few anchor matches is judged
  // by short-baseline evidence (map points mapped a frame or two before,
  // carried matches), which a slow mover passes. Its features' patches are
  // tested under the pose fitted without the dynamic clusters; a cluster most
  // of whose depth-agreeing patches do not match (the texture moved along
  // the surface) is dynamic. Clusters that scored at or below
  // photo_detect_gate x the frame's reference are not tested (clearly
  // static), and nothing is added when most of the view would be dynamic.
  if (options_.photo_detect_share <= 0 || options_.photo_release_ncc <= 0) return;
  Frame& frame = j.frame;
  geometry::ClusterVerdict& verdict = j.verdict;
  const int min_features = options_.verdict.min_features;
  const int n_clusters = j.clusters->clusters;
  std::vector<int> tested(n_clusters, 0), failed(n_clusters, 0);
  for (int i = 0; i < frame.size(); ++i) {
    const int c = frame.cluster[i];
    if (c < 0 || j.anchored_in_cluster[c] >= min_features) continue;
    const geometry::ClusterScore& score = verdict.clusters[c];
    if (score.dynamic || (score.judged && score.mean_rho <= options_.photo_detect_gate * verdict.reference)) continue;
    const int r = photoVerdict(j, i);
    if (r < 0) continue;
    ++tested[c];
    failed[c] += r == 0;
  }
  std::vector<int> added;
  int samples = 0, dynamic_samples = 0;
  for (int c = 0; c < n_clusters; ++c) {
    const bool detected =
        geometry::photoDetects(tested[c], failed[c], options_.photo_detect_share, options_.photo_detect_min);
    samples += j.clusters->sizes[c];
    if (detected) added.push_back(c);
    if (detected || verdict.clusters[c].dynamic) dynamic_samples += j.clusters->sizes[c];
  }
  if (added.empty() || geometry::mostOfViewDynamic(dynamic_samples, samples, options_.max_dynamic_fraction)) return;
  for (int c : added) verdict.clusters[c].dynamic = true;
  verdict.dynamic_clusters += static_cast<int>(added.size());
  // Not dropDynamic(): that would also split the new clusters by the
  // free-space surface, whose violations did not flag them (12 runs:
  // poster-walk ATE 0.0080 against 0.0070 m).
  int removed = 0;
  for (int i = 0; i < frame.size(); ++i) {
    if (!dropped(j, i, verdict) || !frame.points[i]) continue;
    frame.points[i] = nullptr;
    frame.outlier[i] = 0;
    ++removed;
  }
  if (removed > 0 && countMapInliers(frame) >= 10) {
    refit();
    j.refitted = true;
  }
}

void DynamicDetector::releasePhotometrically(FrameJudgement& j, const PoseRefit& refit) {
  // The photometric test of the static hypothesis frees dropped features,
  // under the pose fitted without the dynamic clusters: judged under the
  // initial pose, it would confirm a mover that stage 1 followed. A freed
  // feature goes back into the pose with its stage-1 match. The pose is
  // refitted here only when the freed features add a quarter or more to the
  // matches it rests on (then the pose fitted without them may sit on a
  // mover); stage 2 refits it anyway. The pose it is judged under must rest
  // on most of the view: when the dropped features are more than
  // geometry.max_dynamic_fraction of the clustered ones, the test is skipped.
  Frame& frame = j.frame;
  int clustered = 0, dropped_count = 0;
  if (options_.photo_release_ncc > 0 && j.refitted)
    for (int i = 0; i < frame.size(); ++i)
      if (frame.cluster[i] >= 0) ++clustered, dropped_count += dropped(j, i, j.verdict);
  if (clustered == 0 || geometry::mostOfViewDynamic(dropped_count, clustered, options_.max_dynamic_fraction)) return;
  const int support = countMapInliers(frame);
  int freed = 0;
  for (int i = 0; i < frame.size(); ++i) {
    if (!dropped(j, i, j.verdict) || (j.ev[i].has_anchor && !options_.photo_release_anchored) ||
        photoVerdict(j, i) != 1)
      continue;
    j.ev[i].released = true;
    photo_released_[i] = options_.photo_release_memory;
    frame.points[i] = j.stage_one_points[i];
    frame.outlier[i] = 0;
    freed += j.stage_one_points[i] != nullptr;
  }
  if (freed > 0 && 4 * freed >= support && countMapInliers(frame) >= 10) refit();
}

}  // namespace stillpoint::slam
