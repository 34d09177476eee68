#include <algorithm>

#include <opencv2/calib3d.hpp>

#include <Eigen/Geometry>

#include "matcher.hpp"
#include "optimizer.hpp"
#include "stillpoint/core/log.hpp"
#include "stillpoint/features/descriptor.hpp"
#include "tracking.hpp"

namespace stillpoint::slam {
namespace {
log::Logger logger("tracking");
constexpr std::size_t kOtherMapCandidates = 3;  // keyframes of other maps tried per lost frame
}  // namespace

bool Tracker::poseFromMatches(Frame* frame) const {
  std::vector<cv::Point3f> object;
  std::vector<cv::Point2f> image;
  for (int i = 0; i < frame->size(); ++i) {
    if (!frame->points[i]) continue;
    const Vec3& p = frame->points[i]->position;
    object.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
    image.push_back(frame->un[i]);
  }
  if (object.size() < 4) return false;
  const cv::Mat K = (cv::Mat_<double>(3, 3) << camera_.fx, 0, camera_.cx, 0, camera_.fy, camera_.cy, 0, 0, 1);
  cv::Mat rvec, tvec;
  std::vector<int> inliers;
  if (!cv::solvePnPRansac(object, image, K, cv::noArray(), rvec, tvec, false, 300, 4.0f, 0.99, inliers,
                          cv::SOLVEPNP_EPNP) ||
      inliers.size() < 12)
    return false;
  cv::Mat R;
  cv::Rodrigues(rvec, R);
  SE3 T = SE3::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) T.linear()(r, c) = R.at<double>(r, c);
    T.translation()[r] = tvec.at<double>(r);
  }
  frame->T_c_w = T;
  return true;
}

features::BowVector Tracker::staticWords(const Frame& frame) const {
  if (!vocabulary_ || frame.descriptors.empty()) return {};
  cv::Mat rows;
  rows.reserve(frame.size());
  for (int i = 0; i < frame.size(); ++i)
    if (!frame.dynamic[i]) rows.push_back(frame.descriptors.row(i));
  return vocabulary_->transform(rows);
}

bool Tracker::relocalise() {
  // Most recent keyframes first: after a short loss the camera is usually
  // still near where it was. Then as many of the older ones, a window that
  // moves on with every lost frame: a camera back at a place mapped long ago
  // (a robot's next lap, a kidnapped camera) finds the map there within a few
  // frames, at a bounded cost per frame, instead of staying lost until it
  // reaches recently mapped ground.
  const auto n = static_cast<std::size_t>(options_.tracking.relocalisation_candidates);
  if (vocabulary_) {
    const features::BowVector words = staticWords(current_);
    return relocalise(placeCandidates(words, n, false)) ||
           (map_->mapsStarted() > 1 && relocalise(placeCandidates(words, kOtherMapCandidates, true)));
  }
  std::vector<KeyFrame*> candidates, older;  // newest first
  // Only the map being tracked: without a vocabulary the other maps are
  // reached by merging (map_merge.cpp).
  for (auto it = map_->keyframes().rbegin(); it != map_->keyframes().rend(); ++it) {
    if ((*it)->bad || (*it)->map_id != map_->activeMapId()) continue;
    (candidates.size() < n ? candidates : older).push_back(it->get());
  }
  if (!older.empty()) {
    std::size_t start = 0;
    while (start < older.size() && older[start]->id >= reloc_window_next_id_) ++start;
    if (start == older.size()) start = 0;  // wrap around to the newest of them
    const std::size_t count = std::min(n, older.size());
    for (std::size_t k = 0; k < count; ++k) candidates.push_back(older[(start + k) % older.size()]);
    reloc_window_next_id_ = candidates.back()->id;
  }
  return relocalise(candidates);
}

std::vector<KeyFrame*> Tracker::placeCandidates(const features::BowVector& words, std::size_t n,
                                                bool other_maps) const {
  // In the tracked map: the few newest keyframes (after a short loss the
  // camera is still near them), then the keyframes whose views share the most
  // words with this one, wherever they are: a camera back at a place mapped
  // long ago finds it at once. In the other maps: those alike views only.
  constexpr std::size_t kNewest = 3;
  const std::uint32_t active = map_->activeMapId();
  std::vector<KeyFrame*> candidates;
  for (auto it = map_->keyframes().rbegin();
       !other_maps && it != map_->keyframes().rend() && candidates.size() < kNewest; ++it)
    if (!(*it)->bad && (*it)->map_id == active) candidates.push_back(it->get());
  const auto similar = map_->similarKeyFrames(
      words, [active, other_maps](const KeyFrame* kf) { return (kf->map_id != active) == other_maps; }, 0.0, n);
  for (const Map::PlaceMatch& m : similar) {
    if (m.score < 0.5 * similar.front().score) break;
    if (std::find(candidates.begin(), candidates.end(), m.keyframe) == candidates.end()) candidates.push_back(m.keyframe);
  }
  return candidates;
}

void Tracker::switchToMap(std::uint32_t id) {
  const std::uint32_t from = map_id_;
  map_->activate(id);
  map_id_ = id;
  merge_candidate_.reset();
  // Its frames hang in the other map's world.
  if (detector_) detector_->forgetHistory();
  steady_poses_.clear();
  SP_WARN(logger, "frame " << current_.id << ": relocalised in map " << id << " (map " << from << " is kept)");
}

bool Tracker::relocalise(const std::vector<KeyFrame*>& candidates) {
  // Every candidate is tried, each with its own local map, and the frame is
  // placed where two of them agree (agreedPlacement): under a mover one
  // keyframe's local map can hold a pose centimetres off with enough inliers
  // (cover_on_a_saved_map: 58 inliers, 15 cm sideways), and no other
  // keyframe places the frame there. A single candidate has none to agree
  // with: its pose is taken.
  struct Placement {
    KeyFrame* keyframe;
    SE3 T_c_w;
    std::vector<std::shared_ptr<MapPoint>> points;
    std::vector<char> outlier;
    int inliers;
    std::vector<MapPoint*> seen;
  };
  std::vector<Placement> placements;
  for (KeyFrame* kf : candidates) {
    current_.clearMatches();
    if (searchByDescriptor(&current_, *kf, 0.75f) < 15) continue;
    if (!poseFromMatches(&current_)) continue;
    if (timedOptimizePose() < 10) continue;
    discardOutliers();
    // Widen to the local map around the candidate.
    reference_ = kf;
    std::vector<MapPoint*> seen;
    if (!trackLocalMap(options_.tracking.min_inliers_after_reloc, &seen)) continue;
    // Where the view is far and a mover covers the near part, the pose fit
    // can settle centimetres off along the view on the far points alone
    // (their reprojections barely move), steered by a few of the mover's
    // features that matched by chance. The far points' depth tells: their
    // median offset from the map, which a correct pose keeps at the depth's
    // own bias (within 1.2 cm on the generated sequences' correct
    // relocalisations, 5.4-12.8 cm on the wrong ones).
    const DepthOffset offset = depthOffset(current_);
    if (offAlongView(offset)) {
      SP_INFO(logger, "frame " << current_.id << ": relocalisation against keyframe " << kf->id
                               << " refused: its inliers' depth puts the camera " << offset.metres << " m (+-"
                               << offset.standard_error << ") along the view from the pose");
      ++relocalisations_refused_;
      continue;
    }
    SP_DEBUG(logger, "frame " << current_.id << ": keyframe " << kf->id << " places it with " << inliers_
                              << " inliers at " << current_.T_c_w.inverse().translation().transpose());
    placements.push_back({kf, current_.T_c_w, current_.points, current_.outlier, inliers_, std::move(seen)});
  }
  int chosen = candidates.size() == 1 && placements.size() == 1 ? 0 : -1;
  if (placements.size() > 1) {
    std::vector<SE3> poses;
    std::vector<int> inliers;
    for (const Placement& p : placements) poses.push_back(p.T_c_w), inliers.push_back(p.inliers);
    chosen = agreedPlacement(poses, inliers);
  }
  if (chosen < 0) {
    if (!placements.empty())
      SP_INFO(logger, "frame " << current_.id << ": relocalisation refused: " << placements.size()
                               << " keyframe(s) placed it, no two alike");
    current_.clearMatches();
    return false;
  }
  Placement& p = placements[static_cast<std::size_t>(chosen)];
  current_.T_c_w = p.T_c_w;
  current_.points = std::move(p.points);
  current_.outlier = std::move(p.outlier);
  inliers_ = p.inliers;
  reference_ = p.keyframe;
  countSightings(p.seen);  // the other candidates' poses were not the camera's
  last_reloc_frame_id_ = current_.id;
  if (p.keyframe->map_id != map_->activeMapId()) switch_to_map_ = p.keyframe->map_id;
  SP_INFO(logger, "frame " << current_.id << ": relocalised against keyframe " << p.keyframe->id << " with "
                           << inliers_ << " inliers (" << placements.size() << " keyframe(s) placed it)");
  return true;
}

Tracker::StaticSupport Tracker::staticSupport(const SE3& predicted) const {
  StaticSupport support;
  if (!has_last_) return support;
  // Mutual descriptor matches to the last frame with depth in both, as
  // points in each camera's frame.
  std::vector<int> feature;
  std::vector<Vec3> from, to;
  for (const auto& [j, i] : matchByDescriptor(current_, last_, 0.7f, false, true)) {
    if (current_.depth[j] <= 0 || last_.depth[i] <= 0) continue;
    if (current_.dynamic[j] == kSemanticDynamic) continue;  // a mask's mover
    feature.push_back(j);
    from.push_back(camera_.unproject(Vec2(last_.un[i].x, last_.un[i].y), last_.depth[i]));
    to.push_back(camera_.unproject(Vec2(current_.un[j].x, current_.un[j].y), current_.depth[j]));
  }
  const int n = static_cast<int>(feature.size());
  // From the predicted motion, rounds of: the matches it explains, and the
  // rigid motion that fits them best. The first round allows for the
  // prediction's error (the camera may have sped up or turned since), the
  // other rounds only for depth noise, which grows with the square of depth.
  // A consensus of the most matches instead would follow a mover that
  // fills most of the view; the prediction picks the static scene.
  SE3 motion = predicted;
  std::vector<char> agree(n, 0);
  constexpr int kRounds = 4;
  for (int round = 0; round < kRounds; ++round) {
    int count = 0;
    for (int k = 0; k < n; ++k) {
      const double z = to[k].z();
      const double tolerance = round == 0 ? 0.04 + 0.02 * z : 0.01 + 0.01 * z * z;
      agree[k] = (to[k] - motion * from[k]).norm() < tolerance;
      count += agree[k];
    }
    if (count < 3) return support;
    if (round + 1 == kRounds) break;
    Eigen::Matrix3Xd a(3, count), b(3, count);
    for (int k = 0, c = 0; k < n; ++k)
      if (agree[k]) a.col(c) = from[k], b.col(c++) = to[k];
    motion = SE3(Eigen::umeyama(a, b, false));
  }
  // The descriptor matches are few where the view changes a lot from frame
  // to frame (a mover uncovering the scene): with the motion found, look
  // for every feature of the last frame where that motion puts it.
  support.motion = motion;
  std::vector<char> guided = guidedStaticMatches(motion);
  for (int k = 0; k < n; ++k) guided[feature[k]] = guided[feature[k]] || agree[k];
  for (int k = 0; k < n; ++k)
    if (!guided[feature[k]]) support.moved.push_back(feature[k]);
  for (int j = 0; j < current_.size(); ++j)
    if (guided[j]) support.agree.push_back(j);
  return support;
}

std::vector<char> Tracker::guidedStaticMatches(const SE3& motion) const {
  std::vector<char> agree(current_.size(), 0);
  std::vector<int> best_distance(current_.size(), 256);
  std::vector<float> rotation(current_.size(), 0);
  const LevelInfo& lv = *current_.levels;
  for (int i = 0; i < last_.size(); ++i) {
    if (last_.depth[i] <= 0) continue;
    const Vec3 p = motion * camera_.unproject(Vec2(last_.un[i].x, last_.un[i].y), last_.depth[i]);
    if (p.z() <= 0) continue;
    const Vec2 uv = camera_.project(p);
    const int level = last_.keys[i].octave;
    const float r = kGuidedRadiusPx * static_cast<float>(lv.scales[level]);
    int best = 256, best_j = -1, second = 256;
    for (int j : current_.grid.query(current_.keys, current_.un, static_cast<float>(uv.x()), static_cast<float>(uv.y()),
                                     r, std::max(0, level - 1), std::min(lv.levels - 1, level + 1))) {
      const int d = features::hammingDistance(last_.descriptor(i), current_.descriptor(j));
      if (d < best) {
        second = best;
        best = d;
        best_j = j;
      } else if (d < second) {
        second = d;
      }
    }
    if (best_j < 0 || best > kMatchThresholdLow || best > 0.8 * second || current_.depth[best_j] <= 0) continue;
    const Vec3 q = camera_.unproject(Vec2(current_.un[best_j].x, current_.un[best_j].y), current_.depth[best_j]);
    if ((q - p).norm() >= 0.01 + 0.01 * q.z() * q.z()) continue;
    if (best >= best_distance[best_j]) continue;
    best_distance[best_j] = best;
    agree[best_j] = 1;
    rotation[best_j] = last_.keys[i].angle - current_.keys[best_j].angle;
  }
  // A mover's repeated texture can put a like feature where a static one was
  // predicted; its keypoint orientation then seldom turns as the view's does.
  std::vector<int> matched;
  std::vector<float> rotations;
  for (int j = 0; j < current_.size(); ++j)
    if (agree[j]) matched.push_back(j), rotations.push_back(rotation[j]);
  std::vector<int> kept = matched;
  filterByOrientation(rotations, &kept);
  std::fill(agree.begin(), agree.end(), 0);
  for (int j : kept) agree[j] = 1;
  return agree;
}

}  // namespace stillpoint::slam
