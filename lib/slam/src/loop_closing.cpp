#include "loop_closing.hpp"

#include <Eigen/Geometry>

#include <algorithm>
#include <chrono>
#include <random>
#include <unordered_map>
#include <unordered_set>

#include "matcher.hpp"
#include "optimizer.hpp"
#include "stillpoint/core/geometry.hpp"
#include "stillpoint/core/log.hpp"
#include "stillpoint/features/descriptor.hpp"

namespace stillpoint::slam {
namespace {
log::Logger logger("loops");

constexpr int kMinKeyFrames = 10;      // in the map before loops are looked for
constexpr int kKeyFramesBetween = 10;  // after a loop, before the next
// A loop's older side was seen at least this long before: a camera that went
// away and came back. A view seen again within seconds is the local map's
// business (a missing covisibility link is no drift to correct).
constexpr double kMinLoopSeconds = 5.0;
constexpr int kRansacIterations = 300;
constexpr int kCandidateNeighbours = 10;  // best neighbours whose points join a loop side's keyframe's
constexpr int kStrongCovisibility = 100;  // covisibility edges of the essential graph
constexpr int kGlobalBaIterations = 10;
// A larger map's global BA optimises the loop's part of it (GlobalBaOptions).
// The solve's time grows faster than the map (slam_benchmark, 560
// observations a keyframe: 1.3 s for 100 keyframes, 5.8 s for 400, 30 s for
// 1600), and a time limit alone cannot bound it: on 1600 keyframes the first
// step takes longer than place.global_ba_max_s.
constexpr int kGlobalBaMaxKeyFrames = 400;
constexpr std::size_t kVerifiedPerKeyFrame = 3;
constexpr float kFuseRadiusPx = 4.0f;  // the group's search for the older side's points
// A frame crossing into an older place is checked at most this often: the
// check matches its features against a side's points by descriptor alone.
constexpr double kCrossingEverySeconds = 0.5;
// Each crossing the same newest keyframe's side failed to place doubles the
// wait for the next, up to 2^4 times: the camera tracks on a place the map
// holds, and the newest keyframe, made elsewhere, does not see it.
constexpr int kCrossingBackOffSteps = 4;
constexpr float kCrossingRatio = 0.8f;  // best to second-best descriptor distance
constexpr std::size_t kCrossingCandidates = 2;  // the newer side's keyframes tried besides the newest
// A crossing that would move the newer keyframe less than this, when that
// keyframe was in the last global BA, is no seam: the map already holds
// both sides together (the two placements of the frame differ by a few
// millimetres from noise alone), and a global BA would find what the last
// one found.
constexpr double kCrossingNoSeamM = 0.005;
constexpr double kCrossingNoSeamDeg = 0.25;

// The rigid motion (no scale) taking `from` onto `to` (least squares).
SE3 rigidFit(const std::vector<Vec3>& from, const std::vector<Vec3>& to) {
  Eigen::Matrix3Xd a(3, from.size()), b(3, to.size());
  for (std::size_t i = 0; i < from.size(); ++i) a.col(static_cast<Eigen::Index>(i)) = from[i], b.col(static_cast<Eigen::Index>(i)) = to[i];
  SE3 T = SE3::Identity();
  T.matrix() = Eigen::umeyama(a, b, false);
  return T;
}

// The rigid motion taking the `from` side of most pairs onto their `to`
// side, by RANSAC over three-point fits and two refits on the inliers;
// `agrees(T, k)` tells whether pair k agrees with T. The inliers, empty when
// fewer than `min_inliers`.
template <typename Agrees>
std::vector<std::size_t> rigidConsensus(const std::vector<Vec3>& from, const std::vector<Vec3>& to,
                                        std::size_t min_inliers, std::uint32_t seed, Agrees agrees, SE3* T) {
  auto inliersOf = [&](const SE3& T_to_from) {
    std::vector<std::size_t> out;
    for (std::size_t k = 0; k < from.size(); ++k)
      if (agrees(T_to_from, k)) out.push_back(k);
    return out;
  };
  if (from.size() < min_inliers || from.size() < 3) return {};
  std::mt19937 rng(seed);
  std::uniform_int_distribution<std::size_t> pick(0, from.size() - 1);
  std::vector<std::size_t> best;
  for (int it = 0; it < kRansacIterations; ++it) {
    const std::size_t s0 = pick(rng), s1 = pick(rng), s2 = pick(rng);
    if (s0 == s1 || s1 == s2 || s0 == s2) continue;
    // Three points spread out, not on a line: a well-posed motion.
    const Vec3 u = from[s1] - from[s0], v = from[s2] - from[s0];
    if (u.norm() < 0.05 || v.norm() < 0.05 || u.cross(v).norm() < 0.05 * u.norm() * v.norm()) continue;
    std::vector<std::size_t> inliers = inliersOf(rigidFit({from[s0], from[s1], from[s2]}, {to[s0], to[s1], to[s2]}));
    if (inliers.size() > best.size()) best = std::move(inliers);
  }
  if (best.size() < min_inliers) return {};
  // Refit on the inliers (twice: the set may grow).
  for (int round = 0; round < 2; ++round) {
    std::vector<Vec3> a, b;
    for (std::size_t k : best) a.push_back(from[k]), b.push_back(to[k]);
    *T = renormalized(rigidFit(a, b));
    std::vector<std::size_t> refit = inliersOf(*T);
    if (refit.size() < min_inliers) return {};
    best = std::move(refit);
  }
  return best;
}

}  // namespace

LoopCloser::LoopCloser(const SlamOptions& options, const CameraModel& camera, Map* map)
    : options_(options), camera_(camera), map_(map) {}

LoopCloser::~LoopCloser() { finish(); }

LoopStats LoopCloser::stats() const {
  std::lock_guard lock(mutex_);
  return stats_;
}

void LoopCloser::start() {
  worker_ = std::jthread([this](std::stop_token stop) { run(stop); });
}

void LoopCloser::enqueue(std::int64_t keyframe_id) {
  {
    std::lock_guard lock(mutex_);
    if (closed_) return;
    if (queue_.size() >= kQueueCapacity) queue_.pop_front();
    queue_.push_back(keyframe_id);
  }
  cv_.notify_all();
}

void LoopCloser::finish() {
  {
    std::lock_guard lock(mutex_);
    closed_ = true;
  }
  cv_.notify_all();
  if (worker_.joinable()) worker_.join();
}

void LoopCloser::run(std::stop_token stop) {
  for (;;) {
    std::int64_t id = -1;
    std::optional<Crossing> crossing;
    {
      std::unique_lock lock(mutex_);
      cv_.wait(lock, stop, [this] { return !queue_.empty() || crossing_ || closed_; });
      if (!queue_.empty()) {
        id = queue_.front();
        queue_.pop_front();
      } else if (crossing_) {
        crossing.swap(crossing_);
      } else {
        return;  // closed (or stopped) and drained
      }
    }
    if (crossing)
      processCrossing(crossing->frame, crossing->words, crossing->reference, crossing->newest, crossing->epoch);
    else
      process(id);
  }
}

void LoopCloser::process(std::int64_t keyframe_id) {
  Loop loop;
  if (detect(keyframe_id, &loop)) close(loop);
}

bool LoopCloser::close(const Loop& loop) {
  const auto t0 = std::chrono::steady_clock::now();
  if (!correct(loop)) return false;
  const double correct_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  SP_INFO(logger, "keyframe " << loop.keyframe << ": loop with keyframe " << loop.candidate << " closed in "
                              << correct_ms << " ms");
  if (!options_.place.global_ba) return true;
  std::uint32_t map_id = 0;
  std::int64_t next_keyframe = 0;
  {
    std::shared_lock lock(map_->mutex());
    const KeyFrame* kf = map_->keyFrame(loop.keyframe);
    if (!kf) return true;
    map_id = kf->map_id;
    next_keyframe = map_->nextKeyFrameId();
  }
  const auto t1 = std::chrono::steady_clock::now();
  GlobalBaOptions ba;
  ba.iterations = kGlobalBaIterations;
  ba.max_seconds = options_.sequential ? 0.0 : options_.place.global_ba_max_s;
  ba.abort = &abort_;
  ba.max_keyframes = kGlobalBaMaxKeyFrames;
  ba.seeds = {loop.keyframe, loop.candidate};
  // A merge or a crossing's loop during the solve would leave this loop
  // corrected by the essential graph alone: solve again from the moved map.
  ba.retries = 1;
  const LocalBaStats s = globalBundleAdjustment(map_, &camera_, map_id, ba);
  // The write-back moved the world (Map::epoch) unless the world had moved
  // meanwhile (a solve with nothing to move writes nothing back either).
  const bool applied = s.applied;
  if (applied && !s.out_of_time) global_ba_covers_ = next_keyframe;
  std::lock_guard lock(mutex_);
  ++(applied ? stats_.global_ba_runs : stats_.global_ba_dropped);
  if (s.out_of_time) ++stats_.global_ba_out_of_time;
  const double ba_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t1).count();
  SP_INFO(logger, "global BA over " << s.keyframes << " keyframes and " << s.points << " points in " << ba_ms << " ms"
                                    << (s.out_of_time ? " (cut at its time limit)" : "")
                                    << (s.dropped ? " (solved again: the map moved during the first solve)" : "") << "; "
                                    << s.keyframes_held_out << " keyframes left out for too few points; "
                                    << s.keyframes_carried << " keyframes and " << s.points_carried
                                    << " points carried along (those and any made meanwhile)"
                                    << (applied ? "" : " (dropped: the map moved meanwhile)"));
  return true;
}

bool LoopCloser::detect(std::int64_t keyframe_id, Loop* loop) {
  std::shared_lock lock(map_->mutex());
  KeyFrame* kf = map_->keyFrame(keyframe_id);
  if (!kf || kf->bad || kf->bow.empty()) return false;
  const std::int64_t last_loop = last_loop_keyframe_.load();
  if ((last_loop >= 0 && keyframe_id < last_loop + kKeyFramesBetween) ||
      map_->goodKeyFrameCount(kf->map_id) < static_cast<std::size_t>(kMinKeyFrames)) {
    groups_.clear();
    return false;
  }
  // The bar: the least similar of the keyframes it shares points with.
  std::set<std::int64_t> connected{keyframe_id};
  double min_score = 1.0;
  bool any = false;
  for (const KeyFrame* n : kf->ordered_neighbours) {
    if (n->bad) continue;
    connected.insert(n->id);
    if (n->bow.empty()) continue;
    min_score = std::min(min_score, features::bowScore(kf->bow, n->bow));
    any = true;
  }
  if (!any) {
    groups_.clear();
    return false;
  }
  const auto similar = map_->similarKeyFrames(
      kf->bow,
      [&](const KeyFrame* c) {
        return c->map_id == kf->map_id && c->id < keyframe_id && !connected.count(c->id) &&
               secondsBetween(kf->frame.stamp, c->frame.stamp) >= kMinLoopSeconds;
      },
      min_score, 8);
  // Covisibility consistency: a candidate's group (it and its neighbours)
  // continues a group of the previous keyframe's when they share a keyframe.
  std::vector<Group> next;
  std::vector<KeyFrame*> confirmed;
  for (const Map::PlaceMatch& m : similar) {
    Group g;
    g.members.insert(m.keyframe->id);
    for (const KeyFrame* n : m.keyframe->ordered_neighbours)
      if (!n->bad) g.members.insert(n->id);
    for (const Group& old : groups_) {
      const bool shares = std::any_of(g.members.begin(), g.members.end(), [&](std::int64_t id) { return old.members.count(id) > 0; });
      if (shares) g.count = std::max(g.count, old.count + 1);
    }
    if (g.count + 1 >= options_.place.loop_consistency) confirmed.push_back(m.keyframe);
    next.push_back(std::move(g));
  }
  groups_ = std::move(next);
  // The best few: each check costs a descriptor matching of two keyframes.
  if (confirmed.size() > kVerifiedPerKeyFrame) confirmed.resize(kVerifiedPerKeyFrame);
  for (const KeyFrame* c : confirmed) {
    const bool ok = verify(*kf, *c, loop);
    std::lock_guard stats_lock(mutex_);
    ++stats_.detected;
    if (ok) return true;
    ++stats_.rejected;
    SP_DEBUG(logger, "keyframe " << keyframe_id << ": loop candidate " << c->id << " failed the geometric check");
  }
  return false;
}

std::vector<std::shared_ptr<MapPoint>> LoopCloser::groupPoints(const KeyFrame& kf) const {
  std::vector<const KeyFrame*> group{&kf};
  for (const KeyFrame* n : kf.bestNeighbours(kCandidateNeighbours)) group.push_back(n);
  std::vector<std::shared_ptr<MapPoint>> out;
  std::unordered_set<const MapPoint*> seen;
  for (const KeyFrame* k : group)
    for (const auto& p : k->frame.points)
      if (p && !p->bad && !p->isTemporary() && p->geometry.dynamic_score.load() <= 0.5f && seen.insert(p.get()).second)
        out.push_back(p);
  return out;
}

std::vector<std::shared_ptr<MapPoint>> LoopCloser::seenAt(const Frame& a, const SE3& T_a_w,
                                                          const std::vector<std::shared_ptr<MapPoint>>& points,
                                                          float radius) const {
  std::vector<int> best_distance(a.size(), features::kDescriptorBytes * 8 + 1);
  std::vector<std::shared_ptr<MapPoint>> found(a.size());
  for (const auto& p : points) {
    if (p->bad) continue;
    const Vec3 pc = T_a_w * p->position;
    if (pc.z() < camera_.min_depth || pc.z() > camera_.max_depth) continue;
    const Vec2 uv = camera_.project(pc);
    if (uv.x() < 0 || uv.y() < 0 || uv.x() >= camera_.width || uv.y() >= camera_.height) continue;
    for (int i : a.grid.query(a.keys, a.un, static_cast<float>(uv.x()), static_cast<float>(uv.y()), radius, 0, -1)) {
      if (a.dynamic[i]) continue;
      const int d = features::hammingDistance(a.descriptor(i), p->descriptor.data());
      if (d < kMatchThresholdLow && d < best_distance[i]) best_distance[i] = d, found[i] = p;
    }
  }
  return found;
}

bool LoopCloser::verify(const KeyFrame& kf, const KeyFrame& candidate, Loop* loop) const {
  const Frame& a = kf.frame;
  const Frame& b = candidate.frame;
  const auto min_inliers = static_cast<std::size_t>(options_.place.loop_min_inliers);
  // 3D-3D pairs: static features with depth on both sides.
  std::vector<std::pair<int, int>> pairs;
  std::vector<Vec3> in_a, in_b;
  for (const auto& [i, j] : matchByDescriptor(a, b, 0.75f, false, true)) {
    if (a.depth[i] <= 0 || b.depth[j] <= 0 || a.dynamic[i] || b.dynamic[j]) continue;
    pairs.emplace_back(i, j);
    in_a.push_back(camera_.unproject(Vec2(a.un[i].x, a.un[i].y), a.depth[i]));
    in_b.push_back(camera_.unproject(Vec2(b.un[j].x, b.un[j].y), b.depth[j]));
  }
  if (pairs.size() < min_inliers) return false;
  // A pair agrees with T_a_b when each side reprojects into the other's
  // image (with its depth as the virtual right coordinate) under the gate.
  auto agrees = [&](const SE3& T_a_b, std::size_t k) {
    bool behind_a = false, behind_b = false;
    const double ca = reprojectionChi2(camera_, T_a_b, in_b[k], observationOf(a, pairs[k].first), &behind_a);
    const double cb = reprojectionChi2(camera_, T_a_b.inverse(), in_a[k], observationOf(b, pairs[k].second), &behind_b);
    return !behind_a && !behind_b && ca < kChi2Stereo && cb < kChi2Stereo;
  };
  SE3 T_a_b = SE3::Identity();
  const std::vector<std::size_t> best = rigidConsensus(in_b, in_a, min_inliers,
                                                       static_cast<std::uint32_t>(kf.id * 7919 + candidate.id), agrees, &T_a_b);
  if (best.empty()) return false;
  // The older place's map points, projected into the keyframe where the
  // loop puts it, must be found there by descriptor: a wrong loop that a
  // repetitive texture let through finds few. The keyframe's pose is then
  // refitted on them by reprojection (the 3D-3D fit carries the depth
  // noise of both sides), and searched and refitted once more.
  SE3 T_a_w = T_a_b * b.T_c_w;
  std::vector<std::shared_ptr<MapPoint>> found;
  if (placeOn(a, groupPoints(candidate), &T_a_w, &found) == 0) return false;
  loop->fused.clear();
  for (int i = 0; i < a.size(); ++i)
    if (found[i]) loop->fused.emplace_back(i, found[i]);
  T_a_b = renormalized(T_a_w * b.T_c_w.inverse());
  loop->keyframe = kf.id;
  loop->candidate = candidate.id;
  loop->T_kf_candidate = T_a_b;
  SP_DEBUG(logger, "keyframe " << kf.id << ": loop with " << candidate.id << ", " << best.size() << " 3D-3D inliers of "
                               << pairs.size() << ", " << loop->fused.size() << " map points found");
  return true;
}

int LoopCloser::placeOn(const Frame& a, const std::vector<std::shared_ptr<MapPoint>>& points, SE3* T_a_w,
                        std::vector<std::shared_ptr<MapPoint>>* found_out) const {
  const auto min_inliers = static_cast<std::size_t>(options_.place.loop_min_inliers);
  std::vector<std::shared_ptr<MapPoint>> found;
  int inliers = 0;
  for (const float radius : {8.0f, 4.0f}) {
    found = seenAt(a, *T_a_w, points, radius);
    PoseProblem problem;
    problem.camera = &camera_;
    std::vector<int> features;
    for (int i = 0; i < a.size(); ++i) {
      if (!found[i]) continue;
      problem.points_w.push_back(found[i]->position);
      problem.observations.push_back(observationOf(a, i));
      features.push_back(i);
    }
    if (problem.points_w.size() < min_inliers) return 0;
    const PoseResult r = optimizePose(problem, *T_a_w);
    for (std::size_t k = 0; k < features.size(); ++k)
      if (!r.inlier[k]) found[features[k]] = nullptr;
    *T_a_w = r.T_c_w;
    inliers = r.inliers;
    if (static_cast<std::size_t>(inliers) < min_inliers) return 0;
  }
  if (found_out) *found_out = std::move(found);
  return inliers;
}

std::int64_t LoopCloser::crossingDue(const KeyFrame& reference, Timestamp stamp) {
  if (crossing_checked_ && secondsBetween(stamp, last_crossing_) < kCrossingEverySeconds) return -1;
  const KeyFrame* newest = nullptr;
  const auto& keyframes = map_->keyframes();
  for (auto it = keyframes.rbegin(); it != keyframes.rend() && !newest; ++it)
    if (!(*it)->bad && (*it)->map_id == reference.map_id) newest = it->get();
  if (!newest || newest == &reference || newest->id == last_loop_keyframe_.load() ||
      map_->goodKeyFrameCount(reference.map_id) < static_cast<std::size_t>(kMinKeyFrames) ||
      secondsBetween(newest->frame.stamp, reference.frame.stamp) < kMinLoopSeconds ||
      newest->connections.count(const_cast<KeyFrame*>(&reference)))
    return -1;
  int misses = 0;
  {
    std::lock_guard lock(mutex_);
    if (crossing_misses_keyframe_ == newest->id) misses = crossing_misses_;
  }
  if (crossing_checked_ && secondsBetween(stamp, last_crossing_) <
                               kCrossingEverySeconds * (1 << std::min(misses, kCrossingBackOffSteps)))
    return -1;
  crossing_checked_ = true;
  last_crossing_ = stamp;
  return newest->id;
}

void LoopCloser::enqueueCrossing(Frame frame, features::BowVector words, std::int64_t reference,
                                 std::int64_t newest, std::uint64_t epoch) {
  {
    std::lock_guard lock(mutex_);
    if (closed_) return;
    crossing_ = Crossing{std::move(frame), std::move(words), reference, newest, epoch};
  }
  cv_.notify_all();
}

void LoopCloser::processCrossing(const Frame& frame, const features::BowVector& words, std::int64_t reference,
                                 std::int64_t newest, std::uint64_t epoch) {
  // A loop closed by a crossing links the two places: the frames after it
  // cross again until the map around them has settled.
  if (newest == last_loop_keyframe_.load() ||
      (crossing_closed_ && secondsBetween(frame.stamp, last_crossing_loop_) < kMinLoopSeconds))
    return;
  Loop loop;
  bool placed = false;
  {
    std::shared_lock lock(map_->mutex());
    const KeyFrame* older = map_->keyFrame(reference);
    const KeyFrame* newer = map_->keyFrame(newest);
    // The frame's pose is in the world it was tracked in.
    if (map_->epoch() != epoch || !older || !newer || older->bad || newer->bad || older->map_id != newer->map_id)
      return;
    // The newer side: the newest keyframe, else the keyframes made since
    // the older side that look most like the frame (the newest may face
    // elsewhere when the camera came back through a relocalisation).
    std::vector<const KeyFrame*> newer_candidates{newer};
    if (!words.empty()) {
      std::unordered_set<const KeyFrame*> older_side{older};
      for (const KeyFrame* n : older->bestNeighbours(kCandidateNeighbours)) older_side.insert(n);
      for (const Map::PlaceMatch& m : map_->similarKeyFrames(
               words,
               [&](const KeyFrame* k) {
                 return k != newer && k->map_id == older->map_id && !older_side.count(k) &&
                        secondsBetween(k->frame.stamp, older->frame.stamp) >= kMinLoopSeconds;
               },
               0.0, kCrossingCandidates))
        newer_candidates.push_back(m.keyframe);
    }
    for (const KeyFrame* n : newer_candidates)
      if ((placed = placeCrossing(frame, *older, *n, &loop))) break;
  }
  const bool closed = placed && close(loop);
  std::lock_guard lock(mutex_);
  ++stats_.crossings_checked;
  if (closed) {
    ++stats_.crossings_closed;
    crossing_closed_ = true;
    last_crossing_loop_ = frame.stamp;
    crossing_misses_ = 0;
  } else {
    if (crossing_misses_keyframe_ != newest) crossing_misses_keyframe_ = newest, crossing_misses_ = 0;
    ++crossing_misses_;
  }
}

bool LoopCloser::placeCrossing(const Frame& frame, const KeyFrame& older, const KeyFrame& newer, Loop* loop) const {
  const auto min_inliers = static_cast<std::size_t>(options_.place.loop_min_inliers);
  // The two sides, each keyframe with its best neighbours: one keyframe in
  // both, and they are one place of the map already.
  std::unordered_set<const KeyFrame*> newer_side{&newer};
  for (const KeyFrame* n : newer.bestNeighbours(kCandidateNeighbours)) newer_side.insert(n);
  bool apart = !newer_side.count(&older);
  for (const KeyFrame* n : older.bestNeighbours(kCandidateNeighbours)) apart = apart && !newer_side.count(n);
  if (!apart) {
    SP_DEBUG(logger, "frame " << frame.id << ": keyframes " << older.id << " and " << newer.id << " are one place");
    return false;
  }
  // The older side, where tracking put the frame: refitted on its points alone.
  SE3 T_older = frame.T_c_w;
  const std::vector<std::shared_ptr<MapPoint>> older_points = groupPoints(older);
  const int on_older = placeOn(frame, older_points, &T_older);
  if (on_older == 0) {
    SP_DEBUG(logger, "frame " << frame.id << " in keyframe " << older.id << ": too few of its points found");
    return false;
  }
  // The newer side, wherever its drift puts it: the frame's static features
  // with depth matched by descriptor to the points of the side's keyframes
  // (the first match of each feature), 3D-3D.
  const std::vector<std::shared_ptr<MapPoint>> newer_points = groupPoints(newer);
  std::vector<const KeyFrame*> newer_group{&newer};
  for (const KeyFrame* n : newer.bestNeighbours(kCandidateNeighbours)) newer_group.push_back(n);
  std::vector<int> features;
  std::vector<Vec3> in_w, in_c;
  std::vector<char> taken(frame.size(), 0);
  for (const KeyFrame* k : newer_group)
    for (const auto& [i, j] : matchByDescriptor(frame, *k, kCrossingRatio)) {
      const std::shared_ptr<MapPoint>& p = k->frame.points[j];
      if (taken[i] || !(frame.depth[i] > 0) || !p || p->bad || p->isTemporary() ||
          p->geometry.dynamic_score.load() > 0.5f)
        continue;
      taken[i] = 1;
      features.push_back(i);
      in_w.push_back(p->position);
      in_c.push_back(camera_.unproject(Vec2(frame.un[i].x, frame.un[i].y), frame.depth[i]));
    }
  auto agrees = [&](const SE3& T_c_w, std::size_t k) {
    bool behind = false;
    return reprojectionChi2(camera_, T_c_w, in_w[k], observationOf(frame, features[k]), &behind) < kChi2Stereo &&
           !behind;
  };
  SE3 T_newer = SE3::Identity();
  const std::vector<std::size_t> consensus = rigidConsensus(
      in_w, in_c, min_inliers, static_cast<std::uint32_t>(newer.id * 7919 + older.id), agrees, &T_newer);
  const int on_newer = consensus.empty() ? 0 : placeOn(frame, newer_points, &T_newer);
  if (on_newer == 0) {
    SP_DEBUG(logger, "frame " << frame.id << " crossed from keyframe " << newer.id << " into keyframe " << older.id
                              << ": not placed on the newer side (" << consensus.size() << " of " << in_w.size()
                              << " descriptor pairs agree)");
    return false;
  }
  // The newer keyframe where the older side puts the frame.
  const SE3 T_kf_w = renormalized(newer.T_c_w() * T_newer.inverse() * T_older);
  // Where the map has it already (an earlier loop joined the two sides, and
  // a global BA has seen the newer keyframe since), a correction would only
  // move the map by the noise of the two fits.
  const SE3 seam = T_kf_w * newer.T_c_w().inverse();
  const double seam_m = seam.translation().norm(), seam_deg = rotationAngle(seam.rotation()) * 180 / M_PI;
  if (seam_m < kCrossingNoSeamM && seam_deg < kCrossingNoSeamDeg && newer.id < global_ba_covers_.load()) {
    SP_DEBUG(logger, "frame " << frame.id << " crossed from keyframe " << newer.id << " into keyframe " << older.id
                              << ": the two sides agree (" << seam_m * 1000 << " mm, " << seam_deg
                              << " degrees): no seam");
    return false;
  }
  loop->keyframe = newer.id;
  loop->candidate = older.id;
  loop->T_kf_candidate = renormalized(T_kf_w * older.T_c_w().inverse());
  loop->fused.clear();
  const std::vector<std::shared_ptr<MapPoint>> seen = seenAt(newer.frame, T_kf_w, older_points, kFuseRadiusPx);
  for (int i = 0; i < newer.frame.size(); ++i)
    if (seen[i]) loop->fused.emplace_back(i, seen[i]);
  SP_DEBUG(logger, "frame " << frame.id << " crossed from keyframe " << newer.id << " into keyframe " << older.id
                            << ": " << on_older << " inliers on the older side, " << on_newer << " on the newer ("
                            << consensus.size() << " of " << in_w.size() << " descriptor pairs), "
                            << loop->fused.size() << " of the older points seen by the newer keyframe");
  return true;
}

bool LoopCloser::correct(const Loop& loop) {
  std::unique_lock lock(map_->mutex());
  KeyFrame* kf = map_->keyFrame(loop.keyframe);
  KeyFrame* candidate = map_->keyFrame(loop.candidate);
  if (!kf || kf->bad || !candidate || candidate->bad || kf->map_id != candidate->map_id) return false;
  const std::uint32_t map_id = kf->map_id;
  const SE3 T_kf_w_corrected = renormalized(loop.T_kf_candidate * candidate->T_c_w());
  const double moved_m = (T_kf_w_corrected.inverse().translation() - kf->frame.cameraCentre()).norm();

  // The keyframe's side of the loop and where the loop puts it.
  std::vector<KeyFrame*> ks;
  std::unordered_map<KeyFrame*, std::size_t> index;
  for (const auto& k : map_->keyframes())
    if (!k->bad && k->map_id == map_id) index[k.get()] = ks.size(), ks.push_back(k.get());
  std::vector<SE3> before(ks.size());
  for (std::size_t n = 0; n < ks.size(); ++n) before[n] = ks[n]->T_c_w();
  std::vector<KeyFrame*> group{kf};
  for (KeyFrame* n : kf->ordered_neighbours)
    if (!n->bad && n->map_id == map_id) group.push_back(n);
  std::vector<SE3> initial = before;
  const SE3 T_kf_w = kf->T_c_w();
  for (KeyFrame* g : group) initial[index.at(g)] = renormalized(g->T_c_w() * T_kf_w.inverse() * T_kf_w_corrected);

  // Each point follows one keyframe (its anchor): the group's points the
  // group keyframe that moves them, the others their reference.
  std::unordered_map<MapPoint*, KeyFrame*> anchor;
  for (KeyFrame* g : group)
    for (const auto& p : g->frame.points)
      if (p && !p->bad && !p->isTemporary()) anchor.emplace(p.get(), g);
  std::vector<std::shared_ptr<MapPoint>> points;
  {
    std::unordered_set<MapPoint*> listed;
    for (KeyFrame* k : ks)
      for (const auto& p : k->frame.points) {
        if (!p || p->bad || p->isTemporary() || !listed.insert(p.get()).second) continue;
        points.push_back(p);
        if (anchor.count(p.get())) continue;
        KeyFrame* r = p->reference && index.count(p->reference) ? p->reference : k;
        anchor.emplace(p.get(), r);
      }
  }
  // Move the group first, so the fused points are compared where they belong.
  for (const auto& p : points) {
    KeyFrame* g = anchor.at(p.get());
    const std::size_t n = index.at(g);
    if (std::find(group.begin(), group.end(), g) == group.end()) continue;
    p->position = initial[n].inverse() * (before[n] * p->position);
  }
  std::vector<std::set<KeyFrame*, KeyFrameIdLess>> links_before(group.size());
  for (std::size_t g = 0; g < group.size(); ++g) {
    group[g]->T_c_w() = initial[index.at(group[g])];
    for (const auto& [n, w] : group[g]->connections) links_before[g].insert(n);
  }
  // The essential graph: the spanning tree and strong covisibility as they
  // were before the loop (taken before the fusion below links the two sides:
  // a link across the loop holds the drift the loop corrects), the new links
  // across it as they are now.
  std::vector<PoseGraphEdge> edges;
  auto relative = [](const SE3& T_i_w, const SE3& T_j_w) { return renormalized(T_i_w * T_j_w.inverse()); };
  for (std::size_t n = 0; n < ks.size(); ++n) {
    KeyFrame* k = ks[n];
    if (k->parent && index.count(k->parent)) {
      const std::size_t p = index.at(k->parent);
      edges.push_back({n, p, relative(before[n], before[p])});
    }
    for (const auto& [other, w] : k->connections) {
      if (w < kStrongCovisibility || other->id >= k->id || !index.count(other)) continue;
      const std::size_t o = index.at(other);
      edges.push_back({n, o, relative(before[n], before[o])});
    }
  }
  // Fuse: the keyframe's features take the older side's points, and so do
  // the rest of the group's where the loop puts them. A point this lap mapped
  // again and only a neighbour sees would otherwise stay beside its older
  // copy, both in the local map and never quite together after the pose
  // graph: stage 1 matches either, the pose is pulled both ways, and a
  // static surface looks moving.
  int fused = 0;
  auto fuse = [&](KeyFrame* k, int i, const std::shared_ptr<MapPoint>& older) {
    if (older->bad) return;
    const std::shared_ptr<MapPoint> current = k->frame.points[i];
    if (current == older) return;
    if (current && !current->bad) {
      map_->replacePoint(current, older);
      ++fused;
    } else if (!older->observations.count(k)) {
      k->addObservation(older, i);
      ++fused;
    }
  };
  for (const auto& [i, older] : loop.fused) fuse(kf, i, older);
  const std::vector<std::shared_ptr<MapPoint>> older_points = groupPoints(*candidate);
  for (KeyFrame* g : group) {
    if (g == kf) continue;
    const std::vector<std::shared_ptr<MapPoint>> seen = seenAt(g->frame, g->T_c_w(), older_points, kFuseRadiusPx);
    for (int i = 0; i < g->frame.size(); ++i)
      if (seen[i]) fuse(g, i, seen[i]);
  }
  for (KeyFrame* g : group) g->updateConnections();

  for (std::size_t g = 0; g < group.size(); ++g)
    for (const auto& [other, w] : group[g]->connections) {
      if (links_before[g].count(other) || !index.count(other) ||
          std::find(group.begin(), group.end(), other) != group.end())
        continue;
      edges.push_back({index.at(group[g]), index.at(other), relative(group[g]->T_c_w(), other->T_c_w())});
    }
  edges.push_back({index.at(kf), index.at(candidate), loop.T_kf_candidate});
  std::vector<char> fixed(ks.size(), 0);
  bool any_fixed = false;
  for (std::size_t n = 0; n < ks.size(); ++n) any_fixed |= (fixed[n] = ks[n]->origin) != 0;
  if (!any_fixed) fixed[index.at(candidate)] = 1;
  const auto graph_t0 = std::chrono::steady_clock::now();
  const std::vector<SE3> optimised = optimizePoseGraph(initial, fixed, edges);
  const double graph_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - graph_t0).count();

  for (const auto& p : points) {
    if (p->bad) continue;  // fused away
    const std::size_t n = index.at(anchor.at(p.get()));
    p->position = optimised[n].inverse() * (initial[n] * p->position);
  }
  for (std::size_t n = 0; n < ks.size(); ++n) ks[n]->T_c_w() = optimised[n];
  for (const auto& p : points)
    if (!p->bad) p->updateFromObservations();
  map_->worldMoved();
  last_loop_keyframe_ = kf->id;
  groups_.clear();
  std::lock_guard stats_lock(mutex_);
  ++stats_.closed;
  stats_.last_correction_m = moved_m;
  const Eigen::AngleAxisd rotation(loop.T_kf_candidate.linear());
  SP_INFO(logger, "keyframe " << kf->id << " (t " << kf->frame.stamp.toSecondsString() << ") moved " << moved_m
                              << " m onto keyframe " << candidate->id << " (t " << candidate->frame.stamp.toSecondsString()
                              << "), relative pose t " << loop.T_kf_candidate.translation().transpose() << " r "
                              << (rotation.angle() * rotation.axis()).transpose() << ": "
                              << group.size() << " keyframes corrected, " << fused << " points fused, " << edges.size()
                              << " graph edges over " << ks.size() << " keyframes (solved in " << graph_ms << " ms)");
  return true;
}

}  // namespace stillpoint::slam
