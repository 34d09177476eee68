#include "dynamic_detector.hpp"

#include "dynamic_judgement.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "matcher.hpp"
#include "optimizer.hpp"
#include "stillpoint/features/descriptor.hpp"
#include "stillpoint/geometry/rules.hpp"

namespace stillpoint::slam {

namespace {

// Squared error of feature i of `frame` against world point p_w under the
// frame's pose, over its level sigma: image error plus the virtual-stereo
// coordinate of pose optimisation (a depth error dz counts bf dz / z^2
// pixels: 1 px ~ 5 cm at 1.5 m). Depth at or beyond far_m (> 0) is no
// evidence: far depth on real sensors is off by decimetres between frames.
struct EvidenceError {
  double chi2 = 0;
  Vec3 residual = Vec3::Zero();  // u, v and depth terms over the level sigma, predicted minus measured
};

EvidenceError evidenceError(const Frame& frame, const CameraModel& camera, const LevelInfo& levels, int i,
                            const Vec3& p_w, double far_m) {
  EvidenceError e;
  const double inv_level_sigma2 = levels.inv_sigma2[frame.keys[i].octave];
  const Vec3 p = frame.T_c_w * p_w;
  if (p.z() <= 1e-6) {
    e.chi2 = 1e6;
    e.residual = Vec3(1e3, 0, 0);
    return e;
  }
  const double u = camera.fx * p.x() / p.z() + camera.cx, v = camera.fy * p.y() / p.z() + camera.cy;
  const double du = u - frame.un[i].x, dv = v - frame.un[i].y;
  const double inv_sigma = std::sqrt(inv_level_sigma2);
  e.residual = Vec3(du * inv_sigma, dv * inv_sigma, 0);
  e.chi2 = (du * du + dv * dv) * inv_level_sigma2;
  const double z = frame.depth[i];
  if (far_m > 0 && (z >= far_m || p.z() >= far_m)) return e;
  if (frame.u_right[i] >= 0) {
    const double ur = u - camera.bf() / p.z() - frame.u_right[i];
    e.residual.z() = ur * inv_sigma;
    e.chi2 += ur * ur * inv_level_sigma2;
  }
  return e;
}

JudgedFeature::Evidence evidenceKind(const FeatureEvidence& e, bool by_anchor) {
  return by_anchor ? JudgedFeature::Evidence::kAnchor
         : e.from_map ? JudgedFeature::Evidence::kMapPoint
                      : JudgedFeature::Evidence::kCarried;
}

}  // namespace

int countMapInliers(const Frame& frame) {
  int n = 0;
  for (int i = 0; i < frame.size(); ++i) {
    const auto& p = frame.points[i];
    n += p && !frame.outlier[i] && !p->isTemporary() && !p->observations.empty();
  }
  return n;
}

DynamicDetector::DynamicDetector(const CameraModel& camera, const LevelInfo& levels, const SlamOptions& options,
                                 geometry::ClusteringWorker* clustering, bool threaded)
    : camera_(camera), levels_(levels), options_(options.geometry), clustering_(clustering) {
  if (threaded) helper_ = std::make_unique<TaskThread>();
}

void DynamicDetector::startFrame(const Frame& frame, bool clusters_pending, bool match_now) {
  frame_id_ = frame.id;
  clusters_pending_ = clusters_pending;
  clusters_fetched_ = false;
  clusters_.reset();
  photo_released_.assign(frame.size(), 0);
  on_known_mover_.assign(frame.size(), 0);
  // Reads only the frame's keypoints and descriptors, which stage 1 leaves
  // alone, and the anchor, which stays until the frame is done.
  if (match_now && clusters_pending_ && !anchors_.empty() && helper_)
    anchor_matches_ = helper_->run([this, &frame] { return matchAnchor(frame); });
}

std::unordered_map<const MapPoint*, int> carryMovingFeatures(Frame* last, const std::vector<char>& freed) {
  std::unordered_map<const MapPoint*, int> from;
  for (int i = 0; i < last->size(); ++i) {
    const bool moving = last->dynamic[i] || (i < static_cast<int>(freed.size()) && freed[i]);
    if (last->depth[i] <= 0 || !moving) continue;
    auto p = MapPoint::temporary(*last, i, true);
    from[p.get()] = i;
    last->points[i] = std::move(p);
    last->outlier[i] = 0;
  }
  return from;
}

void DynamicDetector::carryMovers(Frame* last) {
  carried_moving_.clear();
  for (int i = 0; i < last->size(); ++i)
    if (last->depth[i] > 0 && (last->dynamic[i] == kGeometryDynamic || freedInLastFrame(i))) carried_moving_.insert(i);
  carried_from_ = carryMovingFeatures(last, last_photo_released_);
}

std::shared_ptr<const geometry::DepthClusters> DynamicDetector::fetchClusters(GeometryOutput* out) {
  if (clusters_fetched_ || !clusters_pending_) return clusters_;
  clusters_fetched_ = true;
  const auto deadline = std::chrono::microseconds(static_cast<std::int64_t>(options_.deadline_ms * 1000));
  clusters_ = clustering_->result(frame_id_, deadline);
  if (!clusters_) out->deadline_missed = true;
  return clusters_;
}

std::vector<std::pair<int, int>> DynamicDetector::matchAnchor(const Frame& frame) const {
  // No search window (a mover's match is its whole displacement), mutual.
  return matchByDescriptor(frame, anchors_.front(), 0.7f, false, true);
}

GeometryOutput DynamicDetector::judge(Frame* frame, const StageOneMatches& stage_one, const PoseRefit& refit) {
  FrameJudgement j{*frame, stage_one};
  j.clusters = fetchClusters(&j.out);
  if (!j.clusters) return std::move(j.out);
  j.out.clustering_ms = clustering_->lastClusteringMs();
  j.out.clusters = j.clusters->clusters;
  j.out.labels = j.clusters;
  if (j.clusters->clusters == 0) return std::move(j.out);

  gatherEvidence(j);
  labelFeatures(j);
  // Nearer anchors read only the frame's keypoints and labels: the helper
  // matches while the free-space test runs.
  std::future<std::vector<NearerAnchor>> nearer;
  if (helper_ && options_.near_anchor_frames > 0)
    nearer = helper_->run([this, &j] { return nearerAnchors(j.frame, j.anchored_in_cluster); });
  j.free = freeSpace(*frame, *j.clusters);
  j.out.freespace = j.free.share;
  takeNearerAnchors(j, nearer.valid() ? nearer.get() : nearerAnchors(j.frame, j.anchored_in_cluster));
  j.known_mover = options_.known_mover_min_rest > 0 ? knownMovers(j) : std::vector<char>(j.clusters->clusters, 0);
  // The known mover's features: those seen moving, and its fresh ones (no
  // anchor match). An anchor match not seen moving is a static surface that
  // shares the mover's depth cluster (a teddy in front of a person).
  for (int i = 0; i < frame->size(); ++i) {
    const FeatureEvidence& e = j.ev[i];
    on_known_mover_[i] = frame->cluster[i] >= 0 && j.known_mover[frame->cluster[i]] && (e.seen_moving || !e.has_anchor);
  }

  j.verdict = verdictUnderBestPose(j);
  addFreeSpace(j, &j.verdict);
  dropDynamic(j, refit);
  detectPhotometrically(j, refit);
  releasePhotometrically(j, refit);
  report(j);
  return std::move(j.out);
}

void DynamicDetector::gatherEvidence(FrameJudgement& j) {
  Frame& frame = j.frame;
  const int n = frame.size();
  j.ev.assign(n, {});
  const std::vector<std::shared_ptr<MapPoint>> no_carried;
  const auto& carried = j.stage_one.carried ? *j.stage_one.carried : no_carried;
  // Evidence per feature: its stage-1 match (last frame or local map: the
  // motion since then), else its carried match. Carried evidence (a match
  // to a feature found moving in the last frame) is the oldest position of
  // its chain of such matches, at most geometry.carried_frames back: a mover
  // that slows down or turns keeps the error of several frames of its motion,
  // not of one. Each link is a projection-search match that may have hopped
  // to a look-alike neighbour (floor planks), so a chain of n links is
  // judged at n times the noise of one: its chi2 is divided by n.
  for (int i = 0; i < n; ++i) j.ev[i].point = frame.points[i];
  const auto max_links = static_cast<std::size_t>(options_.carried_frames);
  chain_.assign(n, {});
  for (std::size_t i = 0; i < carried.size(); ++i) {
    if (!carried[i]) continue;
    std::vector<Vec3>& chain = chain_[i];
    chain.push_back(carried[i]->position);
    const auto from = carried_from_.find(carried[i].get());
    if (from != carried_from_.end() && from->second < static_cast<int>(last_chain_.size()))
      for (const Vec3& p : last_chain_[from->second]) {
        if (chain.size() >= max_links) break;
        chain.push_back(p);
      }
    if (from != carried_from_.end() && carried_moving_.count(from->second)) j.ev[i].seen_moving = true;
    if (j.ev[i].point) continue;
    j.ev[i].point = carried[i];
    j.ev[i].links = static_cast<int>(chain.size());
  }
  // Projection matches with a close second in the window are mostly
  // mismatches on repetitive texture: not evidence. Their map points still
  // learn their cluster's verdict (the culling of mapped movers needs them).
  const std::vector<float>* ratio = j.stage_one.match_ratio;
  if (options_.evidence_ratio > 0 && ratio)
    for (int i = 0; i < n; ++i) {
      FeatureEvidence& e = j.ev[i];
      if (!e.point || (*ratio)[i] <= options_.evidence_ratio) continue;
      if (e.point == frame.points[i] && !e.point->isTemporary()) j.ambiguous_points.emplace_back(i, e.point);
      e.point = nullptr;
      e.ambiguous = true;
    }
  // Without anchors, the reference keyframe's match by descriptor alone (no
  // search window: an object that moved since still matches), only where
  // stage 1 has no map point: a map-point match already measures the motion
  // since mapping, and window-free matching has more mismatches.
  const KeyFrame* reference = j.stage_one.reference;
  if (anchors_.empty() && reference && !reference->bad)
    for (const auto& [f, k] : matchByDescriptor(frame, *reference, 0.7f))
      if (!j.ev[f].point || j.ev[f].point->isTemporary()) j.ev[f].point = reference->frame.points[k];
  for (int i = 0; i < n; ++i) {
    FeatureEvidence& e = j.ev[i];
    e.from_map = e.point && e.point == frame.points[i];
    // Carried from the last frame's flagged features, whatever flagged them:
    // a mover followed frame to frame. A semantic mask's mark on the feature
    // itself, or on its anchor match below, is not motion and holds no
    // cluster: masks spill over static objects touching their person (a
    // dilated outline, growth over the same surface), and the hold would
    // take those objects out of the pose with the person while it is still
    // or slow. The mark alone keeps the feature out of the pose and the map.
    e.inherited = i < static_cast<int>(carried.size()) && carried[i] != nullptr && !e.ambiguous;
  }
  // The anchor frame's depth point wins over all of these: its baseline is
  // fixed, so a slow mover's error is not one frame's motion.
  if (anchors_.empty()) return;
  const auto matches = anchor_matches_.valid() ? anchor_matches_.get() : matchAnchor(frame);
  const Frame& anchor = anchors_.front();
  for (const auto& [f, k] : matches) {
    FeatureEvidence& e = j.ev[f];
    e.anchor_baseline = static_cast<int>(anchors_.size());
    e.anchor_point = anchor.unprojectToWorld(k);
    e.has_anchor = true;
    e.anchor_distance = features::hammingDistance(anchor.descriptor(k), frame.descriptor(f));
    e.anchor_descriptor = anchor.descriptor(k);
    e.inherited = e.inherited || anchor.dynamic[k] == kGeometryDynamic;
    e.seen_moving = e.seen_moving || anchor.dynamic[k] == kGeometryDynamic;
  }
}

void DynamicDetector::labelFeatures(FrameJudgement& j) const {
  Frame& frame = j.frame;
  j.anchored_in_cluster.assign(j.clusters->clusters, 0);
  for (int i = 0; i < frame.size(); ++i) {
    const cv::Point2f& px = frame.keys[i].pt;
    frame.cluster[i] = static_cast<std::int16_t>(j.clusters->labelAt(camera_, px.x, px.y, frame.depth[i]));
    if (frame.cluster[i] >= 0 && j.ev[i].has_anchor) ++j.anchored_in_cluster[frame.cluster[i]];
  }
}

std::vector<DynamicDetector::NearerAnchor> DynamicDetector::nearerAnchors(const Frame& frame,
                                                                          std::vector<int> anchored) const {
  // The features of clusters with too few anchor matches are matched to the
  // frames k = N, N - 1, ..., 2 back, while their cluster still has too few.
  // A cluster with enough matches at k is judged by them: a fixed baseline
  // shorter than the anchor's, where its look changed less (a surface turning
  // edge-on), but longer and surer than a map point's or a carried match's.
  const int min_features = options_.verdict.min_features;
  const int n = static_cast<int>(anchored.size());
  std::vector<NearerAnchor> out;
  for (int k = std::min(options_.near_anchor_frames, static_cast<int>(anchors_.size()) - 1); k >= 2; --k) {
    std::vector<int> features;
    for (int i = 0; i < frame.size(); ++i)
      if (frame.cluster[i] >= 0 && anchored[frame.cluster[i]] < min_features) features.push_back(i);
    if (features.empty()) break;
    const auto matches = matchSomeByDescriptor(frame, anchors_[anchors_.size() - k], 0.7f, features);
    std::vector<int> found(n, 0);
    for (const auto& [f, a] : matches) ++found[frame.cluster[f]];
    for (const auto& [f, a] : matches)
      if (found[frame.cluster[f]] >= min_features) out.push_back({f, a, k});
    for (int c = 0; c < n; ++c)
      if (found[c] >= min_features) anchored[c] = min_features;  // judged at this baseline: not tried nearer
  }
  return out;
}

void DynamicDetector::takeNearerAnchors(FrameJudgement& j, const std::vector<NearerAnchor>& nearer) const {
  for (const NearerAnchor& a : nearer) {
    FeatureEvidence& e = j.ev[a.feature];
    if (e.has_anchor) continue;  // keeps its match at the longer baseline
    const Frame& anchor = anchors_[anchors_.size() - a.frames_back];
    e.anchor_baseline = a.frames_back;
    e.anchor_point = anchor.unprojectToWorld(a.keypoint);
    e.has_anchor = true;
    e.anchor_distance = features::hammingDistance(anchor.descriptor(a.keypoint), j.frame.descriptor(a.feature));
    e.anchor_descriptor = anchor.descriptor(a.keypoint);
    e.inherited = e.inherited || anchor.dynamic[a.keypoint] == kGeometryDynamic;
    e.seen_moving = e.seen_moving || anchor.dynamic[a.keypoint] == kGeometryDynamic;
    ++j.anchored_in_cluster[j.frame.cluster[a.feature]];
  }
}

bool DynamicDetector::staticExplains(const FrameJudgement& j, int i, const Vec3& p_w, const std::uint8_t* descriptor,
                                     int distance) const {
  // Motion evidence needs the static hypothesis to be worse. Where the
  // evidence point projects under the pose, a keypoint whose descriptor is
  // within geometry.static_match_margin bits of the matched one's explains the
  // feature as static just as well: the match took another copy of a
  // repeating pattern (floor planks, a stripe), and it is no evidence.
  const int margin = options_.static_match_margin;
  if (margin < 0 || !descriptor) return false;
  const Frame& frame = j.frame;
  const Vec3 p = frame.T_c_w * p_w;
  if (p.z() <= camera_.min_depth) return false;
  const double u = camera_.fx * p.x() / p.z() + camera_.cx, v = camera_.fy * p.y() / p.z() + camera_.cy;
  const int level = frame.keys[i].octave;
  const float radius = 3.0f * static_cast<float>(levels_.scales[level]);
  for (int k : frame.grid.query(frame.keys, frame.un, static_cast<float>(u), static_cast<float>(v), radius,
                                std::max(0, level - 1), std::min(levels_.levels - 1, level + 1)))
    if (k != i && features::hammingDistance(descriptor, frame.descriptor(k)) <= distance + margin) return true;
  return false;
}

geometry::ClusterVerdict DynamicDetector::judgeClusters(FrameJudgement& j, bool anchored) const {
  // A cluster with enough anchor matches is judged by them alone (fixed
  // baseline); the others by whatever evidence their features have.
  const Frame& frame = j.frame;
  const int min_features = options_.verdict.min_features;
  j.explained.clear();
  j.residuals.clear();
  j.judged.clear();
  for (FeatureEvidence& e : j.ev) e.carried_chi2 = 0;
  for (int i = 0; i < frame.size(); ++i) {
    const int c = frame.cluster[i];
    if (c < 0) continue;
    FeatureEvidence& e = j.ev[i];
    const auto& p = e.point;
    const bool by_anchor = anchored && e.has_anchor;
    if (!by_anchor && ((anchored && j.anchored_in_cluster[c] >= min_features) || !p || p->bad)) continue;
    // A carried chain is long-baseline evidence like the anchor's: when the
    // frame falls back to its stage-1 matches (the pose is in doubt), the
    // carried match counts only for its last frame's point.
    const bool chained = !by_anchor && e.links > 1;  // p is the carried point
    const Vec3& point = by_anchor ? e.anchor_point : chained && anchored ? chain_[i].back() : p->position;
    EvidenceError error = evidenceError(frame, camera_, levels_, i, point, options_.evidence_depth_max_m);
    if (chained && anchored) error.chi2 /= e.links;
    e.residual = error.residual;
    const JudgedFeature::Evidence kind = evidenceKind(e, by_anchor);
    // Only disagreeing evidence needs the test (chi2 above the cap).
    if (error.chi2 > options_.verdict.rho_cap) {
      const std::uint8_t* d = by_anchor ? e.anchor_descriptor : p->descriptor.data();
      const int distance = by_anchor ? e.anchor_distance : features::hammingDistance(d, frame.descriptor(i));
      if (staticExplains(j, i, point, d, distance)) {
        j.explained.push_back({i, error.chi2, kind});
        continue;
      }
    }
    j.residuals.push_back({c, error.chi2, e.inherited});
    j.judged.push_back({i, kind});
    if (kind == JudgedFeature::Evidence::kCarried) e.carried_chi2 = error.chi2;
  }
  return geometry::classifyClusters(j.residuals, j.clusters->clusters, options_.verdict);
}

std::vector<char> DynamicDetector::knownMovers(const FrameJudgement& j) const {
  // A cluster is a known mover when most of its anchor-matched features
  // (at least verdict.min_features) were matched to features this module
  // found moving: the mover already found in the frames behind.
  const int n = j.clusters->clusters;
  const std::vector<int>& anchored = j.anchored_in_cluster;
  std::vector<int> moving(n, 0);
  for (int i = 0; i < j.frame.size(); ++i) {
    const int c = j.frame.cluster[i];
    if (c >= 0 && j.ev[i].has_anchor) moving[c] += j.ev[i].seen_moving;
  }
  std::vector<char> known(n, 0);
  for (int c = 0; c < n; ++c)
    known[c] = anchored[c] >= options_.verdict.min_features && moving[c] >= options_.verdict.hold_fraction * anchored[c];
  return known;
}

bool DynamicDetector::poseDisagreesWithView(const FrameJudgement& j, const geometry::ClusterVerdict& verdict) const {
  // The second motion hypothesis. Most of the judged view moving under the
  // pose has two explanations: the pose is wrong (stage 1 had few map
  // points), or a mover that was already found has grown to fill most of the
  // view (a person walking up to the camera). The clusters that mostly follow
  // a known mover tell them apart: the view veto is applied to the rest,
  // when the rest has enough evidence to hold the pose. A wrong pose fails
  // the rest too; a grown mover leaves it passing.
  int judged = 0, dynamic = 0, rest = 0, rest_dynamic = 0;
  for (std::size_t k = 0; k < verdict.clusters.size(); ++k) {
    const geometry::ClusterScore& c = verdict.clusters[k];
    if (!c.judged) continue;
    judged += c.features;
    dynamic += c.dynamic ? c.features : 0;
    if (j.known_mover[k]) continue;
    rest += c.features;
    rest_dynamic += c.dynamic ? c.features : 0;
  }
  const double fraction = options_.max_dynamic_fraction;
  if (options_.known_mover_min_rest > 0 && rest >= options_.known_mover_min_rest)
    return geometry::mostOfViewDynamic(rest_dynamic, rest, fraction);
  return geometry::mostOfViewDynamic(dynamic, judged, fraction);
}

bool DynamicDetector::adoptConsensusPose(FrameJudgement& j) const {
  // Features matched to ones found moving before do not vote for the static
  // world, nor do the other features of a cluster most of whose matches are
  // such (a mover's fresh features): where a known mover holds most of the
  // anchor matches (a poster filling the view), the consensus would be its
  // motion. Nor do the features the semantic module keeps out of the pose
  // (a movable object's mask, a known mover): a person the geometry module
  // no longer sees moving would otherwise vote for its own motion.
  Frame& frame = j.frame;
  const double far = options_.evidence_depth_max_m;
  ConsensusProblem problem;
  problem.pose.camera = &camera_;
  problem.cap = options_.verdict.rho_cap;
  problem.samples = options_.consensus_samples;
  problem.seed = static_cast<std::uint32_t>(frame.id);
  for (int i = 0; i < frame.size(); ++i) {
    const FeatureEvidence& e = j.ev[i];
    if (!e.has_anchor || frame.cluster[i] < 0 || e.inherited || j.known_mover[frame.cluster[i]]) continue;
    if (frame.dynamic[i] == kSemanticDynamic) continue;
    Observation o = observationOf(frame, i);
    const double z = frame.depth[i];
    // As in the evidence error: depth beyond evidence_depth_max_m is no
    // evidence, nor a point to sample.
    const bool measured = z > 0 && (far <= 0 || z < far);
    if (!measured) o.u_right = -1;
    problem.pose.points_w.push_back(e.anchor_point);
    problem.pose.observations.push_back(o);
    problem.seen.push_back(measured ? camera_.unproject(Vec2(frame.un[i].x, frame.un[i].y), z) : Vec3::Zero());
    problem.sampleable.push_back(measured);
    problem.group.push_back(frame.cluster[i]);
  }
  if (problem.pose.points_w.size() < 12) return false;
  // A consensus corrects a compromise that most of the view still passes.
  // When most of it already fails the initial pose, the pose is what is
  // wrong (stage 1 had too few map points): the fallback to the stage-1
  // matches decides, as without the consensus.
  const double voters = static_cast<double>(problem.pose.points_w.size());
  problem.min_initial_inliers = static_cast<int>(std::ceil((1 - options_.max_dynamic_fraction) * voters));
  const ConsensusResult consensus = consensusPose(problem, frame.T_c_w);
  if (!(consensus.cost < options_.consensus_ratio * consensus.initial_cost)) return false;
  frame.T_c_w = consensus.T_c_w;
  return true;
}

geometry::ClusterVerdict DynamicDetector::verdictUnderBestPose(FrameJudgement& j) const {
  // The anchor evidence is measured under the pose that explains it best,
  // when that is clearly better than the initial pose (which a slowly
  // starting mover may have pulled into a compromise that both it and the
  // room pass). Only the verdict: the pose is refitted on the stage-1
  // matches, without the dynamic clusters, from the initial pose.
  j.anchored = !anchors_.empty();
  const SE3 initial_pose = j.frame.T_c_w;
  const bool consensus = j.anchored && options_.consensus_ratio > 0 && adoptConsensusPose(j);
  j.out.consensus_pose = consensus;
  geometry::ClusterVerdict verdict = judgeClusters(j, j.anchored);
  // Anchor matches measure the initial pose independently of stage 1: when
  // most of the view that is not a known mover disagrees with it, the pose is
  // what is wrong (stage 1 had few map points), not the world; the frame is
  // judged by its stage-1 matches instead, which are consistent with the pose
  // they produced.
  if (j.anchored && poseDisagreesWithView(j, verdict)) {
    j.anchored = false;
    j.frame.T_c_w = initial_pose;
    j.out.consensus_pose = false;
    verdict = judgeClusters(j, false);
    j.out.anchor_fallback = true;
  }
  if (consensus) j.frame.T_c_w = initial_pose;
  return verdict;
}

bool DynamicDetector::dropped(const FrameJudgement& j, int i, const geometry::ClusterVerdict& verdict) const {
  // A feature leaves the pose and counts as moving: in a dynamic cluster, not
  // released; or in a cluster too small to judge, still moving along its own
  // track (geometry.lone_moving_chi2).
  const int cluster = j.frame.cluster[i];
  const FeatureEvidence& e = j.ev[i];
  if (cluster < 0 || e.released) return false;
  const geometry::ClusterScore& c = verdict.clusters[cluster];
  const double lone_chi2 = options_.lone_moving_chi2;
  return c.dynamic || (lone_chi2 > 0 && !c.judged && e.inherited && e.carried_chi2 > lone_chi2);
}

void DynamicDetector::dropDynamic(FrameJudgement& j, const PoseRefit& refit) const {
  // Drops the features of dynamic clusters from the pose and refits it.
  Frame& frame = j.frame;
  j.stage_one_points = frame.points;
  splitByMovedSurface(j, j.verdict);
  int removed = 0;
  for (int i = 0; i < frame.size(); ++i) {
    if (!dropped(j, i, j.verdict)) continue;
    frame.points[i] = nullptr;
    frame.outlier[i] = 0;
    ++removed;
  }
  j.refitted = removed > 0 && countMapInliers(frame) >= 10;
  if (j.refitted) refit();
}

void DynamicDetector::report(FrameJudgement& j) {
  // Every feature whose evidence was measured is reported with its outcome,
  // those set aside from the verdict too; map points learn the verdict.
  Frame& frame = j.frame;
  const geometry::ClusterVerdict& verdict = j.verdict;
  GeometryOutput& out = j.out;
  out.ran = true;
  out.scores = verdict.clusters;
  out.threshold = verdict.threshold;
  out.dynamic_clusters = verdict.dynamic_clusters;
  const auto add = [&](int i, double chi2, JudgedFeature::Evidence kind, bool set_aside) {
    if (!options_.report_features) return;
    const FeatureEvidence& e = j.ev[i];
    const bool by_anchor = kind == JudgedFeature::Evidence::kAnchor;
    const int distance =
        by_anchor ? e.anchor_distance : features::hammingDistance(e.point->descriptor.data(), frame.descriptor(i));
    JudgedFeature f{frame.keys[i].pt.x, frame.keys[i].pt.y, dropped(j, i, verdict), frame.cluster[i],
                    static_cast<float>(chi2), kind, e.inherited, frame.depth[i], distance,
                    by_anchor || !j.stage_one.match_ratio ? 0.0f : (*j.stage_one.match_ratio)[i],
                    e.residual.cast<float>(), out.freespace[frame.cluster[i]]};
    f.explained = set_aside;
    f.baseline = by_anchor ? e.anchor_baseline : 0;
    out.judged.push_back(f);
  };
  const float w = static_cast<float>(options_.point_dynamic_weight);
  const auto learn = [&](const std::shared_ptr<MapPoint>& p, bool dynamic) {
    const float score = (1 - w) * p->geometry.dynamic_score.load(std::memory_order_relaxed) + (dynamic ? w : 0.0f);
    p->geometry.dynamic_score.store(score, std::memory_order_relaxed);
    if (dynamic && suspects_.size() < 20000) suspects_.push_back(p);
  };
  for (std::size_t k = 0; k < j.judged.size(); ++k) {
    const int i = j.judged[k].feature;
    add(i, j.residuals[k].chi2, j.judged[k].kind, false);
    const auto& p = j.ev[i].point;
    if (!p || p->bad || p->isTemporary()) continue;
    learn(p, dropped(j, i, verdict));
  }
  if (options_.report_features)
    for (const ExplainedEvidence& x : j.explained) add(x.feature, x.chi2, x.kind, true);
  for (const auto& [i, p] : j.ambiguous_points) {
    const int c = frame.cluster[i];
    if (c < 0 || p->bad) continue;
    learn(p, verdict.clusters[c].dynamic);
  }
  for (int i = 0; i < frame.size(); ++i) {
    if (!dropped(j, i, verdict)) continue;
    frame.dynamic[i] = kGeometryDynamic;
    ++out.dynamic_features;
  }
}

void DynamicDetector::endFrame(const Frame& frame, bool tracked, const Placement& where) {
  if (anchor_matches_.valid()) anchor_matches_.wait();  // not used: stage 1 failed
  anchor_matches_ = {};
  if (tracked)
    rememberFrame(frame, where);
  else
    forgetHistory();
  last_photo_released_ = std::move(photo_released_);
  last_chain_ = std::move(chain_);
  chain_.clear();
}

void DynamicDetector::skipFrame() {
  if (anchor_matches_.valid()) anchor_matches_.wait();
  anchor_matches_ = {};
  chain_.clear();
}

void DynamicDetector::forgetHistory() {
  // The helper may still be reading the anchor it is asked to forget.
  if (anchor_matches_.valid()) anchor_matches_.wait();
  anchor_matches_ = {};
  anchors_.clear();
  anchor_places_.clear();
  seen_.clear();
  // So do the depth clusters: each frame's start from the last one's
  // centres, and after a loss the view has changed as much as the world.
  // Centres carried over from the lost frames gave a person close to the
  // camera one cluster with the teddy bear beside it, and the bear was
  // flagged with the person.
  if (clustering_) clustering_->restart();
}

void DynamicDetector::followWorld(std::uint64_t epoch) {
  auto follow = [epoch](SE3* T_c_w, Placement* where) {
    if (where->epoch == epoch) return true;
    if (!where->reference) return false;
    *T_c_w = renormalized(where->T_c_ref * where->reference->T_c_w());
    where->epoch = epoch;
    return true;
  };
  bool placed = true;
  for (std::size_t k = 0; k < anchors_.size(); ++k) placed = follow(&anchors_[k].T_c_w, &anchor_places_[k]) && placed;
  for (SeenFrame& s : seen_) placed = follow(&s.T_c_w, &s.where) && placed;
  if (!placed) forgetHistory();
}

void DynamicDetector::rememberFrame(const Frame& frame, const Placement& where) {
  const GeometryOptions& g = options_;
  const auto keep_seen =
      static_cast<std::size_t>(std::max(g.freespace_frames, g.photo_release_ncc > 0 ? g.photo_frames_back : 0));
  seen_.push_back({clusters_ ? clusters_->depth : cv::Mat(), frame.gray, frame.T_c_w, where});
  while (seen_.size() > keep_seen) seen_.pop_front();
  const auto keep = static_cast<std::size_t>(g.anchor_frames);
  if (keep == 0) return;
  Frame a;
  a.id = frame.id;
  a.stamp = frame.stamp;
  a.camera = frame.camera;
  a.levels = frame.levels;
  a.keys = frame.keys;
  a.un = frame.un;
  a.depth = frame.depth;
  a.descriptors = frame.descriptors;  // shared, never written after extraction
  a.dynamic = frame.dynamic;
  for (std::size_t i = 0; i < photo_released_.size(); ++i)
    if (photo_released_[i]) a.dynamic[i] = kGeometryDynamic;  // memory only: anchors are evidence, never in a pose
  a.T_c_w = frame.T_c_w;
  anchors_.push_back(std::move(a));
  anchor_places_.push_back(where);
  while (anchors_.size() > keep) {
    anchors_.pop_front();
    anchor_places_.pop_front();
  }
}

std::vector<std::shared_ptr<MapPoint>> DynamicDetector::takeSuspects() {
  std::vector<std::shared_ptr<MapPoint>> out = std::move(suspects_);
  suspects_.clear();
  return out;
}

}  // namespace stillpoint::slam
