#include "map.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <numbers>
#include <unordered_set>
#include <vector>

#include "stillpoint/core/geometry.hpp"
#include "stillpoint/features/descriptor.hpp"

namespace stillpoint::slam {

Eigen::Vector3i placeCell(const Vec3& p) { return (p / kPlaceCell).array().floor().cast<int>().matrix(); }

std::uint64_t cellKey(const Eigen::Vector3i& c) {
  const auto bits = [](int v) { return static_cast<std::uint64_t>(v) & 0x1fffff; };  // 21 bits each
  return (bits(c.x()) << 42) | (bits(c.y()) << 21) | bits(c.z());
}

Eigen::Vector3i cellOfKey(std::uint64_t key) {
  const auto value = [key](int shift) {
    const int v = static_cast<int>((key >> shift) & 0x1fffff);
    return v >= (1 << 20) ? v - (1 << 21) : v;  // two's complement in 21 bits
  };
  return {value(42), value(21), value(0)};
}

bool nearPlace(const std::unordered_set<std::uint64_t>& places, const Vec3& p) {
  const Eigen::Vector3i c = placeCell(p);
  for (int dx = -1; dx <= 1; ++dx)
    for (int dy = -1; dy <= 1; ++dy)
      for (int dz = -1; dz <= 1; ++dz)
        if (places.count(cellKey(c + Eigen::Vector3i(dx, dy, dz)))) return true;
  return false;
}

void StaticSightings::add(std::uint32_t map_id, Timestamp stamp, const std::vector<Vec3>& on_static,
                          const std::vector<Vec3>& in_movable) {
  if (cells_ > kMaxCells) {
    maps_.clear();
    cells_ = 0;
  }
  Cells& cells = maps_[map_id];
  // A sighting counts in the 2 x 2 x 2 cells whose centres surround it: a
  // surface lying on a cell border, seen a millimetre either side of it from
  // two keyframes, is one place.
  const auto count = [&](const std::vector<Vec3>& points, int Cell::*kind) {
    std::unordered_set<std::uint64_t> seen;
    for (const Vec3& p : points) {
      const Eigen::Vector3i base = (p / kPlaceCell - Vec3::Constant(0.5)).array().floor().cast<int>().matrix();
      for (int corner = 0; corner < 8; ++corner) {
        const std::uint64_t k = cellKey(base + Eigen::Vector3i(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1));
        if (!seen.insert(k).second) continue;
        const auto [it, added] = cells.try_emplace(k);
        cells_ += added;
        Cell& c = it->second;
        ++(c.*kind);
        if (kind != &Cell::on_static) continue;
        // Stamps need not increase: a map file may come from a later recording.
        if (c.on_static == 1 || stamp < c.first_static) c.first_static = stamp;
        if (c.on_static == 1 || c.last_static < stamp) c.last_static = stamp;
      }
    }
  };
  count(on_static, &Cell::on_static);
  count(in_movable, &Cell::in_movable);
}

bool StaticSightings::seenStanding(std::uint32_t map_id, const Vec3& p, int min, double min_span_s) const {
  const auto map = maps_.find(map_id);
  if (map == maps_.end()) return false;
  const auto it = map->second.find(cellKey(placeCell(p)));
  if (it == map->second.end()) return false;
  const Cell& c = it->second;
  return c.on_static >= min && c.on_static > c.in_movable &&
         secondsBetween(c.last_static, c.first_static) >= min_span_s;
}

void StaticSightings::moveMap(std::uint32_t from, std::uint32_t to, const SE3& T_to_from) {
  auto node = maps_.extract(from);
  if (node.empty() || from == to) {
    if (!node.empty()) maps_.insert(std::move(node));
    return;
  }
  cells_ -= node.mapped().size();
  Cells& into = maps_[to];
  for (const auto& [k, cell] : node.mapped()) {
    const Vec3 centre = (cellOfKey(k).cast<double>() + Vec3::Constant(0.5)) * kPlaceCell;
    const auto [it, added] = into.try_emplace(cellKey(placeCell(T_to_from * centre)));
    cells_ += added;
    Cell& c = it->second;
    const bool had_static = c.on_static > 0;
    c.on_static += cell.on_static;
    c.in_movable += cell.in_movable;
    if (cell.on_static == 0) continue;
    if (!had_static || cell.first_static < c.first_static) c.first_static = cell.first_static;
    if (!had_static || c.last_static < cell.last_static) c.last_static = cell.last_static;
  }
}

void StaticSightings::restore(std::uint32_t map_id, const Eigen::Vector3i& cell, const Cell& c) {
  const auto [it, added] = maps_[map_id].insert_or_assign(cellKey(cell), c);
  cells_ += added;
}

bool KeyFrameIdLess::operator()(const KeyFrame* a, const KeyFrame* b) const { return a->id < b->id; }

std::shared_ptr<MapPoint> MapPoint::temporary(const Frame& frame, int i, bool mover_evidence) {
  auto p = std::make_shared<MapPoint>(-1, frame.unprojectToWorld(i), nullptr);
  std::copy(frame.descriptor(i), frame.descriptor(i) + 32, p->descriptor.begin());
  p->mover_evidence_ = mover_evidence;
  return p;
}

int MapPoint::predictLevel(double distance, const LevelInfo& levels) const {
  if (distance <= 0 || max_distance <= 0) return 0;
  const int level = static_cast<int>(std::ceil(std::log(max_distance / distance) / levels.log_scale_factor));
  return std::clamp(level, 0, levels.levels - 1);
}

void MapPoint::updateFromObservations() {
  if (observations.empty()) return;
  std::vector<const std::uint8_t*> descs;
  Vec3 normal_sum = Vec3::Zero();
  for (const auto& [kf, idx] : observations) {
    descs.push_back(kf->frame.descriptor(idx));
    normal_sum += (position - kf->frame.cameraCentre()).normalized();
  }
  const int best = features::medianDescriptorIndex(descs.data(), static_cast<int>(descs.size()));
  std::copy(descs[best], descs[best] + 32, descriptor.begin());
  normal = normal_sum.normalized();
  // Scale range from the reference keyframe's observation.
  const auto it = reference ? observations.find(reference) : observations.end();
  const auto& [kf, idx] = it != observations.end() ? *it : *observations.begin();
  const double dist = (position - kf->frame.cameraCentre()).norm();
  const int level = kf->frame.keys[idx].octave;
  const LevelInfo& lv = *kf->frame.levels;
  max_distance = dist * lv.scales[level];
  min_distance = max_distance / lv.scales[lv.levels - 1];
}

SE3 PoseAnchor::T_c_w() const {
  // Same composition as before anchors existed: T_self_parent products, then
  // the first keyframe still in the map (or the world).
  SE3 T = SE3::Identity();
  const PoseAnchor* a = this;
  while (!a->keyframe_ && a->parent_) {
    T = T * a->T_self_parent_;
    a = a->parent_.get();
  }
  return renormalized(T * (a->keyframe_ ? a->keyframe_->T_c_w() : a->T_self_parent_));
}

KeyFrame::KeyFrame(std::int64_t id, const Frame& f)
    : id(id), frame(f), anchor_(std::make_shared<PoseAnchor>(this)) {
  frame.gray.release();
}

void KeyFrame::addObservation(const std::shared_ptr<MapPoint>& point, int index) {
  frame.points[index] = point;
  point->observations[this] = index;
}

void KeyFrame::eraseObservation(int index) {
  if (auto& p = frame.points[index]) {
    p->observations.erase(this);
    // A reference that no longer observes the point was never looked up
    // (updateFromObservations falls back to the first observer); null it so
    // that it cannot outlive this keyframe.
    if (p->reference == this) p->reference = nullptr;
    p = nullptr;
  }
}

int KeyFrame::trackedPoints(int min_observations) const {
  int n = 0;
  for (const auto& p : frame.points)
    if (p && !p->bad && static_cast<int>(p->observations.size()) >= min_observations) ++n;
  return n;
}

void KeyFrame::updateConnections() {
  if (bad) return;  // culled: linked to nothing (Map::setKeyFrameBad)
  KeyFrameIndexMap counts;
  for (const auto& p : frame.points) {
    if (!p || p->bad) continue;
    for (const auto& [kf, idx] : p->observations)
      if (kf != this && !kf->bad) counts[kf]++;
  }
  // Drop old links on both sides (a neighbour that kept us in its ordered
  // list would hold a dangling pointer once we are culled and freed), then
  // link both ways.
  for (auto& [kf, w] : connections) {
    kf->connections.erase(this);
    std::erase(kf->ordered_neighbours, this);
  }
  connections.clear();
  KeyFrame* best = nullptr;
  int best_weight = 0;
  for (const auto& [kf, w] : counts) {
    if (w > best_weight || (w == best_weight && best && kf->id < best->id)) {
      best = kf;
      best_weight = w;
    }
    if (w >= kMinWeight) connections[kf] = w;
  }
  if (connections.empty() && best) connections[best] = best_weight;  // stay connected
  ordered_neighbours.clear();
  for (auto& [kf, w] : connections) {
    kf->connections[this] = w;
    ordered_neighbours.push_back(kf);
    std::vector<KeyFrame*>& on = kf->ordered_neighbours;
    on.clear();
    for (auto& [k2, w2] : kf->connections) on.push_back(k2);
    std::sort(on.begin(), on.end(), [kf](KeyFrame* a, KeyFrame* b) {
      const int wa = kf->connections.at(a), wb = kf->connections.at(b);
      return wa != wb ? wa > wb : a->id < b->id;
    });
  }
  std::sort(ordered_neighbours.begin(), ordered_neighbours.end(), [this](KeyFrame* a, KeyFrame* b) {
    const int wa = connections.at(a), wb = connections.at(b);
    return wa != wb ? wa > wb : a->id < b->id;
  });
  if (!parent && best && !origin && best->id < id) {
    parent = best;
    best->children.push_back(this);
  }
}

std::vector<KeyFrame*> KeyFrame::bestNeighbours(int n) const {
  std::vector<KeyFrame*> out;
  for (KeyFrame* kf : ordered_neighbours) {
    if (static_cast<int>(out.size()) >= n) break;
    if (!kf->bad) out.push_back(kf);
  }
  return out;
}

bool Map::fromLoadedMap(const KeyFrame& kf) const { return kf.id < loaded_keyframes_end_; }

void Map::adoptLoaded(Map&& loaded) {
  keyframes_ = std::move(loaded.keyframes_);
  points_ = std::move(loaded.points_);
  next_point_id_ = loaded.next_point_id_;
  loaded_points_end_ = next_point_id_;
  next_keyframe_id_ = loaded.next_keyframe_id_;
  loaded_keyframes_end_ = loaded_points_end_ > 0 ? next_keyframe_id_ : 0;
  next_frame_id_ = loaded.next_frame_id_;
  active_map_id_ = loaded.active_map_id_;
  maps_started_ = loaded.maps_started_;
  static_sightings_ = std::move(loaded.static_sightings_);
  keyframes_by_word_.clear();
  for (const auto& kf : keyframes_)
    if (!kf->bad) indexKeyFrame(kf.get());
  ++epoch_;
}

void Map::replacePoint(const std::shared_ptr<MapPoint>& old, const std::shared_ptr<MapPoint>& by) {
  if (!old || !by || old == by || old->bad || by->bad) return;
  const auto observations = old->observations;
  for (const auto& [kf, idx] : observations) {
    if (kf->frame.points[idx] != old) continue;
    if (by->observations.count(kf)) {
      kf->frame.points[idx] = nullptr;
    } else {
      kf->frame.points[idx] = by;
      by->observations[kf] = idx;
    }
  }
  by->visible += old->visible;
  by->found += old->found;
  old->observations.clear();
  old->bad = true;
  old->replaced_by = by;
  old->reference = nullptr;
  by->updateFromObservations();
}

void Map::indexKeyFrame(KeyFrame* kf) {
  unindexKeyFrame(kf);
  for (const auto& [word, weight] : kf->bow.entries) keyframes_by_word_[word].push_back(kf);
}

void Map::unindexKeyFrame(KeyFrame* kf) {
  for (const auto& [word, weight] : kf->bow.entries) {
    auto it = keyframes_by_word_.find(word);
    if (it == keyframes_by_word_.end()) continue;
    std::erase(it->second, kf);
    if (it->second.empty()) keyframes_by_word_.erase(it);
  }
}

std::vector<Map::PlaceMatch> Map::similarKeyFrames(const features::BowVector& bow,
                                                   const std::function<bool(const KeyFrame*)>& accept,
                                                   double min_score, std::size_t max) const {
  // Words in common first (cheap, from the index), the score only for the
  // keyframes that share at least 80 % as many as the best of them.
  std::unordered_map<KeyFrame*, int> shared;
  for (const auto& [word, weight] : bow.entries) {
    const auto it = keyframes_by_word_.find(word);
    if (it == keyframes_by_word_.end()) continue;
    for (KeyFrame* kf : it->second) ++shared[kf];
  }
  int most = 0;
  for (auto it = shared.begin(); it != shared.end();) {
    if (it->first->bad || !accept(it->first)) {
      it = shared.erase(it);
      continue;
    }
    most = std::max(most, it->second);
    ++it;
  }
  std::vector<PlaceMatch> out;
  for (const auto& [kf, words] : shared) {
    if (words < 0.8 * most) continue;
    const double score = features::bowScore(bow, kf->bow);
    if (score >= min_score) out.push_back({kf, score});
  }
  std::sort(out.begin(), out.end(), [](const PlaceMatch& a, const PlaceMatch& b) {
    return a.score != b.score ? a.score > b.score : a.keyframe->id < b.keyframe->id;
  });
  if (out.size() > max) out.resize(max);
  return out;
}

std::uint32_t Map::beginMap() {
  // Ids are never reused: after a merge into an older map, or a
  // relocalisation into one, the active map is not the newest.
  active_map_id_ = maps_started_++;
  return active_map_id_;
}

KeyFrame* Map::addKeyFrame(std::unique_ptr<KeyFrame> kf) {
  assert(kf->id >= next_keyframe_id_);
  next_keyframe_id_ = kf->id + 1;
  kf->map_id = active_map_id_;
  keyframes_.push_back(std::move(kf));
  KeyFrame* added = keyframes_.back().get();
  for (const auto& [word, weight] : added->bow.entries) keyframes_by_word_[word].push_back(added);
  return added;
}

KeyFrame* Map::keyFrame(std::int64_t id) const {
  const auto it = std::lower_bound(keyframes_.begin(), keyframes_.end(), id,
                                   [](const auto& kf, std::int64_t v) { return kf->id < v; });
  return it != keyframes_.end() && (*it)->id == id ? it->get() : nullptr;
}

std::size_t Map::releaseCulledKeyFrames() {
  return std::erase_if(keyframes_, [](const auto& kf) { return kf->bad; });
}

std::shared_ptr<MapPoint> Map::createPoint(const Vec3& position, KeyFrame* reference) {
  auto p = std::make_shared<MapPoint>(next_point_id_++, position, reference);
  p->first_keyframe_id = reference ? reference->id : 0;
  if (points_.size() > 4096 && points_.size() % 1024 == 0)
    std::erase_if(points_, [](const auto& w) { return w.expired() || w.lock()->bad; });
  points_.push_back(p);
  return p;
}

void Map::erasePoint(const std::shared_ptr<MapPoint>& point) {
  if (!point || point->bad) return;
  point->bad = true;
  auto observations = point->observations;
  for (auto& [kf, idx] : observations)
    if (kf->frame.points[idx] == point) kf->frame.points[idx] = nullptr;
  point->observations.clear();
  point->reference = nullptr;  // its keyframe may be freed before the point
}


void Map::setKeyFrameBad(KeyFrame* kf) {
  if (kf->origin || kf->bad) return;
  unindexKeyFrame(kf);
  for (auto& [other, w] : kf->connections) {
    other->connections.erase(kf);
    std::erase(other->ordered_neighbours, kf);
  }
  for (int i = 0; i < kf->frame.size(); ++i) {
    auto p = kf->frame.points[i];
    if (!p) continue;
    p->observations.erase(kf);
    if (p->reference == kf) p->reference = p->observations.empty() ? nullptr : p->observations.begin()->first;
    if (p->observations.size() < 2) erasePoint(p);
  }
  // Children move to our parent (or to their best remaining neighbour).
  KeyFrame* new_parent = kf->parent;
  while (new_parent && new_parent->bad) new_parent = new_parent->parent;
  for (KeyFrame* child : kf->children) {
    if (child->bad) continue;
    child->parent = new_parent;
    if (new_parent) new_parent->children.push_back(child);
  }
  // Poses expressed through kf now follow new_parent (or stay put in the world).
  PoseAnchor& anchor = *kf->anchor_;
  anchor.keyframe_ = nullptr;
  if (new_parent) {
    std::erase(new_parent->children, kf);
    anchor.parent_ = new_parent->anchor_;
    anchor.T_self_parent_ = renormalized(kf->T_c_w() * new_parent->T_c_w().inverse());
  } else {
    anchor.T_self_parent_ = kf->T_c_w();
  }
  kf->parent = nullptr;
  kf->children.clear();
  kf->connections.clear();
  kf->ordered_neighbours.clear();
  kf->bad = true;
}

std::size_t Map::goodKeyFrameCount() const {
  return std::count_if(keyframes_.begin(), keyframes_.end(), [](const auto& kf) { return !kf->bad; });
}

std::size_t Map::goodKeyFrameCount(std::uint32_t map_id) const {
  return std::count_if(keyframes_.begin(), keyframes_.end(),
                       [map_id](const auto& kf) { return !kf->bad && kf->map_id == map_id; });
}

std::size_t Map::pointsInMemory() const {
  return std::count_if(points_.begin(), points_.end(), [](const auto& w) { return !w.expired(); });
}

std::uint8_t Map::classId(const std::string& name) {
  std::lock_guard lock(classes_mutex_);
  for (std::size_t k = 0; k < classes_.size(); ++k)
    if (classes_[k] == name) return static_cast<std::uint8_t>(k + 1);
  if (classes_.size() >= 255) return 0;
  classes_.push_back(name);
  return static_cast<std::uint8_t>(classes_.size());
}

std::string Map::className(std::uint8_t id) const {
  std::lock_guard lock(classes_mutex_);
  return id >= 1 && id <= classes_.size() ? classes_[id - 1] : std::string("unknown");
}

std::size_t Map::pointCount() const {
  std::size_t n = 0;
  for (const auto& w : points_)
    if (auto p = w.lock(); p && !p->bad) ++n;
  return n;
}

bool offAlongView(const DepthOffset& offset) {
  constexpr double kMaxOffsetM = 0.05;
  constexpr int kMinSamples = 10;
  return offset.samples >= kMinSamples && std::abs(offset.metres) > kMaxOffsetM &&
         std::abs(offset.metres) > 3 * offset.standard_error;
}

int agreedPlacement(const std::vector<SE3>& poses_c_w, const std::vector<int>& inliers) {
  constexpr double kAgreeM = 0.05, kAgreeRad = 3.0 * std::numbers::pi / 180.0;
  int best = -1;
  for (std::size_t a = 0; a < poses_c_w.size(); ++a) {
    const SE3 w_c = poses_c_w[a].inverse();
    bool agreed = false;
    for (std::size_t b = 0; b < poses_c_w.size() && !agreed; ++b) {
      if (b == a) continue;
      const SE3 d = poses_c_w[b] * w_c;  // b's camera from a's
      agreed = (poses_c_w[b].inverse().translation() - w_c.translation()).norm() < kAgreeM &&
               rotationAngle(d.linear()) < kAgreeRad;
    }
    if (agreed && (best < 0 || inliers[a] > inliers[static_cast<std::size_t>(best)])) best = static_cast<int>(a);
  }
  return best;
}

DepthOffset depthOffset(const Frame& frame) {
  std::vector<double> offsets;
  for (int i = 0; i < frame.size(); ++i) {
    if (!frame.points[i] || frame.outlier[i] || frame.depth[i] <= 0) continue;
    offsets.push_back(frame.depth[i] - (frame.T_c_w * frame.points[i]->position).z());
  }
  DepthOffset result;
  result.samples = static_cast<int>(offsets.size());
  if (offsets.empty()) return result;
  const auto median = [](std::vector<double>* v) {
    std::nth_element(v->begin(), v->begin() + v->size() / 2, v->end());
    return (*v)[v->size() / 2];
  };
  result.metres = median(&offsets);
  for (double& d : offsets) d = std::abs(d - result.metres);
  // 1.4826 MAD estimates a normal spread; the median's standard error is
  // sqrt(pi / 2) times the mean's.
  const double spread = 1.4826 * median(&offsets);
  result.standard_error = 1.2533 * spread / std::sqrt(static_cast<double>(result.samples));
  return result;
}

}  // namespace stillpoint::slam
