#include "matcher.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>

#include "stillpoint/features/descriptor.hpp"

namespace stillpoint::slam {
namespace {

using features::hammingDistance;

constexpr int kHistogramBins = 30;

// Indices (into `candidates`) of the three most populated rotation bins.
void keepDominantRotations(const std::vector<float>& rotation_deg, std::vector<char>* keep) {
  std::array<std::vector<int>, kHistogramBins> bins;
  for (std::size_t i = 0; i < rotation_deg.size(); ++i) {
    float rot = rotation_deg[i];
    while (rot < 0) rot += 360.0f;
    while (rot >= 360.0f) rot -= 360.0f;
    const int bin = std::min(kHistogramBins - 1, static_cast<int>(rot * kHistogramBins / 360.0f));
    bins[bin].push_back(static_cast<int>(i));
  }
  std::array<int, kHistogramBins> order{};
  for (int i = 0; i < kHistogramBins; ++i) order[i] = i;
  std::sort(order.begin(), order.end(), [&](int a, int b) { return bins[a].size() > bins[b].size(); });
  keep->assign(rotation_deg.size(), 0);
  const std::size_t top = bins[order[0]].size();
  for (int k = 0; k < 3; ++k) {
    // Secondary bins count only when reasonably populated.
    if (k > 0 && bins[order[k]].size() < 0.1 * top) break;
    for (int i : bins[order[k]]) (*keep)[i] = 1;
  }
}

bool projectIntoFrame(const Frame& f, const Vec3& p_w, Vec3* p_c, Vec2* uv) {
  *p_c = f.T_c_w * p_w;
  if (p_c->z() <= 0) return false;
  *uv = f.camera->project(*p_c);
  return uv->x() >= 0 && uv->x() < f.camera->width && uv->y() >= 0 && uv->y() < f.camera->height;
}

// The least of [begin, end), 256 (more than any distance) when empty.
int minOf(const int* begin, const int* end) {
  int m = 256;
  for (; begin != end; ++begin) m = std::min(m, *begin);
  return m;
}

// The least distance, the first position holding it (-1 when there is
// none), and the least of the others.
struct NearestTwo {
  int best = 256, second = 256, position = -1;
};
// Also lowers nearest[r] to d[r] in the same pass (when `nearest` is given).
NearestTwo nearestTwo(const std::vector<int>& d, int* nearest) {
  NearestTwo n;
  if (d.empty()) return n;
  for (std::size_t r = 0; r < d.size(); ++r) {
    if (nearest) nearest[r] = std::min(nearest[r], d[r]);
    n.best = std::min(n.best, d[r]);
  }
  n.position = static_cast<int>(std::find(d.begin(), d.end(), n.best) - d.begin());
  n.second = std::min(minOf(d.data(), d.data() + n.position), minOf(d.data() + n.position + 1, d.data() + d.size()));
  return n;
}

int topLevel(const Frame& a, const Frame& b) {
  int top = 0;
  for (const cv::KeyPoint& k : a.keys) top = std::max(top, k.octave);
  for (const cv::KeyPoint& k : b.keys) top = std::max(top, k.octave);
  return top;
}

// A frame's keypoints within two pyramid levels of each level (those `keep`
// accepts), in index order, with their descriptors back to back so that a
// query meets them all in one hammingDistances call (cache-line aligned: the
// vector path loads two descriptors at a time, and a load across two lines
// costs it a third of its speed).
class LevelReach {
 public:
  template <class Keep>
  LevelReach(const Frame& f, int top_level, Keep keep)
      : index(top_level + 1), storage_(top_level + 1), descriptors_(top_level + 1) {
    const auto levels = [&](int i, auto visit) {
      const int o = f.keys[i].octave;
      for (int level = std::max(0, o - 2); level <= std::min(top_level, o + 2); ++level) visit(level);
    };
    std::vector<char> kept(f.size());
    for (int i = 0; i < f.size(); ++i)
      if ((kept[i] = keep(i))) levels(i, [&](int level) { index[level].push_back(i); });
    for (int level = 0; level <= top_level; ++level) {
      storage_[level].resize(index[level].size() * features::kDescriptorBytes + kAlign - 1);
      const auto address = reinterpret_cast<std::uintptr_t>(storage_[level].data());
      descriptors_[level] = storage_[level].data() + (kAlign - address % kAlign) % kAlign;
    }
    std::vector<std::uint8_t*> next(descriptors_);
    for (int i = 0; i < f.size(); ++i)
      if (kept[i])
        levels(i, [&](int level) {
          std::memcpy(next[level], f.descriptor(i), features::kDescriptorBytes);
          next[level] += features::kDescriptorBytes;
        });
  }
  // The query's distance to each keypoint of index[level], in that order.
  void distances(const std::uint8_t* query, int level, std::vector<int>* out) const {
    out->resize(index[level].size());
    features::hammingDistances(query, descriptors_[level], static_cast<int>(out->size()), out->data());
  }

  std::vector<std::vector<int>> index;

 private:
  static constexpr std::uintptr_t kAlign = 64;
  std::vector<std::vector<std::uint8_t>> storage_;
  std::vector<std::uint8_t*> descriptors_;  // into storage_, aligned
};

}  // namespace

void filterByOrientation(const std::vector<float>& rotation_deg, std::vector<int>* match_indices) {
  std::vector<char> keep;
  keepDominantRotations(rotation_deg, &keep);
  std::vector<int> out;
  for (std::size_t i = 0; i < keep.size(); ++i)
    if (keep[i]) out.push_back((*match_indices)[i]);
  *match_indices = std::move(out);
}

int searchByProjection(Frame* current, const Frame& last, float radius, std::vector<float>* ratio_out,
                       float max_ratio) {
  std::vector<float> rotations;
  std::vector<int> matched;
  const LevelInfo& lv = *current->levels;
  for (int i = 0; i < last.size(); ++i) {
    const auto& point = last.points[i];
    if (!point || last.outlier[i] || point->bad) continue;
    Vec3 p_c;
    Vec2 uv;
    if (!projectIntoFrame(*current, point->position, &p_c, &uv)) continue;
    const int level = last.keys[i].octave;
    const float r = radius * static_cast<float>(lv.scales[level]);
    const auto candidates = current->grid.query(current->keys, current->un, static_cast<float>(uv.x()),
                                                static_cast<float>(uv.y()), r, std::max(0, level - 1),
                                                std::min(lv.levels - 1, level + 1));
    const double ur_pred = uv.x() - current->camera->bf() / p_c.z();
    // The second best counts every keypoint in the window, taken or not: it
    // measures how distinctive the point is there.
    int best = 256, best_idx = -1, second = 256, best_any = 256;
    for (int j : candidates) {
      if (current->u_right[j] >= 0 && std::abs(ur_pred - current->u_right[j]) > r) continue;
      const int d = hammingDistance(point->descriptor.data(), current->descriptor(j));
      const bool free = !(current->points[j] && !current->points[j]->bad) && !current->dynamic[j];
      if (free && d < best) {
        best = d;
        best_idx = j;
      }
      if (d < best_any) {
        second = best_any;
        best_any = d;
      } else if (d < second) {
        second = d;
      }
    }
    // The best free keypoint against the best other one in the window; a
    // lone candidate against the distance of a good match (kMatchThresholdLow):
    // the right keypoint was often not detected, and a far one is accepted.
    if (best_idx >= 0 && best > best_any) second = best_any;
    const float ratio =
        static_cast<float>(best) / static_cast<float>(std::max(second >= 256 ? kMatchThresholdLow : second, 1));
    if (best_idx >= 0 && best <= kMatchThresholdHigh && (max_ratio <= 0 || ratio <= max_ratio)) {
      if (ratio_out) (*ratio_out)[best_idx] = ratio;
      current->points[best_idx] = point;
      current->outlier[best_idx] = 0;
      rotations.push_back(last.keys[i].angle - current->keys[best_idx].angle);
      matched.push_back(best_idx);
    }
  }
  std::vector<int> kept = matched;
  filterByOrientation(rotations, &kept);
  std::vector<char> keep_flag(current->size(), 0);
  for (int j : kept) keep_flag[j] = 1;
  for (int j : matched)
    if (!keep_flag[j]) current->points[j] = nullptr;
  return static_cast<int>(kept.size());
}

int searchLocalPoints(Frame* current, const std::vector<std::shared_ptr<MapPoint>>& points,
                      float radius_factor, std::vector<char>* in_view_out) {
  const LevelInfo& lv = *current->levels;
  const Vec3 centre = current->cameraCentre();
  int matches = 0;
  if (in_view_out) in_view_out->assign(points.size(), 0);
  for (std::size_t k = 0; k < points.size(); ++k) {
    const auto& point = points[k];
    if (point->bad) continue;
    // Points that the geometry module keeps seeing on moving surfaces.
    if (point->geometry.dynamic_score.load(std::memory_order_relaxed) > 0.5f) continue;
    Vec3 p_c;
    Vec2 uv;
    if (!projectIntoFrame(*current, point->position, &p_c, &uv)) continue;
    const Vec3 ray = point->position - centre;
    const double dist = ray.norm();
    if (dist < 0.8 * point->min_distance || dist > 1.2 * point->max_distance) continue;
    const double view_cos = ray.dot(point->normal) / dist;
    if (view_cos < 0.5) continue;
    if (in_view_out) (*in_view_out)[k] = 1;
    const int level = point->predictLevel(dist, lv);
    const float r = radius_factor * (view_cos > 0.998 ? 2.5f : 4.0f) * static_cast<float>(lv.scales[level]);
    const auto candidates = current->grid.query(current->keys, current->un, static_cast<float>(uv.x()),
                                                static_cast<float>(uv.y()), r, level - 1, level);
    const double ur_pred = uv.x() - current->camera->bf() / p_c.z();
    int best = 256, second = 256, best_idx = -1, best_level = -1, second_level = -1;
    for (int j : candidates) {
      if (current->points[j] && !current->points[j]->bad && current->points[j]->observations.size() > 0) continue;
      if (current->dynamic[j]) continue;
      if (current->u_right[j] >= 0 && std::abs(ur_pred - current->u_right[j]) > r) continue;
      const int d = hammingDistance(point->descriptor.data(), current->descriptor(j));
      if (d < best) {
        second = best;
        second_level = best_level;
        best = d;
        best_idx = j;
        best_level = current->keys[j].octave;
      } else if (d < second) {
        second = d;
        second_level = current->keys[j].octave;
      }
    }
    if (best_idx < 0 || best > kMatchThresholdHigh) continue;
    if (best_level == second_level && best > 0.8 * second) continue;
    current->points[best_idx] = point;
    current->outlier[best_idx] = 0;
    ++matches;
  }
  return matches;
}

// The matches (frame keypoint j, owner[j]) of `matched` whose rotation lies
// in the dominant bins (filterByOrientation).
std::vector<std::pair<int, int>> orientedPairs(const std::vector<float>& rotations, std::vector<int> matched,
                                               const std::vector<int>& owner) {
  filterByOrientation(rotations, &matched);
  std::vector<std::pair<int, int>> out;
  out.reserve(matched.size());
  for (int j : matched) out.emplace_back(j, owner[j]);
  return out;
}

std::vector<std::pair<int, int>> matchByDescriptor(const Frame& current, const KeyFrame& keyframe, float ratio) {
  return matchByDescriptor(current, keyframe.frame, ratio, true);
}

std::vector<std::pair<int, int>> matchByDescriptor(const Frame& current, const Frame& kf, float ratio,
                                                   bool need_point, bool mutual) {
  // Frame keypoints by level so a keyframe keypoint only meets candidates of
  // nearby scale; brute force (hammingDistances) is affordable at ~1000 x
  // ~1000.
  const int top_level = topLevel(current, kf);
  const LevelReach reach(current, top_level, [&](int j) { return !(need_point && current.dynamic[j]); });
  std::vector<int> best_for_frame(current.size(), 256);
  std::vector<int> owner(current.size(), -1);
  // Each candidate's nearest distance to any keyframe keypoint, per level list.
  std::vector<std::vector<int>> nearest_at(top_level + 1);
  for (int level = 0; level <= top_level; ++level) nearest_at[level].assign(reach.index[level].size(), 256);
  std::vector<int> distance;
  for (int i = 0; i < kf.size(); ++i) {
    if (need_point ? !kf.points[i] || kf.points[i]->bad : !(kf.depth[i] > 0)) continue;
    if (kf.keys[i].octave < 0) continue;  // never from our extractor
    const int level = kf.keys[i].octave;
    reach.distances(kf.descriptor(i), level, &distance);
    const NearestTwo n = nearestTwo(distance, nearest_at[level].data());
    if (n.position < 0 || n.best > kMatchThresholdLow || n.best > ratio * n.second) continue;
    const int j = reach.index[level][n.position];
    if (n.best >= best_for_frame[j]) continue;
    best_for_frame[j] = n.best;
    owner[j] = i;
  }
  std::vector<int> nearest(current.size(), 256);
  for (int level = 0; level <= top_level; ++level)
    for (std::size_t r = 0; r < reach.index[level].size(); ++r)
      nearest[reach.index[level][r]] = std::min(nearest[reach.index[level][r]], nearest_at[level][r]);
  std::vector<float> rotations;
  std::vector<int> matched;
  for (int j = 0; j < current.size(); ++j) {
    if (owner[j] < 0) continue;
    // Mutual: no other candidate lies strictly nearer to the frame keypoint.
    if (mutual && nearest[j] < best_for_frame[j]) continue;
    matched.push_back(j);
    rotations.push_back(kf.keys[owner[j]].angle - current.keys[j].angle);
  }
  return orientedPairs(rotations, std::move(matched), owner);
}

std::vector<std::pair<int, int>> matchSomeByDescriptor(const Frame& current, const Frame& other, float ratio,
                                                       const std::vector<int>& features) {
  // matchByDescriptor accepts (j, i) when i is the first keypoint of `other`
  // at j's nearest distance whose own best frame keypoint (first by index,
  // ratio test) is j. Both scans keep matchByDescriptor's reach (two levels)
  // and index order, so ties fall the same way.
  const int top_level = topLevel(current, other);
  const LevelReach other_near(other, top_level, [&](int i) { return other.depth[i] > 0 && other.keys[i].octave >= 0; });
  const LevelReach current_near(current, top_level, [](int) { return true; });
  std::vector<int> distance, back;
  // Whether i's best frame keypoint is j, at distance d_ij, and passes the
  // ratio test: no other k has ratio * d(i, k) < d_ij, and none before j
  // ties it (at d_ij = 0 the ratio cannot tell).
  const auto bestOf = [&](int i, int j, int d_ij) {
    const int level = other.keys[i].octave;
    current_near.distances(other.descriptor(i), level, &back);
    const std::vector<int>& index = current_near.index[level];
    const auto at = std::lower_bound(index.begin(), index.end(), j) - index.begin();  // j is in i's reach
    const int before = minOf(back.data(), back.data() + at);
    const int after = minOf(back.data() + at + 1, back.data() + back.size());
    return before > d_ij && !(d_ij > ratio * std::min(before, after));
  };
  std::vector<int> matched, owner(current.size(), -1);
  std::vector<float> rotations;
  for (int j : features) {
    const int level = current.keys[j].octave;
    other_near.distances(current.descriptor(j), level, &distance);
    const int nearest = minOf(distance.data(), distance.data() + distance.size());
    if (nearest > kMatchThresholdLow) continue;
    for (std::size_t r = 0; r < distance.size(); ++r)
      if (distance[r] == nearest && bestOf(other_near.index[level][r], j, nearest)) {
        owner[j] = other_near.index[level][r];
        break;
      }
    if (owner[j] < 0) continue;
    matched.push_back(j);
    rotations.push_back(other.keys[owner[j]].angle - current.keys[j].angle);
  }
  return orientedPairs(rotations, std::move(matched), owner);
}

std::vector<std::pair<int, int>> matchFromSomeByDescriptor(const Frame& current, const Frame& other, float ratio,
                                                           const std::vector<int>& from) {
  // A few listed keypoints scan the whole frame at once: building the level
  // lists (LevelReach) would cost more than the scans. The reach is the same
  // (two pyramid levels either way), in index order, so ties fall as there.
  const auto near = [](const cv::KeyPoint& a, const cv::KeyPoint& b) { return std::abs(a.octave - b.octave) <= 2; };
  const auto distancesTo = [](const std::uint8_t* query, const Frame& f, std::vector<int>* out) {
    out->resize(f.size());
    if (f.descriptors.isContinuous()) {
      features::hammingDistances(query, f.descriptor(0), f.size(), out->data());
    } else {
      for (int k = 0; k < f.size(); ++k) (*out)[k] = features::hammingDistance(query, f.descriptor(k));
    }
  };
  // Keypoint i of `other` claims its nearest frame keypoint (the first at
  // that distance) when it passes the ratio test; -1 when it does not.
  std::vector<int> distance;
  const auto claimOf = [&](int i, int* best_out) {
    distancesTo(other.descriptor(i), current, &distance);
    for (int j = 0; j < current.size(); ++j)
      if (!near(other.keys[i], current.keys[j])) distance[j] = 256;  // out of reach: more than any distance
    const NearestTwo n = nearestTwo(distance, nullptr);
    *best_out = n.best;
    return n.best > kMatchThresholdLow || n.best > ratio * n.second ? -1 : n.position;
  };
  std::vector<int> best_for_frame(current.size(), 256), owner(current.size(), -1);
  std::vector<int> claimed;
  if (current.size() == 0 || other.size() == 0) return {};
  for (int i : from) {
    if (!(other.depth[i] > 0) || other.keys[i].octave < 0) continue;
    int best = 256;
    const int j = claimOf(i, &best);
    if (j < 0 || best >= best_for_frame[j]) continue;
    if (owner[j] < 0) claimed.push_back(j);
    best_for_frame[j] = best;
    owner[j] = i;
  }
  std::sort(claimed.begin(), claimed.end());
  std::vector<int> matched;
  std::vector<float> rotations;
  std::vector<int> back, tied;
  for (int j : claimed) {
    // Mutual: no keypoint of `other` with depth within j's reach lies
    // strictly nearer, and none before the owner ties it and claims j too
    // (the whole matching gives j to the first).
    distancesTo(current.descriptor(j), other, &back);
    bool mutual = true;
    tied.clear();
    for (int i = 0; i < other.size() && mutual; ++i) {
      if (!(other.depth[i] > 0) || other.keys[i].octave < 0 || !near(other.keys[i], current.keys[j])) continue;
      mutual = back[i] >= best_for_frame[j];
      if (back[i] == best_for_frame[j] && i < owner[j]) tied.push_back(i);
    }
    for (std::size_t k = 0; k < tied.size() && mutual; ++k) {
      int best = 256;
      mutual = claimOf(tied[k], &best) != j;
    }
    if (!mutual) continue;
    matched.push_back(j);
    rotations.push_back(other.keys[owner[j]].angle - current.keys[j].angle);
  }
  return orientedPairs(rotations, std::move(matched), owner);
}

int searchByDescriptor(Frame* current, const KeyFrame& keyframe, float ratio) {
  const auto matches = matchByDescriptor(*current, keyframe, ratio);
  for (const auto& [j, i] : matches) {
    current->points[j] = keyframe.frame.points[i];
    current->outlier[j] = 0;
  }
  return static_cast<int>(matches.size());
}


}  // namespace stillpoint::slam
