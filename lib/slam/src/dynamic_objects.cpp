#include "dynamic_objects.hpp"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <array>
#include <numeric>

namespace stillpoint::slam {
namespace {

// A region needs this many depth samples (geometry) or features with depth
// (semantic) to be an object: fewer are noise at an edge.
constexpr int kMinSamples = 6;
constexpr int kMinSemanticFeatures = 5;
// Semantic features of one class further apart than this belong to
// different objects (single linkage).
constexpr double kLinkDistanceM = 0.5;
// Following: an object is the one of the last frames whose predicted
// centroid lies nearest, within kGateM plus what kMaxSpeed allows.
constexpr double kGateM = 0.3;
constexpr double kMaxSpeedMps = 3.0;
constexpr double kForgetAfterS = 0.5;
constexpr double kVelocitySmoothing = 0.5;  // weight of the newest measurement
// A region only the geometry module saw is reported once it has been
// followed through this many frames: a cluster misjudged in one or two
// frames of a static scene is no mover.
constexpr int kConfirmFrames = 3;
// A depth cluster is a slab of the view: of a region's samples, keep those
// within this margin of the depths of the features judged moving in it (the
// floor or wall beside a mover shares its cluster but not its depth).
constexpr double kDepthMarginM = 0.25;

struct Region {
  std::vector<Vec3> points;  // map frame
  std::vector<int> features;  // semantic: frame feature indices
  std::uint8_t class_id = 0;
  std::uint8_t sources = 0;
  cv::Rect grid_box;  // geometry: its cells, label-grid coordinates
  std::vector<int> components;  // geometry: its connected regions of the grid
};

// Median per axis and the 5-95 % range per axis (of at most 512 of the
// points, evenly taken: the quantiles hardly change, the cost stays flat).
void measure(const std::vector<Vec3>& all, DynamicObject* o) {
  std::vector<Vec3> points;
  const std::size_t stride = (all.size() + 511) / 512;
  for (std::size_t k = 0; k < all.size(); k += stride) points.push_back(all[k]);
  const std::size_t n = points.size();
  for (int axis = 0; axis < 3; ++axis) {
    std::vector<double> v(n);
    for (std::size_t k = 0; k < n; ++k) v[k] = points[k][axis];
    const auto at = [&](double q) {
      const std::size_t i = std::min(n - 1, static_cast<std::size_t>(q * static_cast<double>(n - 1) + 0.5));
      std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(i), v.end());
      return v[i];
    };
    o->centroid[axis] = at(0.5);
    const double lo = at(0.05), hi = at(0.95);
    o->extent[axis] = hi - lo;
  }
  o->samples = static_cast<int>(all.size());
}

}  // namespace

void DynamicObjectTracker::missed(Timestamp stamp) {
  std::erase_if(followed_, [&](const Followed& f) { return secondsBetween(stamp, f.seen) > kForgetAfterS; });
}

std::vector<DynamicObject> DynamicObjectTracker::update(const Frame& frame, const GeometryOutput& geometry,
                                                        std::uint32_t map_id,
                                                        const std::function<std::string(std::uint8_t)>& class_name) {
  if (any_ && map_id != map_id_) followed_.clear();  // another map: another frame
  any_ = true;
  map_id_ = map_id;
  const SE3 T_w_c = frame.T_c_w.inverse();
  std::vector<Region> regions;

  // Geometry: connected regions of the dynamic clusters on the sample grid.
  cv::Mat components;
  if (geometry.ran && geometry.dynamic_clusters > 0 && geometry.labels && !geometry.labels->labels.empty() &&
      !geometry.labels->depth.empty()) {
    const geometry::DepthClusters& L = *geometry.labels;
    cv::Mat mask(L.labels.size(), CV_8U, cv::Scalar(0));
    for (int r = 0; r < L.labels.rows; ++r)
      for (int c = 0; c < L.labels.cols; ++c) {
        const int label = L.labels.at<std::int16_t>(r, c);
        if (label >= 0 && label < static_cast<int>(geometry.scores.size()) && geometry.scores[label].dynamic)
          mask.at<std::uint8_t>(r, c) = 1;
      }
    cv::Mat stats, centres;
    const int n = cv::connectedComponentsWithStats(mask, components, stats, centres, 8, CV_32S);
    std::vector<int> region_of(n, -1);
    for (int k = 1; k < n; ++k) {
      if (stats.at<int>(k, cv::CC_STAT_AREA) < kMinSamples) continue;
      region_of[k] = static_cast<int>(regions.size());
      Region& g = regions.emplace_back();
      g.sources = DynamicObject::kGeometry;
      g.components = {k};
      g.grid_box = cv::Rect(stats.at<int>(k, cv::CC_STAT_LEFT), stats.at<int>(k, cv::CC_STAT_TOP),
                            stats.at<int>(k, cv::CC_STAT_WIDTH), stats.at<int>(k, cv::CC_STAT_HEIGHT));
    }
    const int step = std::max(1, L.step), half = step / 2;
    // The depths of each region's moving features (10-90 %), its gate.
    std::vector<std::vector<float>> feature_depths(regions.size());
    for (int i = 0; i < frame.size(); ++i) {
      if (frame.dynamic[i] != kGeometryDynamic || !(frame.depth[i] > 0)) continue;
      const int c = std::clamp(static_cast<int>(frame.keys[i].pt.x) / step, 0, components.cols - 1);
      const int r = std::clamp(static_cast<int>(frame.keys[i].pt.y) / step, 0, components.rows - 1);
      const int k = components.at<int>(r, c);
      if (k > 0 && region_of[k] >= 0) feature_depths[region_of[k]].push_back(frame.depth[i]);
    }
    std::vector<std::pair<float, float>> gate(regions.size(), {0.0f, 1e9f});
    for (std::size_t g = 0; g < regions.size(); ++g) {
      auto& d = feature_depths[g];
      if (d.size() < 3) continue;
      std::sort(d.begin(), d.end());
      gate[g] = {d[d.size() / 10] - static_cast<float>(kDepthMarginM),
                 d[(d.size() * 9) / 10] + static_cast<float>(kDepthMarginM)};
    }
    for (int r = 0; r < components.rows; ++r)
      for (int c = 0; c < components.cols; ++c) {
        const int k = components.at<int>(r, c);
        if (k <= 0 || region_of[k] < 0) continue;
        const int x = c * step + half, y = r * step + half;
        if (x >= L.depth.cols || y >= L.depth.rows) continue;
        const float z = L.depth.at<float>(y, x);
        if (!(z > 0) || z < gate[region_of[k]].first || z > gate[region_of[k]].second) continue;
        const Vec2 un = camera_.undistortPixel(Vec2(x, y));
        regions[region_of[k]].points.push_back(T_w_c * camera_.unproject(un, z));
      }
    std::erase_if(regions, [](const Region& g) { return static_cast<int>(g.points.size()) < kMinSamples; });
  }

  // Semantic: the features masks keep out, by class, then by place.
  std::vector<int> semantic;
  for (int i = 0; i < frame.size(); ++i)
    if (frame.dynamic[i] == kSemanticDynamic && frame.depth[i] > 0) semantic.push_back(i);
  std::vector<Vec3> world(semantic.size());
  for (std::size_t k = 0; k < semantic.size(); ++k) world[k] = frame.unprojectToWorld(semantic[k]);
  const auto class_of = [&](int i) {
    return frame.movable_class.empty() ? std::uint8_t{0} : frame.movable_class[static_cast<std::size_t>(i)];
  };
  std::vector<int> group(semantic.size(), -1);
  int groups = 0;
  for (std::size_t seed = 0; seed < semantic.size(); ++seed) {
    if (group[seed] >= 0) continue;
    group[seed] = groups;
    std::vector<std::size_t> open{seed};
    while (!open.empty()) {
      const std::size_t a = open.back();
      open.pop_back();
      for (std::size_t b = 0; b < semantic.size(); ++b)
        if (group[b] < 0 && class_of(semantic[b]) == class_of(semantic[a]) &&
            (world[a] - world[b]).norm() < kLinkDistanceM) {
          group[b] = groups;
          open.push_back(b);
        }
    }
    ++groups;
  }
  std::vector<Region> found(groups);
  for (std::size_t k = 0; k < semantic.size(); ++k) {
    Region& s = found[group[k]];
    s.points.push_back(world[k]);
    s.features.push_back(semantic[k]);
    s.class_id = class_of(semantic[k]);
    s.sources = DynamicObject::kSemantic;
  }
  for (Region& s : found) {
    if (static_cast<int>(s.features.size()) < kMinSemanticFeatures) continue;
    // Over a geometry region (most of its features on its cells): one
    // object, the class from the masks, the surface from the depth.
    int best = -1, best_votes = 0;
    if (!components.empty()) {
      const int step = std::max(1, geometry.labels->step);
      std::vector<int> votes(regions.size(), 0);
      for (int i : s.features) {
        const int c = std::clamp(static_cast<int>(frame.keys[i].pt.x) / step, 0, components.cols - 1);
        const int r = std::clamp(static_cast<int>(frame.keys[i].pt.y) / step, 0, components.rows - 1);
        const int comp = components.at<int>(r, c);
        for (std::size_t g = 0; g < regions.size(); ++g)
          if (comp > 0 && std::find(regions[g].components.begin(), regions[g].components.end(), comp) !=
                              regions[g].components.end())
            ++votes[g];
      }
      for (std::size_t g = 0; g < regions.size(); ++g)
        if (votes[g] > best_votes) best = static_cast<int>(g), best_votes = votes[g];
    }
    if (best >= 0 && 2 * best_votes >= static_cast<int>(s.features.size())) {
      regions[best].sources |= DynamicObject::kSemantic;
      if (regions[best].class_id == 0) regions[best].class_id = s.class_id;
    } else {
      regions.push_back(std::move(s));
    }
  }

  // Measure, then follow: greedy nearest pairs to the objects of the last
  // frames, each predicted by its velocity.
  std::vector<DynamicObject> objects(regions.size());
  for (std::size_t k = 0; k < regions.size(); ++k) {
    measure(regions[k].points, &objects[k]);
    objects[k].sources = regions[k].sources;
    objects[k].label = regions[k].class_id ? class_name(regions[k].class_id) : std::string("unknown");
  }
  struct Pair {
    double distance;
    std::size_t now, before;
  };
  std::vector<Pair> pairs;
  for (std::size_t k = 0; k < objects.size(); ++k)
    for (std::size_t f = 0; f < followed_.size(); ++f) {
      const DynamicObject& b = followed_[f].object;
      if (b.label != objects[k].label && b.label != "unknown" && objects[k].label != "unknown") continue;
      const double dt = std::max(0.0, secondsBetween(frame.stamp, followed_[f].seen));
      const Vec3 predicted = b.has_velocity ? Vec3(b.centroid + b.velocity * dt) : b.centroid;
      const double d = (objects[k].centroid - predicted).norm();
      if (d < kGateM + kMaxSpeedMps * dt) pairs.push_back({d, k, f});
    }
  std::sort(pairs.begin(), pairs.end(), [](const Pair& a, const Pair& b) { return a.distance < b.distance; });
  std::vector<char> now_taken(objects.size(), 0), before_taken(followed_.size(), 0);
  for (const Pair& p : pairs) {
    if (now_taken[p.now] || before_taken[p.before]) continue;
    now_taken[p.now] = before_taken[p.before] = 1;
    DynamicObject& o = objects[p.now];
    const Followed& b = followed_[p.before];
    o.id = b.object.id;
    o.frames = b.object.frames + 1;
    if (o.label == "unknown") o.label = b.object.label;  // a class once seen stays
    const double dt = secondsBetween(frame.stamp, b.seen);
    if (dt > 1e-3) {
      const Vec3 measured = (o.centroid - b.object.centroid) / dt;
      o.velocity = b.object.has_velocity
                       ? Vec3(kVelocitySmoothing * measured + (1 - kVelocitySmoothing) * b.object.velocity)
                       : measured;
      o.has_velocity = true;
    }
  }
  for (std::size_t k = 0; k < objects.size(); ++k)
    if (!now_taken[k]) objects[k].id = next_id_++;
  std::vector<Followed> kept;
  for (std::size_t f = 0; f < followed_.size(); ++f)
    if (!before_taken[f] && secondsBetween(frame.stamp, followed_[f].seen) <= kForgetAfterS) kept.push_back(followed_[f]);
  for (const DynamicObject& o : objects) kept.push_back({o, frame.stamp});
  followed_ = std::move(kept);
  std::erase_if(objects, [](const DynamicObject& o) {
    return !(o.sources & DynamicObject::kSemantic) && o.label == "unknown" && o.frames < kConfirmFrames;
  });
  return objects;
}

}  // namespace stillpoint::slam
