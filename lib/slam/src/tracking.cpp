#include "tracking.hpp"

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <mutex>
#include <numeric>
#include <unordered_map>

#include "matcher.hpp"
#include "stillpoint/features/descriptor.hpp"
#include "optimizer.hpp"
#include "stillpoint/core/log.hpp"

namespace stillpoint::slam {
namespace {
log::Logger logger("tracking");

// Adds the lifetime of the scope to a stage's milliseconds.
class ScopedStageTimer {
 public:
  explicit ScopedStageTimer(double* ms) : ms_(ms), start_(std::chrono::steady_clock::now()) {}
  ~ScopedStageTimer() {
    *ms_ += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  double* ms_;
  std::chrono::steady_clock::time_point start_;
};
}  // namespace

Tracker::Tracker(const CameraModel& camera, const SlamOptions& options, const LevelInfo& levels, Map* map,
                 geometry::ClusteringWorker* clustering)
    : camera_(camera),
      options_(options),
      levels_(levels),
      map_(map),
      clustering_(clustering),
      close_depth_(options.tracking.close_depth_baselines * camera.baseline) {
  if (clustering_ && !options_.sequential) helper_ = std::make_unique<TaskThread>();
}

KeyFrame* Tracker::track(Frame frame, bool mapping_idle, bool clusters_pending, TrackOutput* out) {
  current_ = std::move(frame);
  match_ratio_.assign(current_.size(), 0.0f);
  clusters_pending_ = clusters_pending && clustering_;
  clusters_fetched_ = false;
  clusters_.reset();
  times_ = StageTimes{};
  geometry_ = GeometryOutput{};
  semantic_marked_ = 0;
  carried_.clear();
  photo_released_.assign(current_.size(), 0);
  KeyFrame* new_keyframe = nullptr;
  bool ok = false;
  if (state_ == TrackingState::kInitialising) {
    std::unique_lock lock(map_->mutex());
    ok = initialise();
    if (ok) new_keyframe = reference_;
  } else {
    std::shared_lock lock(map_->mutex());
    const bool was_lost = state_ == TrackingState::kLost;
    if (!was_lost) {
      // Reads only the frame's keypoints and descriptors, which stage 1
      // leaves alone, and the anchor, which stays until the frame is done.
      if (clusters_pending_ && !anchors_.empty() && helper_)
        anchor_matches_ = helper_->run([this] { return matchAnchor(); });
      if (options_.semantic.enabled && options_.semantic.propagate_masks) markSemanticMovers();
      {
        ScopedStageTimer timer(&times_.initial_pose);
        refreshLastFrame();
        const bool use_motion = has_velocity_ && current_.id > last_reloc_frame_id_ + 2;
        if (use_motion) ok = trackWithMotionModel();
        if (!ok) ok = trackReferenceKeyFrame();
        if (!ok && !use_motion) {
          // Just after a relocalisation (or without a velocity yet): the
          // camera moved little in a frame, so the last frame's points
          // projected at the predicted pose (the last pose when there is no
          // velocity) still find their features. The reference keyframe
          // chosen by covisibility after a relocalisation can share many
          // points but have seen them from elsewhere, and its descriptor
          // matches then fall short (looped_replay_test: the frame after
          // every relocalisation was lost).
          if (!has_velocity_) {
            velocity_ = SE3::Identity();
            velocity_dt_ = 0;
          }
          ok = trackWithMotionModel(has_velocity_);
        }
      }
      // Stage 1 keeps its outliers so the geometry module sees every match.
      if (ok && clusters_pending) removeDynamicFeatures();
      if (ok) discardOutliers();
      if (ok) ok = trackLocalMap(options_.tracking.min_inliers_local_map);
      if (ok && clusters_pending_) updateProbation();
    } else {
      ScopedStageTimer timer(&times_.initial_pose);
      ok = relocalise();
    }
    if (ok) {
      state_ = was_lost ? TrackingState::kRelocalised : TrackingState::kOk;
    } else {
      state_ = TrackingState::kLost;
      has_velocity_ = false;
    }
    ScopedStageTimer keyframe_timer(&times_.keyframe);
    if (ok && needNewKeyFrame(mapping_idle)) {
      lock.unlock();
      std::unique_lock write(map_->mutex());
      new_keyframe = createKeyFrame();
    }
  }

  if (ok) {
    if (has_last_ && current_.id == last_.id + 1 && state_ == TrackingState::kOk) {
      velocity_ = renormalized(current_.T_c_w * last_.T_c_w.inverse());
      velocity_dt_ = secondsBetween(current_.stamp, last_.stamp);
      has_velocity_ = true;
    } else if (state_ != TrackingState::kOk) {
      has_velocity_ = false;
    }
    // Temporary odometry points never outlive the frame they helped track.
    for (int i = 0; i < current_.size(); ++i)
      if (current_.points[i] && (current_.points[i]->isTemporary() || current_.outlier[i]))
        current_.points[i] = nullptr;
    std::shared_lock lock(map_->mutex());  // keyframe poses change under local BA
    record({current_.stamp, reference_->anchor(), renormalized(current_.T_c_w * reference_->T_c_w().inverse())});
    out->T_w_c = current_.T_c_w.inverse();
  }
  SP_DEBUG(logger, "frame " << current_.id << " state " << toString(state_) << " inliers " << inliers_
                              << " local kfs " << local_keyframes_.size() << " local points " << local_points_.size()
                              << (new_keyframe ? " NEW KF" : ""));
  out->stages = times_;
  out->state = state_;
  out->features = current_.size();
  out->tracked = ok ? inliers_ : 0;
  out->new_keyframe = new_keyframe != nullptr;
  out->geometry = std::move(geometry_);
  out->semantic_features = semantic_marked_;
  markMoverCells(ok);
  if (anchor_matches_.valid()) anchor_matches_.wait();  // not used: stage 1 failed
  anchor_matches_ = {};
  if (ok) {
    rememberAnchor();
  } else {
    anchors_.clear();
    seen_depth_.clear();
  }
  last_ = std::move(current_);
  last_photo_released_ = std::move(photo_released_);
  last_chain_ = std::move(chain_);
  chain_.clear();
  has_last_ = true;
  return new_keyframe;
}

void Tracker::markMoverCells(bool tracked) {
  const TrackingOptions& t = options_.tracking;
  mover_cells_.release();
  if (!tracked || t.mover_cells_every <= 1 || current_.size() == 0) return;
  const auto dynamic = std::count_if(current_.dynamic.begin(), current_.dynamic.end(), [](char d) { return d != 0; });
  if (dynamic == 0 || dynamic < t.mover_cells_min_share * current_.size()) return;
  constexpr int kScale = 8;  // the extractor samples one point per grid cell (32 px and up)
  mover_cells_ = cv::Mat::zeros((camera_.height + kScale - 1) / kScale, (camera_.width + kScale - 1) / kScale, CV_8UC1);
  const int radius = std::max(1, static_cast<int>(std::lround(t.mover_cells_radius_px * camera_.width / 640.0 / kScale)));
  for (int i = 0; i < current_.size(); ++i)
    if (current_.dynamic[i])
      cv::circle(mover_cells_, cv::Point(cvRound(current_.keys[i].pt.x / kScale), cvRound(current_.keys[i].pt.y / kScale)),
                 radius, cv::Scalar(255), cv::FILLED);
}

void Tracker::record(const TrajectoryRecord& r) {
  last_record_ = r;
  const int keep = options_.tracking.trajectory_records;
  if (keep == 0) return;
  records_.push_back(r);
  if (keep > 0 && records_.size() > static_cast<std::size_t>(keep)) records_.pop_front();
}

void Tracker::releaseCulledKeyFrames() {
  if (options_.mapping.keep_culled_keyframes) return;
  // Our pointers to keyframes: the reference (its record holds the anchor;
  // a culled reference is only ever tested for `bad`, which null equals) and
  // the local keyframes (rebuilt for every frame).
  if (reference_ && reference_->bad) reference_ = nullptr;
  std::erase_if(local_keyframes_, [](KeyFrame* kf) { return kf->bad; });
  const std::size_t released = map_->releaseCulledKeyFrames();
  if (released > 0) SP_DEBUG(logger, "freed " << released << " culled keyframes");
}

bool Tracker::maskMoves(const Frame& f, const std::vector<std::pair<int, int>>& still,
                        const std::vector<std::pair<int, int>>& mask, float gate_px) const {
  // (current, keyframe) index pairs -> world points and pixels.
  const auto collect = [&](const std::vector<std::pair<int, int>>& pairs, std::vector<cv::Point3f>* w,
                           std::vector<cv::Point2f>* px) {
    for (const auto& [j, i] : pairs) {
      if (f.depth[i] <= 0) continue;
      const Vec3 p = f.unprojectToWorld(i);
      w->emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
      px->push_back(current_.un[j]);
    }
  };
  std::vector<cv::Point3f> still_w, mask_w;
  std::vector<cv::Point2f> still_px, mask_px;
  collect(still, &still_w, &still_px);
  collect(mask, &mask_w, &mask_px);
  if (mask_w.size() < 6 || still_w.size() < 10) return true;  // too few to tell: moving
  const auto misses = [&](const SE3& T, const std::vector<cv::Point3f>& w, const std::vector<cv::Point2f>& px) {
    std::vector<float> miss(w.size(), 1e9f);
    for (std::size_t k = 0; k < w.size(); ++k) {
      const Vec3 p = T * Vec3(w[k].x, w[k].y, w[k].z);
      if (p.z() <= 0) continue;
      const Vec2 uv = camera_.project(p);
      miss[k] = static_cast<float>(std::hypot(uv.x() - px[k].x, uv.y() - px[k].y));
    }
    return miss;
  };
  const auto median = [](std::vector<float> v) {
    auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
    std::nth_element(v.begin(), mid, v.end());
    return *mid;
  };
  const SE3 last = last_record_ ? last_record_->T_c_w() : last_.T_c_w;
  SE3 T = has_velocity_ ? predictedPose(last) : last;
  // Refine the predicted pose on the other matches: drop the clear
  // mismatches, then Levenberg-Marquardt from the prediction (a local step:
  // it cannot jump to another solution); keep it only if it fits better.
  const std::vector<float> before = misses(T, still_w, still_px);
  const float s0 = median(before);
  std::vector<cv::Point3f> fit_w;
  std::vector<cv::Point2f> fit_px;
  for (std::size_t k = 0; k < before.size(); ++k)
    if (before[k] < std::max(4.0f, 3.0f * s0)) fit_w.push_back(still_w[k]), fit_px.push_back(still_px[k]);
  float s = s0;
  if (fit_w.size() >= 10) {
    const cv::Mat K = (cv::Mat_<double>(3, 3) << camera_.fx, 0, camera_.cx, 0, camera_.fy, camera_.cy, 0, 0, 1);
    cv::Mat R(3, 3, CV_64F), rvec, tvec(3, 1, CV_64F);
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) R.at<double>(r, c) = T.linear()(r, c);
      tvec.at<double>(r) = T.translation()(r);
    }
    cv::Rodrigues(R, rvec);
    cv::solvePnPRefineLM(fit_w, fit_px, K, cv::noArray(), rvec, tvec);
    cv::Rodrigues(rvec, R);
    SE3 refined = SE3::Identity();
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) refined.linear()(r, c) = R.at<double>(r, c);
      refined.translation()(r) = tvec.at<double>(r);
    }
    const float s1 = median(misses(refined, still_w, still_px));
    if (s1 < s0) T = refined, s = s1;
  }
  const float m = median(misses(T, mask_w, mask_px));
  const bool moving = m > gate_px && m > 2.0f * s;
  SP_DEBUG(logger, "frame " << current_.id << ": " << mask_w.size() << " masked matches miss " << m << " px, "
                              << still_w.size() << " others " << s << " px (motion model " << s0
                              << "): " << (moving ? "moving" : "static"));
  return moving;
}

void Tracker::markSemanticMovers() {
  // The newest segmented keyframe near the camera: features inside its
  // movable masks are looked up in this frame by descriptor alone (the
  // object may have moved anywhere since) and kept out of the pose, so a
  // masked object does not pull the pose between keyframes.
  const KeyFrame* source = nullptr;
  const auto consider = [&](const KeyFrame* kf) {
    if (kf && !kf->bad && kf->segmented && (!source || kf->id > source->id)) source = kf;
  };
  consider(reference_);
  for (const KeyFrame* kf : local_keyframes_) consider(kf);
  if (!source) return;
  // A keyframe whose segmentation found nothing (a detector's miss while the
  // object is still in view) holds only what it inherited by propagation:
  // the newest keyframe with a mask of its own, a few keyframes older, is
  // looked up too.
  const KeyFrame* masked = nullptr;
  const int window = options_.semantic.propagate_mask_window;
  if (window > 0 && source->in_mask.empty()) {
    const auto consider_masked = [&](const KeyFrame* kf) {
      if (kf && !kf->bad && kf->segmented && !kf->in_mask.empty() && kf->id < source->id &&
          source->id - kf->id <= window && (!masked || kf->id > masked->id))
        masked = kf;
    };
    consider_masked(reference_);
    for (const KeyFrame* kf : local_keyframes_) consider_masked(kf);
  }
  const auto has_flags = [](const Frame& other) {
    return std::find(other.dynamic.begin(), other.dynamic.end(), kSemanticDynamic) != other.dynamic.end();
  };
  // Flags the current features matched to `other`'s semantic-dynamic ones;
  // returns how many were newly flagged.
  const auto adopt_flags = [&](const Frame& other) {
    int adopted = 0;
    for (const auto& [j, i] : matchByDescriptor(current_, other, 0.7f, false, true))
      if (other.dynamic[i] == kSemanticDynamic && !current_.dynamic[j])
        current_.dynamic[j] = kSemanticDynamic, ++adopted;
    semantic_marked_ += adopted;
    return adopted;
  };
  // Most keyframes mask nothing: skip the brute-force pass then.
  if (!has_flags(source->frame)) {
    if (!masked) return;
    source = masked;
    masked = nullptr;
  }
  const Frame& f = source->frame;
  // Mutual nearest neighbours over all the keyframe's features, ratio 0.7 and
  // rotation consistency: window-free matching on repetitive texture
  // mismatches, and a static feature marked here is lost to the pose.
  const float warp = options_.semantic.propagate_warp_px;
  const float gate = options_.semantic.propagate_motion_px;
  std::vector<cv::Point2f> from, to;
  std::vector<float> depth_change;
  const std::vector<char>& in_mask = source->in_mask;
  const auto matches = matchByDescriptor(current_, f, 0.7f, false, true);
  std::vector<std::pair<int, int>> warp_pairs, still_pairs;
  for (const auto& [j, i] : matches) {
    if (f.dynamic[i] != kSemanticDynamic) {
      if (warp > 0 && gate > 0 && !f.dynamic[i]) still_pairs.emplace_back(j, i);
      continue;
    }
    current_.dynamic[j] = kSemanticDynamic, ++semantic_marked_;
    if (warp <= 0 || in_mask.empty() || !in_mask[i]) continue;
    warp_pairs.emplace_back(j, i);
    from.push_back(f.un[i]);
    to.push_back(current_.un[j]);
    if (f.depth[i] > 0 && current_.depth[j] > 0) depth_change.push_back(current_.depth[j] - f.depth[i]);
  }
  if (masked) {
    const int older = adopt_flags(masked->frame);
    SP_DEBUG(logger, "frame " << current_.id << ": " << older << " more from the masks of keyframe " << masked->id);
  }
  if (options_.semantic.propagate_from_last && has_last_ && has_flags(last_)) {
    // The last frame's flagged features, looked up here: from frame to frame
    // an object changes less than since its keyframe. (Features the geometry
    // module flagged carry its flag instead and are not followed.)
    const int chained = adopt_flags(last_);
    SP_DEBUG(logger, "frame " << current_.id << ": " << chained << " flagged from the last frame");
  }
  const float grow = options_.semantic.propagate_grow_px;
  for (int pass = 0; grow > 0 && semantic_marked_ >= 5 && pass < options_.semantic.propagate_grow_passes; ++pass) {
    // Region growing from the matches, then (more passes) from what it added.
    std::vector<int> grown;
    for (int j = 0; j < current_.size(); ++j) {
      const float z = current_.depth[j];
      if (current_.dynamic[j] || z <= 0) continue;
      int support = 0;
      for (int s : current_.grid.query(current_.keys, current_.un, current_.un[j].x, current_.un[j].y, grow, 0, -1))
        support += current_.dynamic[s] == kSemanticDynamic && current_.depth[s] > 0 &&
                   std::abs(current_.depth[s] - z) < 0.1f + 0.05f * z;
      if (support >= 2) grown.push_back(j);
    }
    for (int j : grown) current_.dynamic[j] = kSemanticDynamic;
    semantic_marked_ += static_cast<int>(grown.size());
    if (grown.empty()) break;
  }
  if (warp > 0 && from.size() >= 6 && !depth_change.empty()) {
    // The object's motion in the image since the keyframe (it does not
    // follow the camera's): a similarity through the matches of the
    // keyframe's own mask, then every feature in that mask is looked for
    // where it went. Only the mask: features the keyframe inherited by
    // propagation would carry a static false positive on from keyframe to
    // keyframe (static texture matches well), and it grew by the radius each time.
    std::vector<unsigned char> inlier;
    const cv::Mat A = cv::estimateAffinePartial2D(from, to, inlier, cv::RANSAC, 3.0);
    const int inliers = static_cast<int>(std::count(inlier.begin(), inlier.end(), 1));
    bool fits = !A.empty() && inliers >= 6 && 2 * inliers >= static_cast<int>(from.size());
    if (fits && gate > 0) {
      // Motion gate: an object that stands still (a person who stopped, a
      // false positive) lands where the static scene says it should, one
      // that moves does not. Judged on the matches that agree with the
      // similarity (window-free matching has mismatches).
      std::vector<std::pair<int, int>> agreed;
      for (std::size_t k = 0; k < inlier.size(); ++k)
        if (inlier[k]) agreed.push_back(warp_pairs[k]);
      fits = maskMoves(f, still_pairs, agreed, gate);
    }
    if (fits) {
      auto mid = depth_change.begin() + static_cast<std::ptrdiff_t>(depth_change.size() / 2);
      std::nth_element(depth_change.begin(), mid, depth_change.end());
      const float dz = *mid;
      int warped = 0;
      for (int i = 0; i < f.size(); ++i) {
        if (!in_mask[i] || f.depth[i] <= 0) continue;
        const cv::Point2f& q = f.un[i];
        const float x = static_cast<float>(A.at<double>(0, 0) * q.x + A.at<double>(0, 1) * q.y + A.at<double>(0, 2));
        const float y = static_cast<float>(A.at<double>(1, 0) * q.x + A.at<double>(1, 1) * q.y + A.at<double>(1, 2));
        const float z = f.depth[i] + dz;
        for (int s : current_.grid.query(current_.keys, current_.un, x, y, warp, 0, -1)) {
          if (current_.dynamic[s] || current_.depth[s] <= 0 || std::abs(current_.depth[s] - z) >= 0.1f + 0.05f * z)
            continue;
          current_.dynamic[s] = kSemanticDynamic;
          ++warped;
        }
      }
      semantic_marked_ += warped;
      SP_DEBUG(logger, "frame " << current_.id << ": warped " << warped);
    }
  }
  SP_DEBUG(logger, "frame " << current_.id << ": " << semantic_marked_ << " features matched to masks of keyframe " << source->id);
}

int Tracker::timedOptimizePose(const SE3* prior) {
  ScopedStageTimer timer(&times_.pose_optimisation);
  // The motion model's prediction as a prior (stage 1 only, `prior` set).
  const TrackingOptions& t = options_.tracking;
  Eigen::Matrix<double, 6, 1> sqrt_information;
  sqrt_information.head<3>().setConstant(1.0 / (t.motion_prior_sigma_deg * M_PI / 180.0));
  sqrt_information.tail<3>().setConstant(t.motion_prior_sigma_m > 0 ? 1.0 / t.motion_prior_sigma_m : 0.0);
  const bool use_prior = prior && t.motion_prior_sigma_m > 0;
  const auto optimise = [&] {
    return use_prior ? optimizeFramePose(&current_, prior, &sqrt_information) : optimizeFramePose(&current_);
  };
  // Map points on probation (new, not yet seen to stay put) are left out of
  // the fit and judged by it: a mover mapped while it went unflagged cannot
  // pull the pose before it has shown its motion. Only when enough trusted
  // matches remain; then their inlier flags come from the fitted pose.
  std::vector<int> held;
  int trusted = 0;
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    if (!p || p->bad) continue;
    if (!p->isTemporary() && p->probation > 0)
      held.push_back(i);
    else
      ++trusted;
  }
  if (held.empty() || trusted < options_.geometry.probation_min_trusted) return optimise();
  std::vector<std::shared_ptr<MapPoint>> aside;
  aside.reserve(held.size());
  for (int i : held) aside.push_back(std::move(current_.points[i]));
  const int inliers = optimise();
  for (std::size_t k = 0; k < held.size(); ++k) {
    const int i = held[k];
    current_.points[i] = std::move(aside[k]);
    const Observation o = observationOf(current_, i);
    const double chi2 = reprojectionChi2(camera_, current_.T_c_w, current_.points[i]->position, o);
    current_.outlier[i] = chi2 > (o.u_right >= 0 ? kChi2Stereo : kChi2Mono);
  }
  return inliers;
}

void Tracker::updateProbation() {
  // A point on probation matched consistently with the final pose (which it
  // did not influence), outside any dynamic cluster, has one frame less to go.
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    if (!p || p->bad || p->isTemporary() || p->probation <= 0 || current_.outlier[i] || current_.dynamic[i]) continue;
    --p->probation;
  }
}

bool Tracker::initialise() {
  int with_depth = 0;
  for (float d : current_.depth) with_depth += d > 0;
  if (with_depth < options_.tracking.min_init_features) {
    SP_INFO(logger, "frame " << current_.id << ": " << with_depth << " features with depth, need "
                             << options_.tracking.min_init_features << " to initialise");
    return false;
  }
  current_.T_c_w = SE3::Identity();
  auto kf = std::make_unique<KeyFrame>(0, current_);
  KeyFrame* k = map_->addKeyFrame(std::move(kf));
  for (int i = 0; i < k->frame.size(); ++i) {
    if (k->frame.depth[i] <= 0) continue;
    auto p = map_->createPoint(k->frame.unprojectToWorld(i), k);
    k->addObservation(p, i);
    p->updateFromObservations();
    current_.points[i] = p;
  }
  reference_ = k;
  last_keyframe_stamp_ = current_.stamp;
  last_keyframe_frame_id_ = current_.id;
  local_keyframes_ = {k};
  inliers_ = k->trackedPoints(1);
  state_ = TrackingState::kOk;
  SP_INFO(logger, "map initialised with " << inliers_ << " points");
  return true;
}

void Tracker::refreshLastFrame() {
  // The last frame's pose follows its reference keyframe (bundle adjustment
  // may have moved it); then give it temporary points from depth so the
  // motion model has enough to match against.
  if (last_record_) last_.T_c_w = last_record_->T_c_w();
  carried_from_.clear();
  std::vector<std::pair<float, int>> by_depth;
  for (int i = 0; i < last_.size(); ++i) {
    if (last_.depth[i] <= 0) continue;
    // A feature the photometric test freed from a dynamic cluster is carried
    // too (geometry.photo_release_memory): its cluster keeps its memory.
    const bool freed = i < static_cast<int>(last_photo_released_.size()) && last_photo_released_[i];
    if (!last_.dynamic[i] && !freed) {
      by_depth.emplace_back(last_.depth[i], i);
      continue;
    }
    // Moving features are carried over as evidence for the geometry module.
    auto p = std::make_shared<MapPoint>(-1, last_.unprojectToWorld(i), nullptr);
    std::copy(last_.descriptor(i), last_.descriptor(i) + 32, p->descriptor.begin());
    p->moving = true;
    carried_from_[p.get()] = i;
    last_.points[i] = std::move(p);
    last_.outlier[i] = 0;
  }
  const float exclusion = options_.semantic.enabled ? options_.semantic.temp_exclusion_px : 0.0f;
  if (exclusion > 0 && std::find(last_.dynamic.begin(), last_.dynamic.end(), kSemanticDynamic) != last_.dynamic.end()) {
    // The unflagged rest of a masked object (its features nearest to the
    // camera get temporary points first) lends none.
    std::erase_if(by_depth, [&](const std::pair<float, int>& e) {
      const auto [z, i] = e;
      if (last_.points[i] && !last_.points[i]->bad) return false;
      int support = 0;
      for (int s : last_.grid.query(last_.keys, last_.un, last_.un[i].x, last_.un[i].y, exclusion, 0, -1))
        support += last_.dynamic[s] == kSemanticDynamic && last_.depth[s] > 0 &&
                   std::abs(last_.depth[s] - z) < 0.1f + 0.05f * z;
      return support >= 2;
    });
  }
  std::sort(by_depth.begin(), by_depth.end());
  int added = 0;
  for (const auto& [z, i] : by_depth) {
    const bool has_point = last_.points[i] && !last_.points[i]->bad;
    if (!has_point) {
      auto p = std::make_shared<MapPoint>(-1, last_.unprojectToWorld(i), nullptr);
      std::copy(last_.descriptor(i), last_.descriptor(i) + 32, p->descriptor.begin());
      last_.points[i] = std::move(p);
      last_.outlier[i] = 0;
      ++added;
    }
    // As many as a keyframe would map (createKeyFrame), so the motion model
    // sees the far structure that pins the rotation.
    if (z > close_depth_ && added >= options_.keyframes.min_new_points) break;
  }
}

int Tracker::discardOutliers() {
  int map_matches = 0;
  for (int i = 0; i < current_.size(); ++i) {
    if (!current_.points[i]) continue;
    if (current_.outlier[i]) {
      current_.points[i] = nullptr;
      current_.outlier[i] = 0;
    } else if (!current_.points[i]->isTemporary() && !current_.points[i]->observations.empty()) {
      ++map_matches;
    }
  }
  return map_matches;
}

int Tracker::countMapInliers() const {
  int n = 0;
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    n += p && !current_.outlier[i] && !p->isTemporary() && !p->observations.empty();
  }
  return n;
}

void Tracker::removeDynamicFeatures() {
  ScopedStageTimer timer(&times_.geometry);
  const auto clusters = currentClusters();
  if (!clusters) return;
  geometry_.clustering_ms = clustering_->lastClusteringMs();
  geometry_.clusters = clusters->clusters;
  geometry_.labels = clusters;
  if (clusters->clusters == 0) return;

  // Evidence per feature: its match to the reference keyframe by descriptor
  // alone (no search window, so an object that moved since the keyframe still
  // matches, and its error is the whole displacement), else its stage-1 match
  // (last frame or local map: only the motion of one frame).
  std::vector<std::shared_ptr<MapPoint>> evidence(current_.points);
  // Carried evidence (a match to a feature found moving in the last frame) is
  // the oldest position of its chain of such matches, at most
  // geometry.carried_frames back: a mover that slows down or turns keeps the
  // error of several frames of its motion, not of one. Each link is a
  // projection-search match that may have hopped to a look-alike neighbour
  // (floor planks), so a chain of n links is judged at n times the noise of
  // one: its chi2 is divided by n (a steady mover's grows as n^2).
  chain_.assign(current_.size(), {});
  std::vector<int> chain_links(current_.size(), 1);
  const auto max_links = static_cast<std::size_t>(options_.geometry.carried_frames);
  for (std::size_t i = 0; i < carried_.size(); ++i) {
    if (!carried_[i]) continue;
    std::vector<Vec3>& chain = chain_[i];
    chain.push_back(carried_[i]->position);
    const auto from = carried_from_.find(carried_[i].get());
    if (from != carried_from_.end() && from->second < static_cast<int>(last_chain_.size()))
      for (const Vec3& p : last_chain_[from->second]) {
        if (chain.size() >= max_links) break;
        chain.push_back(p);
      }
    if (evidence[i]) continue;
    evidence[i] = carried_[i];
    chain_links[i] = static_cast<int>(chain.size());
  }
  // Matches of the projection search with a close second in the window are
  // mostly mismatches on repetitive texture (README): not evidence.
  // Their map points still learn the verdict of the cluster they fell in
  // (below): the culling of mapped movers should not lose them.
  std::vector<char> ambiguous(current_.size(), 0);
  std::vector<std::shared_ptr<MapPoint>> ambiguous_points;
  std::vector<int> ambiguous_features;
  if (options_.geometry.evidence_ratio > 0)
    for (int i = 0; i < current_.size(); ++i)
      if (evidence[i] && match_ratio_[i] > options_.geometry.evidence_ratio) {
        if (evidence[i] == current_.points[i] && !evidence[i]->isTemporary()) {
          ambiguous_points.push_back(evidence[i]);
          ambiguous_features.push_back(i);
        }
        evidence[i] = nullptr;
        ambiguous[i] = 1;
      }
  // Only where stage 1 has no map point: a map-point match already measures
  // the motion since mapping, and window-free matching has more mismatches.
  if (anchors_.empty() && reference_ && !reference_->bad)
    for (const auto& [j, i] : matchByDescriptor(current_, *reference_, 0.7f))
      if (!evidence[j] || evidence[j]->isTemporary()) evidence[j] = reference_->frame.points[i];
  std::vector<char> from_map(current_.size());
  for (int i = 0; i < current_.size(); ++i) from_map[i] = evidence[i] && evidence[i] == current_.points[i];
  // The anchor frame's depth point wins over all of these: its baseline is
  // fixed, so a slow mover's error is not one frame's motion.
  std::vector<Vec3> anchor_point(current_.size());
  std::vector<char> has_anchor(current_.size(), 0);
  std::vector<int> anchor_distance(current_.size(), 0);
  std::vector<const std::uint8_t*> anchor_descriptor(current_.size(), nullptr);
  // Matched to a feature that lay in a dynamic cluster (anchor or last frame).
  std::vector<char> inherited(current_.size(), 0);
  for (std::size_t i = 0; i < carried_.size(); ++i) inherited[i] = carried_[i] != nullptr && !ambiguous[i];
  // Features following a semantic mask count as moving before too: they keep
  // their anchor evidence and hold their cluster like the module's own.
  for (int i = 0; i < current_.size(); ++i) inherited[i] |= current_.dynamic[i] == kSemanticDynamic;
  // Feature j's anchor evidence: keypoint i of `anchor`, `back` frames back.
  std::vector<int> anchor_baseline(current_.size(), 0);
  const auto takeAnchor = [&](int j, const Frame& anchor, int i, int back) {
    anchor_baseline[j] = back;
    anchor_point[j] = anchor.unprojectToWorld(i);
    has_anchor[j] = 1;
    anchor_distance[j] = features::hammingDistance(anchor.descriptor(i), current_.descriptor(j));
    anchor_descriptor[j] = anchor.descriptor(i);
    inherited[j] |= anchor.dynamic[i];
  };
  if (!anchors_.empty()) {
    const auto matches = anchor_matches_.valid() ? anchor_matches_.get() : matchAnchor();
    for (const auto& [j, i] : matches) takeAnchor(j, anchors_.front(), i, static_cast<int>(anchors_.size()));
  }
  // Motion evidence needs the static hypothesis to be worse. Where the
  // evidence point projects under the pose, a keypoint whose descriptor is
  // within geometry.static_match_margin bits of the matched one's explains the
  // feature as static just as well: the match took another copy of a
  // repeating pattern (floor planks, a stripe), and it is no evidence.
  const int static_margin = options_.geometry.static_match_margin;
  const auto staticExplains = [&](int i, const Vec3& p_w, const std::uint8_t* descriptor, int distance) {
    if (static_margin < 0 || !descriptor) return false;
    const Vec3 p = current_.T_c_w * p_w;
    if (p.z() <= camera_.min_depth) return false;
    const double u = camera_.fx * p.x() / p.z() + camera_.cx, v = camera_.fy * p.y() / p.z() + camera_.cy;
    const int level = current_.keys[i].octave;
    const float radius = 3.0f * static_cast<float>(levels_.scales[level]);
    for (int j : current_.grid.query(current_.keys, current_.un, static_cast<float>(u), static_cast<float>(v), radius,
                                     std::max(0, level - 1), std::min(levels_.levels - 1, level + 1)))
      if (j != i && features::hammingDistance(descriptor, current_.descriptor(j)) <= distance + static_margin)
        return true;
    return false;
  };
  // The photometric test of the static hypothesis: against the frame
  // photo_frames_back back and, with photo_frames 2 or 3, half as far each
  // time (10, 5, 3), all of which must pass (or all but one, which must still
  // come near: PhotoVote): a mover whose texture matches by chance at the
  // static hypothesis in one frame seldom does in all. A patch
  // that cannot be tested that far back (it leaves the image there, or the
  // history is shorter) is tested at half the distance instead, once
  // (geometry.photo_fallback): at shorter baselines a slow mover matches.
  const std::size_t seen = seen_depth_.size();
  std::vector<std::vector<std::size_t>> photo_tries;  // frame indices per try, nearest baseline last
  for (int far = options_.geometry.photo_frames_back, tries = options_.geometry.photo_fallback ? 2 : 1;
       tries > 0 && far >= 2; far /= 2, --tries) {
    std::vector<std::size_t>& frames = photo_tries.emplace_back();
    // Too short a history: out of range, the patch cannot be tested there.
    for (int k = far; static_cast<int>(frames.size()) < options_.geometry.photo_frames; k = (k + 1) / 2) {
      frames.push_back(seen >= static_cast<std::size_t>(k) ? seen - k : seen);
      if (k <= 2) break;
    }
  }
  // 1: the static hypothesis explains the patch; 0: its depth agrees but its
  // pixels do not match; -1: no verdict on its pixels (untestable, or its
  // depth disagrees in a frame).
  const auto photoVerdict = [&](int i) {
    if (current_.depth[i] <= 0) return -1;
    for (const std::vector<std::size_t>& frames : photo_tries) {
      PhotoVote vote(options_.geometry);
      bool testable = true;
      for (std::size_t f : frames) {
        PhotoAgreement a;
        testable = photoAgreement(i, clusters->depth, f, &a);
        if (!testable) break;
        // Failed (or depth disagrees): the other frames cannot change the
        // verdict. Most dropped features are movers and stop here.
        if (a.depth_share < options_.geometry.photo_depth_share) return -1;
        vote.add(a.ncc);
        if (vote.failed()) break;
      }
      if (testable) return vote.passed() ? 1 : 0;
    }
    return -1;
  };
  const auto photoStatic = [&](int i) { return photoVerdict(i) == 1; };
  const int min_features = options_.geometry.verdict.min_features;
  std::vector<int> anchored_in_cluster(clusters->clusters, 0);
  for (int i = 0; i < current_.size(); ++i) {
    const cv::Point2f& px = current_.keys[i].pt;
    current_.cluster[i] = static_cast<std::int16_t>(clusters->labelAt(camera_, px.x, px.y, current_.depth[i]));
    if (current_.cluster[i] >= 0 && has_anchor[i]) ++anchored_in_cluster[current_.cluster[i]];
  }
  // Nearer anchors (geometry.near_anchor_frames): the features of clusters
  // with too few anchor matches are matched to the frames k = N, N - 1, ..., 2
  // back, while their cluster still has too few. A cluster with enough
  // matches at k is judged by them: a fixed baseline shorter than the
  // anchor's, where its look changed less (a surface turning edge-on), but
  // longer and surer than a map point's or a carried match's. Its features
  // matched at a longer baseline keep that match. It reads only the frame's
  // keypoints and labels: the helper matches while the free-space test runs.
  auto nearerAnchors = [this, anchored = anchored_in_cluster, min_features, n = clusters->clusters]() mutable {
    std::vector<NearerAnchor> out;
    for (int k = std::min(options_.geometry.near_anchor_frames, static_cast<int>(anchors_.size()) - 1); k >= 2; --k) {
      std::vector<int> features;
      for (int i = 0; i < current_.size(); ++i)
        if (current_.cluster[i] >= 0 && anchored[current_.cluster[i]] < min_features) features.push_back(i);
      if (features.empty()) break;
      const auto matches = matchSomeByDescriptor(current_, anchors_[anchors_.size() - k], 0.7f, features);
      std::vector<int> found(n, 0);
      for (const auto& [j, i] : matches) ++found[current_.cluster[j]];
      for (const auto& [j, i] : matches)
        if (found[current_.cluster[j]] >= min_features) out.push_back({j, i, k});
      for (int c = 0; c < n; ++c)
        if (found[c] >= min_features) anchored[c] = min_features;  // judged at this baseline: not tried nearer
    }
    return out;
  };
  std::future<std::vector<NearerAnchor>> nearer;
  if (helper_ && options_.geometry.near_anchor_frames > 0) nearer = helper_->run(nearerAnchors);
  const FreeSpace free = freeSpaceViolations(*clusters);
  geometry_.freespace = free.share;
  for (const NearerAnchor& a : nearer.valid() ? nearer.get() : nearerAnchors()) {
    if (has_anchor[a.feature]) continue;  // keeps its match at the longer baseline
    takeAnchor(a.feature, anchors_[anchors_.size() - a.frames_back], a.keypoint, a.frames_back);
    ++anchored_in_cluster[current_.cluster[a.feature]];
  }

  // A cluster with enough anchor matches is judged by them alone (fixed
  // baseline); the others by whatever evidence their features have.
  std::vector<geometry::FeatureResidual> residuals;
  std::vector<int> matched;
  std::vector<JudgedFeature::Evidence> kinds;
  std::vector<EvidenceError> errors;
  std::vector<Vec3> residual_vectors(current_.size(), Vec3::Zero());
  const auto evidenceKind = [&](int i, bool by_anchor) {
    return by_anchor     ? JudgedFeature::Evidence::kAnchor
           : from_map[i] ? JudgedFeature::Evidence::kMapPoint
                         : JudgedFeature::Evidence::kCarried;
  };
  struct Explained {
    int index;
    double chi2;
    JudgedFeature::Evidence kind;
  };
  std::vector<Explained> explained;
  // The chi2 of each feature judged by carried evidence (0: other or none),
  // for geometry.lone_moving_chi2.
  std::vector<double> carried_chi2(current_.size(), 0.0);
  const auto judge = [&](bool anchored) {
    std::fill(carried_chi2.begin(), carried_chi2.end(), 0.0);
    explained.clear();
    residuals.clear();
    matched.clear();
    kinds.clear();
    errors.clear();
    for (int i = 0; i < current_.size(); ++i) {
      const int c = current_.cluster[i];
      if (c < 0) continue;
      const auto& p = evidence[i];
      const bool by_anchor = anchored && has_anchor[i];
      if (!by_anchor && ((anchored && anchored_in_cluster[c] >= min_features) || !p || p->bad)) continue;
      // A carried chain is long-baseline evidence like the anchor's: when the
      // frame falls back to its stage-1 matches (the pose is in doubt), the
      // carried match counts only for its last frame's point.
      const bool chained = !by_anchor && chain_links[i] > 1;  // p is the carried point
      const Vec3& point = by_anchor ? anchor_point[i] : chained && anchored ? chain_[i].back() : p->position;
      EvidenceError e = evidenceError(i, point);
      if (chained && anchored) e.level_chi2 /= chain_links[i];
      residual_vectors[i] = e.residual;
      // Only disagreeing evidence needs the test (chi2 above the cap).
      if (e.level_chi2 > options_.geometry.verdict.rho_cap) {
        const std::uint8_t* d = by_anchor ? anchor_descriptor[i] : p->descriptor.data();
        const int distance = by_anchor ? anchor_distance[i] : features::hammingDistance(d, current_.descriptor(i));
        // Set aside from the verdict, but still a matched feature whose
        // outcome is reported (and scored).
        if (staticExplains(i, point, d, distance)) {
          explained.push_back({i, e.level_chi2, evidenceKind(i, by_anchor)});
          continue;
        }
      }
      errors.push_back(e);
      residuals.push_back({c, e.level_chi2, inherited[i] != 0});
      matched.push_back(i);
      kinds.push_back(evidenceKind(i, by_anchor));
      if (kinds.back() == JudgedFeature::Evidence::kCarried) carried_chi2[i] = e.level_chi2;
    }
    geometry::ClusterVerdict v = geometry::classifyClusters(residuals, clusters->clusters, options_.geometry.verdict);
    const GeometryOptions& g = options_.geometry;
    if (g.frame_sigma_factor <= 0 || residuals.empty()) return v;
    // Experiment (off by default, README): the frame's own image noise.
    // Static evidence misses by about the same number of pixels at every
    // pyramid level on real images (two tracked poses and a depth point, not
    // keypoint localisation), so the level sigma alone under-states it for
    // fine levels. "reference": estimated from the features of the clusters
    // at or below the reference score of a first verdict (static by
    // construction of the reference), so a mover does not inflate it.
    std::vector<double> per_dof;
    for (std::size_t k = 0; k < residuals.size(); ++k) {
      if (errors[k].dof == 0) continue;
      const geometry::ClusterScore& cs = v.clusters[residuals[k].cluster];
      if (g.frame_sigma_from == "reference" && !(cs.judged && cs.mean_rho <= v.reference)) continue;
      per_dof.push_back(errors[k].pixel2 / errors[k].dof);
    }
    if (per_dof.size() < 8) return v;
    std::size_t q = static_cast<std::size_t>(g.frame_sigma_quantile * (per_dof.size() - 1) + 0.5);
    std::nth_element(per_dof.begin(), per_dof.begin() + q, per_dof.end());
    const double frame_sigma2 = g.frame_sigma_factor * per_dof[q];
    for (std::size_t k = 0; k < residuals.size(); ++k) {
      const EvidenceError& e = errors[k];
      const double sigma2 = std::max(g.frame_sigma_min_scale / e.inv_level_sigma2, frame_sigma2);
      residuals[k].chi2 = e.pixel2 / sigma2 + e.depth_chi2;
    }
    return geometry::classifyClusters(residuals, clusters->clusters, options_.geometry.verdict);
  };
  bool anchored = !anchors_.empty();
  // The anchor evidence is measured under the pose that explains it best,
  // when that is clearly better than the initial pose (which a slowly
  // starting mover may have pulled into a compromise that both it and the
  // room pass). Only the verdict: the pose is refitted on the stage-1
  // matches, without the dynamic clusters, from the initial pose.
  const SE3 initial_pose = current_.T_c_w;
  const bool consensus = anchored && options_.geometry.consensus_ratio > 0 &&
                         adoptConsensusPose(has_anchor, anchor_point, inherited);
  geometry_.consensus_pose = consensus;
  geometry::ClusterVerdict verdict = judge(anchored);
  // Anchor matches measure the initial pose independently of stage 1: when
  // most of the view disagrees with it, the pose is what is wrong (stage 1
  // had few map points), not the world; the frame is judged by its stage-1
  // matches instead, which are consistent with the pose they produced.
  if (anchored) {
    int judged = 0, dynamic = 0;
    for (const geometry::ClusterScore& c : verdict.clusters)
      if (c.judged) judged += c.features, dynamic += c.dynamic ? c.features : 0;
    if (dynamic > options_.geometry.max_dynamic_fraction * judged) {
      anchored = false;
      current_.T_c_w = initial_pose;  // the stage-1 matches agree with the pose they produced
      geometry_.consensus_pose = false;
      verdict = judge(false);
      geometry_.anchor_fallback = true;
    }
  }
  if (consensus) current_.T_c_w = initial_pose;
  // Dense evidence: a cluster a good share of whose depth samples lie in space
  // the anchor frame saw empty has moved, whatever its features say.
  // As with the anchor evidence, when that would make most of the view
  // (geometry.max_dynamic_fraction of the samples) dynamic, the pose is what
  // is wrong, not the world: then it flags nothing.
  const auto addFreeSpace = [&](geometry::ClusterVerdict& v) {
    const double share = options_.geometry.freespace_flag;
    if (share <= 0) return;
    std::vector<std::size_t> added;
    int samples = 0, dynamic_samples = 0;
    for (std::size_t c = 0; c < v.clusters.size(); ++c) {
      samples += clusters->sizes[c];
      if (!v.clusters[c].dynamic && geometry_.freespace[c] >= share) added.push_back(c);
      if (v.clusters[c].dynamic || geometry_.freespace[c] >= share) dynamic_samples += clusters->sizes[c];
    }
    if (dynamic_samples > options_.geometry.max_dynamic_fraction * samples) {
      geometry_.freespace_vetoed = !added.empty();
      return;
    }
    for (std::size_t c : added) v.clusters[c].dynamic = true;
    v.dynamic_clusters += static_cast<int>(added.size());
  };
  addFreeSpace(verdict);
  // Features of a dynamic cluster whose anchor match agrees with the pose:
  // static surface the cluster straddles (the anchor evidence of a mover is
  // nearly always far above the cap, of static features below it; README).
  std::vector<char> released(current_.size(), 0);
  // The moved surface grown from the free-space violations: in a dynamic
  // cluster that holds violations but whose features mostly lie off that
  // surface (a walker's legs and the floor they stand on), the features off
  // it are static.
  const double split_keep = options_.geometry.freespace_split_keep;
  const cv::Mat moved = split_keep > 0 ? growMovedSurface(*clusters, free) : cv::Mat();
  const auto onMoved = [&](int i) {
    const int step = clusters->step;
    const int c0 = static_cast<int>(current_.keys[i].pt.x) / step, r0 = static_cast<int>(current_.keys[i].pt.y) / step;
    const double radius2 = options_.geometry.freespace_split_radius_m * options_.geometry.freespace_split_radius_m;
    const float z = current_.depth[i];
    const Vec3 p = z > 0 ? camera_.unproject(Vec2(current_.un[i].x, current_.un[i].y), z) : Vec3::Zero();
    for (int r = std::max(0, r0 - 3); r <= std::min(moved.rows - 1, r0 + 3); ++r)
      for (int c = std::max(0, c0 - 3); c <= std::min(moved.cols - 1, c0 + 3); ++c) {
        if (!moved.at<std::uint8_t>(r, c)) continue;
        if (std::abs(r - r0) + std::abs(c - c0) <= 1) return true;  // its own cell or a 4-neighbour
        const cv::Vec3f& q = free.points.at<cv::Vec3f>(r, c);
        if (z > 0 && (Vec3(q[0], q[1], q[2]) - p).squaredNorm() < radius2) return true;
      }
    return false;
  };
  const auto release = [&](const geometry::ClusterVerdict& v) {
    std::fill(released.begin(), released.end(), 0);
    const double limit = options_.geometry.anchor_release_chi2;
    if (limit > 0)
      for (std::size_t k = 0; k < matched.size(); ++k)
        if (kinds[k] == JudgedFeature::Evidence::kAnchor && residuals[k].chi2 < limit) released[matched[k]] = 1;
    if (moved.empty()) return;
    std::vector<int> on(clusters->clusters, 0), off(clusters->clusters, 0);
    std::vector<char> off_moved(current_.size(), 0);
    for (int i = 0; i < current_.size(); ++i) {
      const int c = current_.cluster[i];
      if (c < 0 || !v.clusters[c].dynamic || free.violations[c] < options_.geometry.freespace_split_min_samples) continue;
      off_moved[i] = !onMoved(i);
      ++(off_moved[i] ? off : on)[c];
    }
    // Only a feature whose own evidence agrees with the pose goes back into
    // it: one that disagrees is a part of the mover the growth did not reach,
    // and one without evidence keeps its cluster's verdict.
    std::vector<char> agrees(current_.size(), 0);
    for (std::size_t k = 0; k < matched.size(); ++k)
      agrees[matched[k]] = residuals[k].chi2 <= options_.geometry.freespace_split_protect_chi2;
    for (int i = 0; i < current_.size(); ++i) {
      const int c = current_.cluster[i];
      if (off_moved[i] && agrees[i] && on[c] < split_keep * (on[c] + off[c])) released[i] = 1;
    }
  };
  // A feature leaves the pose and counts as moving: in a dynamic cluster, not
  // released; or in a cluster too small to judge, still moving along its own
  // track (geometry.lone_moving_chi2).
  const double lone_chi2 = options_.geometry.lone_moving_chi2;
  const auto dropped = [&](int i, const geometry::ClusterVerdict& v) {
    if (current_.cluster[i] < 0 || released[i]) return false;
    const geometry::ClusterScore& c = v.clusters[current_.cluster[i]];
    return c.dynamic || (lone_chi2 > 0 && !c.judged && inherited[i] && carried_chi2[i] > lone_chi2);
  };
  // Drops the features of dynamic clusters from the pose and refits it.
  const std::vector<std::shared_ptr<MapPoint>> points = current_.points;
  const std::vector<char> outlier = current_.outlier;
  bool refitted = false;  // the pose is fitted without the dropped features
  const auto remove = [&](const geometry::ClusterVerdict& v) {
    release(v);
    int removed = 0;
    for (int i = 0; i < current_.size(); ++i) {
      if (!dropped(i, v)) continue;
      current_.points[i] = nullptr;
      current_.outlier[i] = 0;
      ++removed;
    }
    refitted = removed > 0 && countMapInliers() >= 10;
    if (refitted) timedOptimizePose();
  };
  if (verdict.dynamic_clusters > 0 && options_.geometry.rejudge) {
    // The stage-1 pose still holds the movers' pull: judge again under the
    // pose refitted without them, from the same matches.
    remove(verdict);
    geometry::ClusterVerdict second = judge(anchored);
    addFreeSpace(second);
    bool same = second.dynamic_clusters == verdict.dynamic_clusters;
    for (std::size_t c = 0; same && c < second.clusters.size(); ++c)
      same = second.clusters[c].dynamic == verdict.clusters[c].dynamic;
    verdict = std::move(second);
    if (!same) {
      current_.points = points;
      current_.outlier = outlier;
      remove(verdict);
    }
    geometry_.rejudged = !same;
  } else {
    remove(verdict);
  }
  // Photometric detection (geometry.photo_detect_share, session 18): a
  // cluster with too few anchor matches is judged by short-baseline evidence
  // (map points mapped a frame or two before, carried matches), which a slow
  // mover passes. Its features' patches are tested as in the release below,
  // under the pose fitted without the dynamic clusters; a cluster most of
  // whose depth-agreeing patches still do not match (the texture moved along
  // the surface) is dynamic. Patches whose depth disagrees say nothing here
  // (occluded in that frame, say), nor are clusters that scored at or below
  // photo_detect_gate x the frame's reference tested (clearly static). As
  // with free space, nothing is added when that would make more than
  // max_dynamic_fraction of the view dynamic.
  if (options_.geometry.photo_detect_share > 0 && options_.geometry.photo_release_ncc > 0) {
    const GeometryOptions& g = options_.geometry;
    const int n_clusters = clusters->clusters;
    std::vector<int> tested(n_clusters, 0), failed(n_clusters, 0);
    for (int i = 0; i < current_.size(); ++i) {
      const int c = current_.cluster[i];
      if (c < 0 || anchored_in_cluster[c] >= min_features) continue;
      const geometry::ClusterScore& score = verdict.clusters[c];
      if (score.dynamic || (score.judged && score.mean_rho <= g.photo_detect_gate * verdict.reference)) continue;
      const int r = photoVerdict(i);
      if (r < 0) continue;
      ++tested[c];
      failed[c] += r == 0;
    }
    std::vector<int> added;
    int samples = 0, dynamic_samples = 0;
    for (int c = 0; c < n_clusters; ++c) {
      const bool detected = photoDetects(tested[c], failed[c], g);
      samples += clusters->sizes[c];
      if (detected) added.push_back(c);
      if (detected || verdict.clusters[c].dynamic) dynamic_samples += clusters->sizes[c];
    }
    if (!added.empty() && dynamic_samples <= g.max_dynamic_fraction * samples) {
      for (int c : added) verdict.clusters[c].dynamic = true;
      verdict.dynamic_clusters += static_cast<int>(added.size());
      // Not remove(verdict): that would also split the new clusters by the
      // free-space surface, whose violations did not flag them (12 runs:
      // poster-walk ATE 0.0080 against 0.0070 m, halfsphere recall 0.898
      // against 0.901).
      int removed = 0;
      for (int i = 0; i < current_.size(); ++i) {
        if (!dropped(i, verdict) || !current_.points[i]) continue;
        current_.points[i] = nullptr;
        current_.outlier[i] = 0;
        ++removed;
      }
      if (removed > 0 && countMapInliers() >= 10) {
        timedOptimizePose();
        refitted = true;
      }
    }
  }
  // The photometric test of the static hypothesis, under the pose fitted
  // without the dynamic clusters: judged under the initial pose, it confirms
  // a mover that stage 1 followed (MotionPriorHoldsStageOneOffTheBoard: a
  // 20 mm step); fitted without the mover, the pose no longer explains it.
  // A freed feature goes back into the pose with its stage-1 match. The pose
  // is refitted by stage 2 (local map), which follows at once; it is refitted
  // here first only when the freed features add a quarter or more to the
  // matches it rests on: then the pose fitted without them may sit on a
  // mover, and stage 2 would search the local map from there
  // (PhotometricReleaseHoldsUnderAVerdictThatFlagsTheRoom: 452 mm without
  // this refit). A few freed features change the pose too little to pay for
  // a pose optimisation (README, session 17).
  // The pose it is judged under must rest on most of the view: when the
  // dropped features are more than geometry.max_dynamic_fraction of the
  // clustered ones, it may rest on a mover, and the test would confirm it.
  int clustered = 0, dropped_count = 0;
  if (options_.geometry.photo_release_ncc > 0 && refitted)
    for (int i = 0; i < current_.size(); ++i)
      if (current_.cluster[i] >= 0) ++clustered, dropped_count += dropped(i, verdict);
  if (clustered > 0 && dropped_count <= options_.geometry.max_dynamic_fraction * clustered) {
    const int support = countMapInliers();
    int freed = 0;
    for (int i = 0; i < current_.size(); ++i) {
      if (!dropped(i, verdict) || (has_anchor[i] && !options_.geometry.photo_release_anchored) || !photoStatic(i))
        continue;
      released[i] = 1;
      photo_released_[i] = options_.geometry.photo_release_memory;
      current_.points[i] = points[i];
      current_.outlier[i] = 0;
      freed += points[i] != nullptr;
    }
    if (freed > 0 && 4 * freed >= support && countMapInliers() >= 10) timedOptimizePose();
  }
  geometry_.ran = true;
  geometry_.scores = verdict.clusters;
  geometry_.threshold = verdict.threshold;
  geometry_.dynamic_clusters = verdict.dynamic_clusters;

  // Every feature whose evidence was measured is reported, with its outcome;
  // those set aside from the verdict (`explained`) too.
  const auto report = [&](int i, double chi2, JudgedFeature::Evidence kind, bool set_aside) {
    const bool by_anchor = kind == JudgedFeature::Evidence::kAnchor;
    const int distance = by_anchor ? anchor_distance[i]
                                   : features::hammingDistance(evidence[i]->descriptor.data(), current_.descriptor(i));
    JudgedFeature f{current_.keys[i].pt.x, current_.keys[i].pt.y, dropped(i, verdict), current_.cluster[i],
                    static_cast<float>(chi2), kind, inherited[i] != 0, current_.depth[i], distance,
                    by_anchor ? 0.0f : match_ratio_[i], residual_vectors[i].cast<float>(),
                    geometry_.freespace[current_.cluster[i]]};
    f.explained = set_aside;
    f.baseline = by_anchor ? anchor_baseline[i] : 0;
    geometry_.judged.push_back(f);
  };
  const float w = static_cast<float>(options_.geometry.point_dynamic_weight);
  for (std::size_t k = 0; k < matched.size(); ++k) {
    const int i = matched[k];
    const bool dynamic = dropped(i, verdict);
    report(i, residuals[k].chi2, kinds[k], false);
    const auto& p = evidence[i];
    if (!p || p->bad || p->isTemporary()) continue;
    const float score = (1 - w) * p->dynamic_score.load(std::memory_order_relaxed) + (dynamic ? w : 0.0f);
    p->dynamic_score.store(score, std::memory_order_relaxed);
    if (dynamic && dynamic_suspects_.size() < 20000) dynamic_suspects_.push_back(p);
  }
  for (const Explained& x : explained) report(x.index, x.chi2, x.kind, true);
  for (std::size_t k = 0; k < ambiguous_points.size(); ++k) {
    const int c = current_.cluster[ambiguous_features[k]];
    const auto& p = ambiguous_points[k];
    if (c < 0 || p->bad) continue;
    const bool dynamic = verdict.clusters[c].dynamic;
    const float score = (1 - w) * p->dynamic_score.load(std::memory_order_relaxed) + (dynamic ? w : 0.0f);
    p->dynamic_score.store(score, std::memory_order_relaxed);
    if (dynamic && dynamic_suspects_.size() < 20000) dynamic_suspects_.push_back(p);
  }
  for (int i = 0; i < current_.size(); ++i) {
    if (!dropped(i, verdict)) continue;
    current_.dynamic[i] = 1;
    ++geometry_.dynamic_features;
  }
}

bool photoDetects(int tested, int failed, const GeometryOptions& options) {
  return options.photo_detect_share > 0 && tested >= options.photo_detect_min &&
         failed > options.photo_detect_share * tested;
}

void PhotoVote::add(double ncc) {
  if (ncc < worst_) {
    second_ = worst_;
    worst_ = ncc;
  } else if (ncc < second_) {
    second_ = ncc;
  }
  ++frames_;
}

Tracker::FreeSpace Tracker::freeSpaceViolations(const geometry::DepthClusters& clusters) const {
  FreeSpace out;
  out.share.assign(clusters.clusters, -1.0f);
  out.violations.assign(clusters.clusters, 0);
  if (clusters.depth.empty() || clusters.labels.empty()) return out;
  out.violated = cv::Mat::zeros(clusters.labels.size(), CV_8U);
  out.points = cv::Mat::zeros(clusters.labels.size(), CV_32FC3);
  const auto back = static_cast<std::size_t>(options_.geometry.freespace_frames);
  if (seen_depth_.empty()) return out;
  const SeenDepth& anchor = seen_depth_[seen_depth_.size() >= back ? seen_depth_.size() - back : 0];
  if (anchor.depth.empty()) return out;
  const cv::Mat& seen = anchor.depth;
  const SE3 T_a_c = anchor.T_c_w * current_.T_c_w.inverse();
  const Mat3 R = T_a_c.linear();
  const Vec3 t = T_a_c.translation();
  const bool distorted = camera_.hasDistortion();
  const double tol0 = options_.geometry.freespace_tolerance_m, tol2 = options_.geometry.freespace_tolerance_z2;
  std::vector<int> tested(clusters.clusters, 0);
  std::vector<int>& violated = out.violations;
  const int half = clusters.step / 2;
  for (int r = 0; r < clusters.labels.rows; ++r) {
    const auto* label = clusters.labels.ptr<std::int16_t>(r);
    const int y = r * clusters.step + half;
    for (int c = 0; c < clusters.labels.cols; ++c) {
      if (label[c] < 0) continue;
      const int x = c * clusters.step + half;
      const float z = clusters.depth.at<float>(y, x);
      Vec2 uv(x, y);
      if (distorted) uv = camera_.undistortPixel(uv);
      const Vec3 p_c = camera_.unproject(uv, z);
      out.points.at<cv::Vec3f>(r, c) = cv::Vec3f(p_c.x(), p_c.y(), p_c.z());
      const Vec3 p = R * p_c + t;  // in the anchor camera
      if (p.z() <= camera_.min_depth) continue;
      Vec2 q = camera_.project(p);
      if (distorted) q = camera_.distortPixel(q);
      const int qx = static_cast<int>(std::lround(q.x())), qy = static_cast<int>(std::lround(q.y()));
      if (qx < 1 || qy < 1 || qx >= seen.cols - 1 || qy >= seen.rows - 1) continue;
      // The anchor's depth image is cold: the sample below this one lands
      // about a step further down it, so its rows are fetched now.
      for (int ahead = qy + clusters.step - 1; ahead <= std::min(seen.rows - 1, qy + clusters.step + 1); ++ahead)
        __builtin_prefetch(seen.ptr<float>(ahead) + qx);
      // The nearest surface the anchor saw around that pixel: a point on a
      // depth edge may fall on either side of it.
      float nearest = std::numeric_limits<float>::max();
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const float d = seen.at<float>(qy + dy, qx + dx);
          if (d > camera_.min_depth && d < camera_.max_depth) nearest = std::min(nearest, d);
        }
      if (nearest == std::numeric_limits<float>::max()) continue;
      ++tested[label[c]];
      if (p.z() < nearest - (tol0 + tol2 * p.z() * p.z())) {
        ++violated[label[c]];
        out.violated.at<std::uint8_t>(r, c) = 1;
      }
    }
  }
  for (int j = 0; j < clusters.clusters; ++j)
    if (tested[j] >= 8) out.share[j] = static_cast<float>(violated[j]) / static_cast<float>(tested[j]);
  return out;
}

bool Tracker::photoAgreement(int i, const cv::Mat& depth, std::size_t frame, PhotoAgreement* out) const {
  if (frame >= seen_depth_.size()) return false;
  const SeenDepth& seen = seen_depth_[frame];
  if (seen.gray.empty() || seen.depth.empty() || current_.gray.empty()) return false;
  const int r = options_.geometry.photo_patch_radius;
  const int x0 = static_cast<int>(std::lround(current_.keys[i].pt.x));
  const int y0 = static_cast<int>(std::lround(current_.keys[i].pt.y));
  const cv::Mat& gray = current_.gray;
  if (x0 - r < 0 || y0 - r < 0 || x0 + r >= gray.cols || y0 + r >= gray.rows) return false;
  const SE3 T_s_c = seen.T_c_w * current_.T_c_w.inverse();
  const Mat3 R = T_s_c.linear();
  const Vec3 t = T_s_c.translation();
  const bool distorted = camera_.hasDistortion();
  const double tol0 = options_.geometry.freespace_tolerance_m, tol2 = options_.geometry.freespace_tolerance_z2;
  const int n = (2 * r + 1) * (2 * r + 1);
  const auto sample = [&](double qx, double qy) {  // bilinear, in the image (first pass)
    const int ix = static_cast<int>(qx), iy = static_cast<int>(qy);
    const double fx = qx - ix, fy = qy - iy;
    const std::uint8_t* row0 = seen.gray.ptr<std::uint8_t>(iy);
    const std::uint8_t* row1 = seen.gray.ptr<std::uint8_t>(iy + 1);
    return (1 - fy) * ((1 - fx) * row0[ix] + fx * row0[ix + 1]) + fy * ((1 - fx) * row1[ix] + fx * row1[ix + 1]);
  };
  // Two passes. The first warps the patch and checks its depth: most dropped
  // features are movers whose depth disagrees there, and once more pixels
  // disagree than geometry.photo_depth_share allows, the patch has failed
  // whatever its intensities; only whether it stays in the image is still
  // needed (a patch that leaves it is untestable, and tested nearer). The
  // second pass samples the intensities of a patch whose depth agrees.
  constexpr int kMaxPatch = 31 * 31;  // geometry.photo_patch_radius <= 15 (options)
  std::array<double, kMaxPatch> qx, qy;
  const int may_disagree = n - static_cast<int>(std::ceil(options_.geometry.photo_depth_share * n - 1e-9));
  // The patch's rows lie on as many cache lines, mostly cold: all are
  // fetched at once (the seen frame's below, once the warp places them).
  for (int y = y0 - r; y <= y0 + r; ++y) {
    if (!depth.empty()) {
      __builtin_prefetch(depth.ptr<float>(y) + x0 - r);
      __builtin_prefetch(depth.ptr<float>(y) + x0 + r);
    }
    __builtin_prefetch(gray.ptr<std::uint8_t>(y) + x0);
  }
  // The patch's depths, read once. A pixel without depth takes the
  // keypoint's: the patch is small.
  std::array<float, kMaxPatch> patch_z;
  float z_near = current_.depth[i], z_far = current_.depth[i];
  for (int y = y0 - r, k = 0; y <= y0 + r; ++y) {
    const float* depth_row = depth.empty() ? nullptr : depth.ptr<float>(y);
    for (int x = x0 - r; x <= x0 + r; ++x, ++k) {
      const float z = depth_row ? depth_row[x] : 0.0f;
      patch_z[k] = z > camera_.min_depth && z < camera_.max_depth ? z : current_.depth[i];
      z_near = std::min(z_near, patch_z[k]), z_far = std::max(z_far, patch_z[k]);
    }
  }
  // In the image with a bilinear neighbourhood (the second pass samples it).
  const auto inImage = [&](const Vec2& q, double margin) {
    return q.x() >= margin && q.y() >= margin && q.x() < seen.gray.cols - 1 - margin &&
           q.y() < seen.gray.rows - 1 - margin;
  };
  // Whether the whole patch provably stays in front of the seen camera and
  // in its image, without warping each pixel: the patch's rays between its
  // nearest and farthest depth fill a truncated pyramid, whose image under a
  // pinhole camera lies inside the hull of its 8 corners' images. Then the
  // first pass may stop as soon as the depth has failed (the result is the
  // same as warping every pixel); a camera with distortion warps them all.
  bool stays_in = !distorted;
  for (int corner = 0; corner < 8 && stays_in; ++corner) {
    const Vec2 uv(corner & 1 ? x0 + r : x0 - r, corner & 2 ? y0 + r : y0 - r);
    const Vec3 p = R * camera_.unproject(uv, corner & 4 ? z_far : z_near) + t;
    stays_in = p.z() > camera_.min_depth && inImage(camera_.project(p), 0.01);
  }
  // Without distortion the warp is linear in the pixel before the division:
  // p = z * (a + x * b + y * c) + t, one reciprocal per pixel.
  const Vec3 b = R.col(0) / camera_.fx, c = R.col(1) / camera_.fy;
  const Vec3 a = R.col(2) - camera_.cx * b - camera_.cy * c;
  // Pixel (x, y) at depth z in the seen camera (p) and image (q); false
  // when behind it.
  const auto warp = [&](int x, int y, double z, Vec3* p, Vec2* q) {
    if (distorted) {
      *p = R * camera_.unproject(camera_.undistortPixel(Vec2(x, y)), z) + t;
      if (p->z() <= camera_.min_depth) return false;
      *q = camera_.distortPixel(camera_.project(*p));
      return true;
    }
    *p = z * (a + x * b + y * c) + t;
    if (p->z() <= camera_.min_depth) return false;
    const double inv_z = 1.0 / p->z();
    *q = Vec2(camera_.fx * p->x() * inv_z + camera_.cx, camera_.fy * p->y() * inv_z + camera_.cy);
    return true;
  };
  // The seen frame's images are cold (several frames back), and each patch
  // row lands on other cache lines: their loads are issued together first
  // rather than one row's miss after another's.
  for (int y = y0 - r, k = r; y <= y0 + r; ++y, k += 2 * r + 1) {
    Vec3 p;
    Vec2 q;
    if (!warp(x0, y, patch_z[k], &p, &q) || !inImage(q, r + 1.0)) continue;
    const int qx = static_cast<int>(q.x()), qy = static_cast<int>(q.y());
    __builtin_prefetch(seen.depth.ptr<float>(qy) + qx - r);
    __builtin_prefetch(seen.depth.ptr<float>(qy) + qx + r);
    __builtin_prefetch(seen.gray.ptr<std::uint8_t>(qy) + qx);
    __builtin_prefetch(seen.gray.ptr<std::uint8_t>(qy + 1) + qx);
  }
  int agree = 0, k = 0;
  for (int y = y0 - r; y <= y0 + r; ++y) {
    for (int x = x0 - r; x <= x0 + r; ++x, ++k) {
      const float z = patch_z[k];
      Vec3 p;
      Vec2 q;
      if (!warp(x, y, z, &p, &q) || !inImage(q, 0.0)) return false;
      qx[k] = q.x(), qy[k] = q.y();
      const float zs = seen.depth.at<float>(static_cast<int>(q.y() + 0.5), static_cast<int>(q.x() + 0.5));
      agree += zs > camera_.min_depth && std::abs(zs - p.z()) < tol0 + tol2 * p.z() * p.z();
      if (stays_in && k + 1 - agree > may_disagree) {
        // Failed on depth; the share reported is at least the final one,
        // and already below geometry.photo_depth_share.
        out->depth_share = static_cast<double>(n - (k + 1 - agree)) / n;
        out->ncc = -1;
        return true;
      }
    }
  }
  out->depth_share = static_cast<double>(agree) / n;
  out->ncc = -1;
  if (n - agree > may_disagree) return true;
  double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
  k = 0;
  for (int y = y0 - r; y <= y0 + r; ++y) {
    const std::uint8_t* gray_row = gray.ptr<std::uint8_t>(y);
    for (int x = x0 - r; x <= x0 + r; ++x, ++k) {
      const double a = gray_row[x], b = sample(qx[k], qy[k]);
      sa += a, sb += b, saa += a * a, sbb += b * b, sab += a * b;
    }
  }
  const double va = saa - sa * sa / n, vb = sbb - sb * sb / n;
  if (va > 1e-6 && vb > 1e-6) out->ncc = (sab - sa * sb / n) / std::sqrt(va * vb);
  return true;
}

cv::Mat Tracker::growMovedSurface(const geometry::DepthClusters& clusters, const FreeSpace& free) const {
  if (free.violated.empty()) return cv::Mat();
  const int rows = free.points.rows, cols = free.points.cols;
  // Unit normals of the samples from their grid neighbours (zero: unknown).
  cv::Mat normals = cv::Mat::zeros(rows, cols, CV_32FC3);
  const auto point = [&](int r, int c) {
    const cv::Vec3f& v = free.points.at<cv::Vec3f>(r, c);
    return Vec3(v[0], v[1], v[2]);
  };
  for (int r = 1; r + 1 < rows; ++r)
    for (int c = 1; c + 1 < cols; ++c) {
      const Vec3 p = point(r, c), l = point(r, c - 1), rt = point(r, c + 1), u = point(r - 1, c), d = point(r + 1, c);
      if (p.z() <= 0 || l.z() <= 0 || rt.z() <= 0 || u.z() <= 0 || d.z() <= 0) continue;
      const double jump = 0.1 * p.z();
      if (std::abs(rt.z() - l.z()) > 2 * jump || std::abs(d.z() - u.z()) > 2 * jump) continue;
      Vec3 n = (rt - l).cross(d - u);
      if (n.norm() <= 0) continue;
      n.normalize();
      normals.at<cv::Vec3f>(r, c) = cv::Vec3f(n.x(), n.y(), n.z());
    }
  const double plane_tol = options_.geometry.freespace_grow_plane_m;
  const double min_cos = std::cos(options_.geometry.freespace_grow_angle_deg * M_PI / 180.0);
  cv::Mat reached = free.violated.clone();
  std::vector<std::pair<int, int>> queue;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c)
      if (reached.at<std::uint8_t>(r, c)) queue.emplace_back(r, c);
  for (std::size_t k = 0; k < queue.size(); ++k) {
    const auto [r, c] = queue[k];
    const Vec3 p = point(r, c);
    const cv::Vec3f& na = normals.at<cv::Vec3f>(r, c);
    constexpr int kDr[4] = {1, -1, 0, 0}, kDc[4] = {0, 0, 1, -1};
    for (int d = 0; d < 4; ++d) {
      const int r2 = r + kDr[d], c2 = c + kDc[d];
      if (r2 < 0 || c2 < 0 || r2 >= rows || c2 >= cols || reached.at<std::uint8_t>(r2, c2)) continue;
      if (clusters.labels.at<std::int16_t>(r2, c2) < 0) continue;
      const Vec3 q = point(r2, c2);
      if (q.z() <= 0) continue;
      const cv::Vec3f& nb = normals.at<cv::Vec3f>(r2, c2);
      // Same surface: q lies on p's tangent plane and the normals agree.
      // Without normals (a depth edge next to either) the surface is not
      // followed: that is where a walker's foot meets the floor.
      if (na == cv::Vec3f() || nb == cv::Vec3f()) continue;
      const double off = std::abs(na[0] * (q.x() - p.x()) + na[1] * (q.y() - p.y()) + na[2] * (q.z() - p.z()));
      if (off > plane_tol * (1 + p.z() * p.z()) || std::abs(na.dot(nb)) < min_cos) continue;
      reached.at<std::uint8_t>(r2, c2) = 1;
      queue.emplace_back(r2, c2);
    }
  }
  return reached;
}

Tracker::EvidenceError Tracker::evidenceError(int i, const Vec3& p_w) const {
  // Image error plus a depth term: by default the virtual-stereo coordinate
  // of pose optimisation (a depth error dz counts bf dz / z^2 pixels: 1 px ~
  // 5 cm at 1.5 m), optionally the depth error at the sensor's scale, which
  // sees motion along the ray but, on the real excerpt's noisy keypoint
  // depths, flagged more static clusters (README).
  EvidenceError e;
  e.inv_level_sigma2 = levels_.inv_sigma2[current_.keys[i].octave];
  const Vec3 p = current_.T_c_w * p_w;
  if (p.z() <= 1e-6) {
    e.depth_chi2 = e.level_chi2 = 1e6;
    e.residual = Vec3(1e3, 0, 0);
    return e;
  }
  const double u = camera_.fx * p.x() / p.z() + camera_.cx, v = camera_.fy * p.y() / p.z() + camera_.cy;
  const double du = u - current_.un[i].x, dv = v - current_.un[i].y;
  const double inv_sigma = std::sqrt(e.inv_level_sigma2);
  e.residual = Vec3(du * inv_sigma, dv * inv_sigma, 0);
  e.pixel2 = du * du + dv * dv;
  e.dof = 2;
  e.level_chi2 = e.pixel2 * e.inv_level_sigma2;
  const double z = current_.depth[i];
  // Beyond geometry.evidence_depth_max_m the sensor's depth is not evidence:
  // far depth on real sensors is off by decimetres to a metre between frames
  // (options.hpp, README).
  const double far = options_.geometry.evidence_depth_max_m;
  if (far > 0 && (z >= far || p.z() >= far)) return e;
  if (z > 0 && options_.geometry.depth_sigma_at_1m > 0) {
    const double sigma = options_.geometry.depth_sigma_at_1m * z * z;
    e.depth_chi2 = (p.z() - z) * (p.z() - z) / (sigma * sigma);
    e.residual.z() = (p.z() - z) / sigma;
    e.level_chi2 += e.depth_chi2;
  } else if (current_.u_right[i] >= 0) {
    const double ur = u - camera_.bf() / p.z() - current_.u_right[i];
    e.pixel2 += ur * ur;
    e.residual.z() = ur * inv_sigma;
    e.dof = 3;
    e.level_chi2 += ur * ur * e.inv_level_sigma2;
  }
  return e;
}

bool Tracker::adoptConsensusPose(const std::vector<char>& has_anchor, const std::vector<Vec3>& anchor_point,
                                 const std::vector<char>& inherited) {
  // Features matched to ones found moving before do not vote for the static
  // world: where a known mover holds most of the anchor matches (a poster
  // filling the view), the consensus would be its motion.
  const double far = options_.geometry.evidence_depth_max_m;
  ConsensusProblem problem;
  problem.pose.camera = &camera_;
  problem.cap = options_.geometry.verdict.rho_cap;
  problem.samples = options_.geometry.consensus_samples;
  problem.seed = static_cast<std::uint32_t>(current_.id);
  for (int i = 0; i < current_.size(); ++i) {
    if (!has_anchor[i] || current_.cluster[i] < 0 || inherited[i]) continue;
    Observation o = observationOf(current_, i);
    const double z = current_.depth[i];
    // As in evidenceError: depth beyond evidence_depth_max_m is no evidence,
    // nor a point to sample.
    const bool measured = z > 0 && (far <= 0 || z < far);
    if (!measured) o.u_right = -1;
    problem.pose.points_w.push_back(anchor_point[i]);
    problem.pose.observations.push_back(o);
    problem.seen.push_back(measured ? camera_.unproject(Vec2(current_.un[i].x, current_.un[i].y), z) : Vec3::Zero());
    problem.sampleable.push_back(measured);
    problem.group.push_back(current_.cluster[i]);
  }
  if (problem.pose.points_w.size() < 12) return false;
  // A consensus corrects a compromise that most of the view still passes.
  // When most of it already fails the initial pose, the pose is what is
  // wrong (stage 1 had too few map points): the fallback to the stage-1
  // matches decides, as without the consensus.
  const double voters = static_cast<double>(problem.pose.points_w.size());
  problem.min_initial_inliers =
      static_cast<int>(std::ceil((1 - options_.geometry.max_dynamic_fraction) * voters));
  const ConsensusResult consensus = consensusPose(problem, current_.T_c_w);
  if (!(consensus.cost < options_.geometry.consensus_ratio * consensus.initial_cost)) return false;
  current_.T_c_w = consensus.T_c_w;
  return true;
}

std::vector<std::pair<int, int>> Tracker::matchAnchor() const {
  // No search window (a mover's match is its whole displacement), mutual.
  return matchByDescriptor(current_, anchors_.front(), 0.7f, false, true);
}

std::shared_ptr<const geometry::DepthClusters> Tracker::currentClusters() {
  if (clusters_fetched_ || !clusters_pending_) return clusters_;
  clusters_fetched_ = true;
  const auto deadline = std::chrono::microseconds(static_cast<std::int64_t>(options_.geometry.deadline_ms * 1000));
  clusters_ = clustering_->result(current_.id, deadline);
  if (!clusters_) geometry_.deadline_missed = true;
  return clusters_;
}

void Tracker::holdKnownMoversOutOfPose() {
  // A mover flagged in the last frame reaches this one as carried matches,
  // which never enter the pose; but its features that were not flagged then
  // (a cluster only partly on it, a feature without depth) match ordinary
  // points and pull the pose along with it: on the overlays a poster filling
  // 30-40 % of the view drags the pose until the static scene is flagged
  // instead. Clusters mostly matched to last frame's dynamic features are
  // kept out of the initial pose; they are judged as usual.
  const auto clusters = currentClusters();
  if (!clusters || clusters->clusters == 0) return;
  std::vector<int> label(current_.size(), -1), carried(clusters->clusters, 0), matched(clusters->clusters, 0);
  for (int i = 0; i < current_.size(); ++i) {
    const cv::Point2f& px = current_.keys[i].pt;
    label[i] = clusters->labelAt(camera_, px.x, px.y, current_.depth[i]);
    if (label[i] < 0) continue;
    if (i < static_cast<int>(carried_.size()) && carried_[i]) ++carried[label[i]];
    else if (current_.points[i]) ++matched[label[i]];
  }
  held_.assign(current_.size(), nullptr);
  const int min_features = options_.geometry.verdict.min_features;
  for (int i = 0; i < current_.size(); ++i) {
    const int c = label[i];
    if (c < 0 || !current_.points[i] || carried[c] < min_features || carried[c] < matched[c]) continue;
    held_[i] = std::move(current_.points[i]);
  }
}

void Tracker::rememberAnchor() {
  if (!clustering_) return;
  const GeometryOptions& g = options_.geometry;
  const auto seen = static_cast<std::size_t>(std::max(g.freespace_frames, g.photo_release_ncc > 0 ? g.photo_frames_back : 0));
  seen_depth_.push_back({clusters_ ? clusters_->depth : cv::Mat(), current_.gray, current_.T_c_w});
  while (seen_depth_.size() > seen) seen_depth_.pop_front();
  const auto keep = static_cast<std::size_t>(options_.geometry.anchor_frames);
  if (keep == 0) return;
  Frame a;
  a.id = current_.id;
  a.stamp = current_.stamp;
  a.camera = current_.camera;
  a.levels = current_.levels;
  a.keys = current_.keys;
  a.un = current_.un;
  a.depth = current_.depth;
  a.descriptors = current_.descriptors;  // shared, never written after extraction
  a.dynamic = current_.dynamic;
  for (std::size_t i = 0; i < photo_released_.size(); ++i)
    if (photo_released_[i]) a.dynamic[i] = 1;  // memory only: anchors are evidence, never in a pose
  a.T_c_w = current_.T_c_w;
  anchors_.push_back(std::move(a));
  while (anchors_.size() > keep) anchors_.pop_front();
}

SE3 Tracker::predictedPose(const SE3& last) const {
  // Constant velocity per frame, but a frame that comes after a gap (a frame
  // skipped for bad input, dropped by the camera) is predicted further.
  // Intervals within a factor 1.5 count as one frame: TUM's colour stamps
  // alternate between 32 and 36 ms around a steady 30 Hz, and scaling the
  // velocity by that jitter made the prediction worse (6-run sweeps on
  // tum_fr3_teddy_200: 0.0092 m against 0.0083 m).
  const double dt = secondsBetween(current_.stamp, last_.stamp);
  const double ratio = velocity_dt_ > 0 && dt > 0 ? dt / velocity_dt_ : 1.0;
  if (ratio < 1.5 && ratio > 1.0 / 1.5) return renormalized(velocity_ * last);
  const double s = std::clamp(ratio, 0.25, 4.0);
  SE3 v = SE3::Identity();
  v.linear() = expSO3(s * logSO3(velocity_.linear()));
  v.translation() = s * velocity_.translation();
  return renormalized(v * last);
}

int Tracker::setAsideCarried() {
  int carried = 0;
  carried_.assign(current_.size(), nullptr);
  for (int i = 0; i < current_.size(); ++i) {
    if (!current_.points[i] || !current_.points[i]->moving) continue;
    carried_[i] = std::move(current_.points[i]);
    current_.points[i] = nullptr;
    ++carried;
  }
  return carried;
}

bool Tracker::trackWithMotionModel(bool with_prior) {
  current_.T_c_w = predictedPose(last_.T_c_w);
  current_.clearMatches();
  const auto max_ratio = static_cast<float>(options_.geometry.projection_ratio);
  match_ratio_.assign(current_.size(), 0.0f);
  int matches = searchByProjection(&current_, last_, 7.0f, &match_ratio_, max_ratio);
  matches -= setAsideCarried();
  if (matches < 20) {
    current_.clearMatches();
    match_ratio_.assign(current_.size(), 0.0f);
    matches = searchByProjection(&current_, last_, 14.0f, &match_ratio_, max_ratio);
    matches -= setAsideCarried();
  }
  if (matches < 20) {
    SP_DEBUG(logger, "frame " << current_.id << ": motion model found " << matches << " matches");
    return false;
  }
  held_.clear();
  if (options_.geometry.exclude_known_movers) holdKnownMoversOutOfPose();
  const SE3 predicted = current_.T_c_w;
  timedOptimizePose(with_prior ? &predicted : nullptr);
  for (std::size_t i = 0; i < held_.size(); ++i)
    if (held_[i]) current_.points[i] = std::move(held_[i]), current_.outlier[i] = 1;
  const int kept = countMapInliers();
  SP_DEBUG(logger, "frame " << current_.id << ": motion model " << matches << " matches, " << kept << " map inliers");
  return kept >= 10;
}

bool Tracker::trackReferenceKeyFrame() {
  if (!reference_ || reference_->bad) return false;
  current_.clearMatches();
  match_ratio_.assign(current_.size(), 0.0f);  // ratio-tested matches
  const int matches = searchByDescriptor(&current_, *reference_, 0.7f);
  SP_DEBUG(logger, "frame " << current_.id << ": reference keyframe " << reference_->id << " gave " << matches
                            << " matches");
  if (matches < 15) return false;
  current_.T_c_w = last_.T_c_w;
  timedOptimizePose();
  return countMapInliers() >= 10;
}

bool Tracker::relocalise() {
  // Most recent keyframes first: after a short loss the camera is usually
  // still near where it was. Then as many of the older ones, a window that
  // moves on with every lost frame: a camera back at a place mapped long ago
  // (a robot's next lap, a kidnapped camera) finds the map there within a few
  // frames, at a bounded cost per frame, instead of staying lost until it
  // reaches recently mapped ground.
  const auto n = static_cast<std::size_t>(options_.tracking.relocalisation_candidates);
  std::vector<KeyFrame*> candidates, older;  // newest first
  for (auto it = map_->keyframes().rbegin(); it != map_->keyframes().rend(); ++it) {
    if ((*it)->bad) continue;
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
  const cv::Mat K = (cv::Mat_<double>(3, 3) << camera_.fx, 0, camera_.cx, 0, camera_.fy, camera_.cy, 0, 0, 1);
  for (KeyFrame* kf : candidates) {
    current_.clearMatches();
    if (searchByDescriptor(&current_, *kf, 0.75f) < 15) continue;
    std::vector<cv::Point3f> object;
    std::vector<cv::Point2f> image;
    for (int i = 0; i < current_.size(); ++i) {
      if (!current_.points[i]) continue;
      const Vec3& p = current_.points[i]->position;
      object.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
      image.push_back(current_.un[i]);
    }
    cv::Mat rvec, tvec;
    std::vector<int> inliers;
    if (!cv::solvePnPRansac(object, image, K, cv::noArray(), rvec, tvec, false, 300, 4.0f, 0.99, inliers,
                            cv::SOLVEPNP_EPNP) ||
        inliers.size() < 12)
      continue;
    cv::Mat R;
    cv::Rodrigues(rvec, R);
    SE3 T = SE3::Identity();
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) T.linear()(r, c) = R.at<double>(r, c);
      T.translation()[r] = tvec.at<double>(r);
    }
    current_.T_c_w = T;
    if (timedOptimizePose() < 10) continue;
    discardOutliers();
    // Widen to the local map around the candidate.
    reference_ = kf;
    if (trackLocalMap(options_.tracking.min_inliers_after_reloc)) {
      last_reloc_frame_id_ = current_.id;
      SP_INFO(logger, "frame " << current_.id << ": relocalised against keyframe " << kf->id << " with "
                               << inliers_ << " inliers");
      return true;
    }
  }
  return false;
}

void Tracker::updateLocalMap() {
  ScopedStageTimer timer(&times_.local_map);
  std::unordered_map<KeyFrame*, int> votes;
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    if (!p || p->bad || p->isTemporary()) continue;
    for (const auto& [kf, idx] : p->observations)
      if (!kf->bad) votes[kf]++;
  }
  local_keyframes_.clear();
  KeyFrame* best = nullptr;
  int best_votes = 0;
  for (const auto& [kf, n] : votes) {
    kf->local_for_frame = current_.id;
    local_keyframes_.push_back(kf);
    if (n > best_votes || (n == best_votes && best && kf->id > best->id)) {
      best = kf;
      best_votes = n;
    }
  }
  std::sort(local_keyframes_.begin(), local_keyframes_.end(),
            [&](KeyFrame* a, KeyFrame* b) { return votes[a] != votes[b] ? votes[a] > votes[b] : a->id > b->id; });
  const std::size_t max_kfs = static_cast<std::size_t>(options_.tracking.local_keyframes_max);
  const std::size_t direct = local_keyframes_.size();
  for (std::size_t k = 0; k < direct && local_keyframes_.size() < max_kfs; ++k) {
    auto add = [&](KeyFrame* n) {
      if (!n || n->bad || n->local_for_frame == current_.id || local_keyframes_.size() >= max_kfs) return;
      n->local_for_frame = current_.id;
      local_keyframes_.push_back(n);
    };
    for (KeyFrame* n : local_keyframes_[k]->bestNeighbours(10)) add(n);
    for (KeyFrame* c : local_keyframes_[k]->children) add(c);
    add(local_keyframes_[k]->parent);
  }
  if (best) reference_ = best;

  local_points_.clear();
  for (KeyFrame* kf : local_keyframes_) {
    for (const auto& p : kf->frame.points) {
      if (!p || p->bad || p->local_for_frame == current_.id) continue;
      p->local_for_frame = current_.id;
      local_points_.push_back(p);
    }
  }
}

bool Tracker::trackLocalMap(int min_inliers) {
  updateLocalMap();
  // Points already matched are seen; don't search them again.
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    if (!p || p->isTemporary()) continue;
    p->visible++;
  }
  std::vector<std::shared_ptr<MapPoint>> candidates;
  candidates.reserve(local_points_.size());
  std::vector<char> already(local_points_.size(), 0);
  std::unordered_map<MapPoint*, int> matched;
  for (int i = 0; i < current_.size(); ++i)
    if (current_.points[i]) matched[current_.points[i].get()] = i;
  for (const auto& p : local_points_)
    if (!matched.count(p.get())) candidates.push_back(p);
  {
    ScopedStageTimer search_timer(&times_.local_map);
    std::vector<char> in_view;
    // Depth-sensor keypoints jitter more between frames than the pose error
    // suggests (depth-edge corners), so the window is wider than for stereo.
    const float radius = current_.id < last_reloc_frame_id_ + 2 ? 5.0f : 3.0f;
    searchLocalPoints(&current_, candidates, radius, &in_view);
    for (std::size_t k = 0; k < candidates.size(); ++k)
      if (in_view[k]) candidates[k]->visible++;
  }

  timedOptimizePose();
  inliers_ = 0;
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    if (!p) continue;
    if (current_.outlier[i]) continue;
    if (p->isTemporary()) continue;
    p->found++;
    if (!p->observations.empty()) ++inliers_;
  }
  return inliers_ >= min_inliers;
}

bool Tracker::needNewKeyFrame(bool mapping_idle) const {
  const KeyframeOptions& o = options_.keyframes;
  if (!reference_) return false;
  const std::size_t keyframes = map_->goodKeyFrameCount();
  if (current_.id < last_reloc_frame_id_ + 30 && keyframes > 30) return false;
  // Every map point of the reference keyframe counts: a point seen by one
  // keyframe is as useful to tracking as one seen by many (requiring several
  // observations starves young maps of keyframes, and then of observations).
  const int ref_matches = reference_->trackedPoints(1);
  // "Close" in ORB-SLAM2's sense is "can be mapped from depth". Keyframes
  // map far points too (keyframes.min_new_points), so every keypoint with
  // depth counts: counting only those nearer than close_depth_ fired this
  // rule where the map was already complete, because far matches take a
  // share of the pose's inliers, and the map grew on every lap of a looped
  // replay (test/looped_replay_test.cpp).
  int close_tracked = 0, close_untracked = 0;
  for (int i = 0; i < current_.size(); ++i) {
    if (current_.depth[i] <= 0) continue;
    const auto& p = current_.points[i];
    if (p && !current_.outlier[i] && !p->isTemporary())
      ++close_tracked;
    else
      ++close_untracked;
  }
  const bool need_close = close_tracked < o.close_tracked_min && close_untracked > o.close_untracked_min;
  const double ratio = keyframes < 2 ? 0.4 : o.tracked_ratio;
  const double since_s = secondsBetween(current_.stamp, last_keyframe_stamp_);
  const bool c1a = since_s >= o.max_interval_s;
  const bool c1b = current_.id >= last_keyframe_frame_id_ + o.min_interval_frames && mapping_idle;
  const bool c1c = inliers_ < 0.25 * ref_matches || need_close;
  const bool c2 = (inliers_ < ratio * ref_matches || need_close) && inliers_ > 15;
  return (c1a || c1b || c1c) && c2;
}

KeyFrame* Tracker::createKeyFrame() {
  releaseCulledKeyFrames();  // the exclusive lock is held anyway
  const std::int64_t id = map_->nextKeyFrameId();
  Frame copy = current_;
  for (int i = 0; i < copy.size(); ++i) {
    const auto& p = copy.points[i];
    if (!p || p->bad || p->isTemporary() || copy.outlier[i]) {
      copy.points[i] = nullptr;
      copy.outlier[i] = 0;
    }
  }
  KeyFrame* kf = map_->addKeyFrame(std::make_unique<KeyFrame>(id, copy));
  for (int i = 0; i < kf->frame.size(); ++i) {
    const auto p = kf->frame.points[i];
    if (!p) continue;
    if (p->observations.count(kf)) {
      // The same point matched twice in one frame keeps only its first match.
      kf->frame.points[i] = nullptr;
      continue;
    }
    kf->addObservation(p, i);
    p->updateFromObservations();
  }
  // New points from depth: all close ones, and at least the nearest N
  // (keyframes.min_new_points, 500). In the virtual-stereo coordinate a depth
  // error dz counts bf dz / z^2 px, and a structured-light sensor's depth
  // noise grows as z^2, so a far point's depth is as good there as a near
  // one's; far structure is what pins the rotation. 100 (ORB-SLAM2's) left
  // the background mostly unmapped: ATE on the real excerpt 0.0082 -> 0.0049 m
  // (README, Results).
  std::vector<std::pair<float, int>> by_depth;
  for (int i = 0; i < kf->frame.size(); ++i)
    if (kf->frame.depth[i] > 0 && !kf->frame.points[i] && !kf->frame.dynamic[i])
      by_depth.emplace_back(kf->frame.depth[i], i);
  std::sort(by_depth.begin(), by_depth.end());
  int created = 0;
  for (const auto& [z, i] : by_depth) {
    if (z > close_depth_ && created >= options_.keyframes.min_new_points) break;
    auto p = map_->createPoint(kf->frame.unprojectToWorld(i), kf);
    if (clustering_) p->probation = options_.geometry.probation_frames;
    kf->addObservation(p, i);
    p->updateFromObservations();
    current_.points[i] = p;
    current_.outlier[i] = 0;
    ++created;
  }
  kf->updateConnections();
  kf->dynamic_suspects = std::move(dynamic_suspects_);
  dynamic_suspects_.clear();
  reference_ = kf;
  last_keyframe_stamp_ = current_.stamp;
  last_keyframe_frame_id_ = current_.id;
  return kf;
}

}  // namespace stillpoint::slam
