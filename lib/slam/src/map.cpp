#include "map.hpp"

#include <algorithm>
#include <cmath>

#include "stillpoint/features/descriptor.hpp"

namespace stillpoint::slam {

bool KeyFrameIdLess::operator()(const KeyFrame* a, const KeyFrame* b) const { return a->id < b->id; }

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
  const auto it = observations.find(reference);
  const auto& [kf, idx] = it != observations.end() ? *it : *observations.begin();
  const double dist = (position - kf->frame.cameraCentre()).norm();
  const int level = kf->frame.keys[idx].octave;
  const LevelInfo& lv = *kf->frame.levels;
  max_distance = dist * lv.scales[level];
  min_distance = max_distance / lv.scales[lv.levels - 1];
}

KeyFrame::KeyFrame(std::int64_t id, const Frame& f) : id(id), frame(f) {}

void KeyFrame::addObservation(const std::shared_ptr<MapPoint>& point, int index) {
  frame.points[index] = point;
  point->observations[this] = index;
}

void KeyFrame::eraseObservation(int index) {
  if (auto& p = frame.points[index]) {
    p->observations.erase(this);
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
  KeyFrameIndexMap counts;
  for (const auto& p : frame.points) {
    if (!p || p->bad) continue;
    for (const auto& [kf, idx] : p->observations)
      if (kf != this && !kf->bad) counts[kf]++;
  }
  // Drop our side of old links, then link both ways.
  for (auto& [kf, w] : connections) kf->connections.erase(this);
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
  if (!parent && best && id != 0 && best->id < id) {
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

SE3 KeyFrame::resolvedT_c_w() const {
  SE3 T = SE3::Identity();
  const KeyFrame* kf = this;
  while (kf->bad && kf->parent) {
    T = T * kf->T_self_parent;
    kf = kf->parent;
  }
  return renormalized(T * kf->T_c_w());
}

KeyFrame* Map::addKeyFrame(std::unique_ptr<KeyFrame> kf) {
  keyframes_.push_back(std::move(kf));
  return keyframes_.back().get();
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
}

void Map::replacePoint(const std::shared_ptr<MapPoint>& a, const std::shared_ptr<MapPoint>& b) {
  if (a == b || a->bad) return;
  auto observations = a->observations;
  a->observations.clear();
  a->bad = true;
  a->replaced_by = b;
  for (auto& [kf, idx] : observations) {
    if (!b->observations.count(kf)) {
      kf->frame.points[idx] = b;
      b->observations[kf] = idx;
    } else {
      kf->frame.points[idx] = nullptr;
    }
  }
  b->visible += a->visible;
  b->found += a->found;
  b->updateFromObservations();
}

void Map::setKeyFrameBad(KeyFrame* kf) {
  if (kf->id == 0 || kf->bad) return;
  for (auto& [other, w] : kf->connections) {
    other->connections.erase(kf);
    std::erase(other->ordered_neighbours, kf);
  }
  for (int i = 0; i < kf->frame.size(); ++i) {
    auto p = kf->frame.points[i];
    if (!p) continue;
    p->observations.erase(kf);
    if (p->reference == kf && !p->observations.empty()) p->reference = p->observations.begin()->first;
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
  if (new_parent) {
    std::erase(new_parent->children, kf);
    kf->T_self_parent = renormalized(kf->T_c_w() * new_parent->T_c_w().inverse());
  }
  kf->parent = new_parent;
  kf->children.clear();
  kf->connections.clear();
  kf->ordered_neighbours.clear();
  kf->bad = true;
}

std::size_t Map::goodKeyFrameCount() const {
  return std::count_if(keyframes_.begin(), keyframes_.end(), [](const auto& kf) { return !kf->bad; });
}

std::size_t Map::pointCount() const {
  std::size_t n = 0;
  for (const auto& w : points_)
    if (auto p = w.lock(); p && !p->bad) ++n;
  return n;
}

}  // namespace stillpoint::slam
