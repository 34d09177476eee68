#include "matcher.hpp"

#include <algorithm>
#include <array>
#include <cmath>

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
    if (point->dynamic_score.load(std::memory_order_relaxed) > 0.5f) continue;
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

std::vector<std::pair<int, int>> matchByDescriptor(const Frame& current, const KeyFrame& keyframe, float ratio) {
  return matchByDescriptor(current, keyframe.frame, ratio, true);
}

std::vector<std::pair<int, int>> matchByDescriptor(const Frame& current, const Frame& kf, float ratio,
                                                   bool need_point, bool mutual) {
  // Frame keypoints by level so a map point only meets candidates of nearby
  // scale; brute force is affordable at ~1000 x ~1000 with popcount.
  std::vector<float> rotations;
  std::vector<int> matched;
  std::vector<int> best_for_frame(current.size(), 256);
  std::vector<int> owner(current.size(), -1);
  std::vector<int> nearest(current.size(), 256);  // each frame keypoint's nearest distance to any candidate
  // The frame's candidates for each level (within 2 levels of it), in index
  // order, so the scan below meets them in the same order as a full scan
  // would (ties keep the first) without visiting the others.
  int top_level = 0;
  for (const cv::KeyPoint& k : current.keys) top_level = std::max(top_level, k.octave);
  for (const cv::KeyPoint& k : kf.keys) top_level = std::max(top_level, k.octave);
  std::vector<std::vector<int>> candidates(top_level + 1);
  for (int j = 0; j < current.size(); ++j) {
    if (need_point && current.dynamic[j]) continue;
    const int o = current.keys[j].octave;
    for (int level = std::max(0, o - 2); level <= std::min(top_level, o + 2); ++level) candidates[level].push_back(j);
  }
  for (int i = 0; i < kf.size(); ++i) {
    if (need_point ? !kf.points[i] || kf.points[i]->bad : !(kf.depth[i] > 0)) continue;
    if (kf.keys[i].octave < 0) continue;  // never from our extractor
    const std::uint8_t* d_kf = kf.descriptor(i);
    int best = 256, second = 256, best_idx = -1;
    for (int j : candidates[kf.keys[i].octave]) {
      const int d = hammingDistance(d_kf, current.descriptor(j));
      nearest[j] = std::min(nearest[j], d);
      if (d < best) {
        second = best;
        best = d;
        best_idx = j;
      } else if (d < second) {
        second = d;
      }
    }
    if (best_idx < 0 || best > kMatchThresholdLow || best > ratio * second) continue;
    if (best >= best_for_frame[best_idx]) continue;
    best_for_frame[best_idx] = best;
    owner[best_idx] = i;
  }
  for (int j = 0; j < current.size(); ++j) {
    if (owner[j] < 0) continue;
    // Mutual: no other candidate lies strictly nearer to the frame keypoint.
    if (mutual && nearest[j] < best_for_frame[j]) continue;
    matched.push_back(j);
    rotations.push_back(kf.keys[owner[j]].angle - current.keys[j].angle);
  }
  filterByOrientation(rotations, &matched);
  std::vector<std::pair<int, int>> out;
  out.reserve(matched.size());
  for (int j : matched) out.emplace_back(j, owner[j]);
  return out;
}

std::vector<std::pair<int, int>> matchSomeByDescriptor(const Frame& current, const Frame& other, float ratio,
                                                       const std::vector<int>& features) {
  // matchByDescriptor accepts (j, i) when i is the first keypoint of `other`
  // at j's nearest distance whose own best frame keypoint (first by index,
  // ratio test) is j. Both scans keep matchByDescriptor's reach (two levels)
  // and index order, so ties fall the same way.
  int top_level = 0;
  for (const cv::KeyPoint& k : current.keys) top_level = std::max(top_level, k.octave);
  for (const cv::KeyPoint& k : other.keys) top_level = std::max(top_level, k.octave);
  std::vector<std::vector<int>> other_near(top_level + 1), current_near(top_level + 1);
  const auto addNear = [top_level](std::vector<std::vector<int>>* near, int octave, int index) {
    for (int level = std::max(0, octave - 2); level <= std::min(top_level, octave + 2); ++level)
      (*near)[level].push_back(index);
  };
  for (int i = 0; i < other.size(); ++i)
    if (other.depth[i] > 0 && other.keys[i].octave >= 0) addNear(&other_near, other.keys[i].octave, i);
  for (int j = 0; j < current.size(); ++j) addNear(&current_near, current.keys[j].octave, j);
  // Whether i's best frame keypoint is j, at distance d_ij, and passes the
  // ratio test: no other k has ratio * d(i, k) < d_ij, and none before j
  // ties it (at d_ij = 0 the ratio cannot tell). Stops at the first k that
  // fails it, which is what makes rejections cheap.
  const auto bestOf = [&](int i, int j, int d_ij) {
    const std::uint8_t* d_i = other.descriptor(i);
    for (int k : current_near[other.keys[i].octave]) {
      if (k == j) continue;
      const int d = hammingDistance(d_i, current.descriptor(k));
      if (d_ij > ratio * d || (k < j && d <= d_ij)) return false;
    }
    return true;
  };
  std::vector<int> matched, owner(current.size(), -1), distance;
  std::vector<float> rotations;
  for (int j : features) {
    const std::vector<int>& reach = other_near[current.keys[j].octave];
    const std::uint8_t* d_j = current.descriptor(j);
    distance.resize(reach.size());
    int nearest = 256;
    for (std::size_t r = 0; r < reach.size(); ++r) {
      distance[r] = hammingDistance(other.descriptor(reach[r]), d_j);
      nearest = std::min(nearest, distance[r]);
    }
    if (nearest > kMatchThresholdLow) continue;
    for (std::size_t r = 0; r < reach.size(); ++r)
      if (distance[r] == nearest && bestOf(reach[r], j, nearest)) {
        owner[j] = reach[r];
        break;
      }
    if (owner[j] < 0) continue;
    matched.push_back(j);
    rotations.push_back(other.keys[owner[j]].angle - current.keys[j].angle);
  }
  filterByOrientation(rotations, &matched);
  std::vector<std::pair<int, int>> out;
  out.reserve(matched.size());
  for (int j : matched) out.emplace_back(j, owner[j]);
  return out;
}

int searchByDescriptor(Frame* current, const KeyFrame& keyframe, float ratio) {
  const auto matches = matchByDescriptor(*current, keyframe, ratio);
  for (const auto& [j, i] : matches) {
    current->points[j] = keyframe.frame.points[i];
    current->outlier[j] = 0;
  }
  return static_cast<int>(matches.size());
}

int fuse(Map* map, KeyFrame* kf, const std::vector<std::shared_ptr<MapPoint>>& points, float radius) {
  Frame& f = kf->frame;
  const LevelInfo& lv = *f.levels;
  const Vec3 centre = f.cameraCentre();
  int fused = 0;
  for (const auto& point : points) {
    if (!point || point->bad || point->observations.count(kf)) continue;
    Vec3 p_c;
    Vec2 uv;
    if (!projectIntoFrame(f, point->position, &p_c, &uv)) continue;
    const Vec3 ray = point->position - centre;
    const double dist = ray.norm();
    if (dist < 0.8 * point->min_distance || dist > 1.2 * point->max_distance) continue;
    if (ray.dot(point->normal) < 0.5 * dist) continue;
    const int level = point->predictLevel(dist, lv);
    const float r = radius * static_cast<float>(lv.scales[level]);
    const auto candidates =
        f.grid.query(f.keys, f.un, static_cast<float>(uv.x()), static_cast<float>(uv.y()), r, level - 1, level + 1);
    const double ur_pred = uv.x() - f.camera->bf() / p_c.z();
    int best = 256, best_idx = -1;
    for (int j : candidates) {
      if (f.dynamic[j]) continue;
      const int kl = f.keys[j].octave;
      // Reprojection gate at the candidate's own scale (chi2, 3 or 2 dof).
      const double ex = uv.x() - f.un[j].x, ey = uv.y() - f.un[j].y;
      double e2 = ex * ex + ey * ey;
      double gate = 5.99;
      if (f.u_right[j] >= 0) {
        const double er = ur_pred - f.u_right[j];
        e2 += er * er;
        gate = 7.8;
      }
      if (e2 * lv.inv_sigma2[kl] > gate) continue;
      const int d = hammingDistance(point->descriptor.data(), f.descriptor(j));
      if (d < best) {
        best = d;
        best_idx = j;
      }
    }
    if (best_idx < 0 || best > kMatchThresholdLow) continue;
    const auto existing = f.points[best_idx];
    // Two points are one only if they agree in 3D too: the image gate alone
    // lets a point merge with one metres behind it on the same ray.
    // (3 % of the depth, 2 cm at least: about 3 sigma of the sensor's noise.)
    if (existing && !existing->bad &&
        (existing->position - point->position).norm() > std::max(0.02, 0.03 * p_c.z()))
      continue;
    if (existing && !existing->bad) {
      // Keep the better observed of the two.
      if (existing->observations.size() >= point->observations.size())
        map->replacePoint(point, existing);
      else
        map->replacePoint(existing, point);
    } else {
      kf->addObservation(point, best_idx);
      point->updateFromObservations();
    }
    ++fused;
  }
  return fused;
}

}  // namespace stillpoint::slam
