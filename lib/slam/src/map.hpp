#pragma once
// Keyframes, map points and the covisibility graph.
//
// Locking rule (Map::mutex()):
// - The map's structure (keyframes, points, observations, covisibility, the
//   spanning tree, positions and poses) changes only under the exclusive
//   lock: local mapping (culling, bundle adjustment's write-back, semantic
//   masks) and tracking when it makes a map, inserts a keyframe or frees the
//   culled ones.
// - Under the shared lock, tracking reads the structure and writes only its
//   own bookkeeping (MapPoint::visible, found, local_search and
//   geometry.probation; KeyFrame::local_search), which other threads read
//   only under the exclusive lock;
//   MapPoint::geometry.dynamic_score is atomic (written by tracking, read by
//   local mapping and the matcher). Tracking is the only thread that takes
//   the shared lock to write, so its writes never race with one another.
// - Temporary points (MapPoint::temporary) belong to one frame of the
//   tracking thread and are never in the map.
#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <shared_mutex>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "dense_cloud.hpp"
#include "frame.hpp"
#include "stillpoint/core/result.hpp"
#include "stillpoint/features/vocabulary.hpp"

namespace stillpoint::slam {

class KeyFrame;

// Where a pose relative to a keyframe is anchored (trajectory records). While
// the keyframe is in the map the anchor follows its pose (bundle adjustment
// moves it); when the keyframe is culled the anchor keeps its pose relative to
// the anchor of the keyframe that takes over its children (its parent), or in
// the world when it has none. Records hold anchors, not keyframes, so a culled
// keyframe is freed while the poses expressed through it still resolve; an
// anchor lives as long as something expressed through it does. Read and
// written under the map's lock.
class PoseAnchor {
 public:
  explicit PoseAnchor(const KeyFrame* keyframe) : keyframe_(keyframe) {}
  SE3 T_c_w() const;

 private:
  friend class Map;
  const KeyFrame* keyframe_;  // null once culled
  std::shared_ptr<const PoseAnchor> parent_;
  SE3 T_self_parent_ = SE3::Identity();  // T_self_world when there is no parent
};

// Containers keyed by keyframe iterate in keyframe-id order, never in
// pointer order, so runs are reproducible.
struct KeyFrameIdLess {
  bool operator()(const KeyFrame* a, const KeyFrame* b) const;
};
using KeyFrameIndexMap = std::map<KeyFrame*, int, KeyFrameIdLess>;

class MapPoint {
 public:
  MapPoint(std::int64_t id, const Vec3& position, KeyFrame* reference) : id(id), position(position), reference(reference) {}

  const std::int64_t id;
  Vec3 position;
  Vec3 normal = Vec3::Zero();  // mean viewing direction (unit)
  double min_distance = 0, max_distance = 0;  // scale-invariance range
  std::array<std::uint8_t, 32> descriptor{};
  KeyFrameIndexMap observations;  // keyframe -> keypoint index
  KeyFrame* reference;
  std::int64_t first_keyframe_id = 0;
  int visible = 1;  // times it was inside a tracked frame's view (tracking; see the locking rule)
  int found = 1;    // times it was matched there (tracking)
  bool bad = false;
  // The point this one was fused into (Map::replacePoint), once bad.
  std::weak_ptr<MapPoint> replaced_by;
  // The geometry module's state of the point.
  struct Geometry {
    // Exponentially weighted share of recent observations that fell in
    // dynamic depth clusters (written by tracking, read by local mapping).
    std::atomic<float> dynamic_score{0.0f};
    // Frames it must still be matched consistently with a pose estimated
    // without it before it may enter the pose (geometry.probation_frames; 0:
    // trusted). Tracking only.
    int probation = 0;
    // Made on a feature of a known mover (DynamicDetector::onKnownMover): its
    // probation is geometry.mover_probation_frames, and it is the last to
    // join a fit short of trusted matches. Tracking only.
    bool on_mover = false;
  } geometry;
  // The semantic module's state (local mapping only): segmented keyframes
  // that observed this point, and how many of them saw it in a movable mask.
  struct Semantic {
    int checks = 0;
    int hits = 0;
  } semantic;
  // Tracking's local-map bookkeeping: the last local-map search that gathered
  // it (Tracker::updateLocalMap numbers them; a frame may search more than once).
  std::int64_t local_search = -1;
  bool isTemporary() const { return id < 0; }
  // A temporary point of a frame's feature i (from its depth): the motion
  // model's odometry, or with `mover_evidence` evidence of a feature found
  // moving, which stage 1 matches but never puts in a pose.
  static std::shared_ptr<MapPoint> temporary(const Frame& frame, int i, bool mover_evidence);
  bool moverEvidence() const { return mover_evidence_; }

  double foundRatio() const { return static_cast<double>(found) / visible; }
  // Level at which a feature of this point is expected at distance d.
  int predictLevel(double distance, const LevelInfo& levels) const;
  // Recomputes descriptor, normal and distance range from the observations.
  void updateFromObservations();

 private:
  bool mover_evidence_ = false;
};

class KeyFrame {
 public:
  KeyFrame(std::int64_t id, const Frame& frame);

  const std::int64_t id;
  Frame frame;  // features, matches (frame.points) and pose (frame.T_c_w)
  // The map it belongs to (Map::activeMapId() when it was made), and whether
  // it is that map's first keyframe: its origin, never culled, fixed in
  // bundle adjustment, the root of the map's spanning tree.
  std::uint32_t map_id = 0;
  bool origin = false;

  SE3& T_c_w() { return frame.T_c_w; }
  const SE3& T_c_w() const { return frame.T_c_w; }

  // Covisibility: keyframes sharing at least kMinWeight points, by weight.
  static constexpr int kMinWeight = 15;
  KeyFrameIndexMap connections;
  std::vector<KeyFrame*> ordered_neighbours;
  void updateConnections();
  std::vector<KeyFrame*> bestNeighbours(int n) const;

  // Spanning tree of the keyframes in the map (culled ones leave it).
  KeyFrame* parent = nullptr;
  std::vector<KeyFrame*> children;
  bool bad = false;  // culled: out of the graph, freed by Map::releaseCulledKeyFrames()
  std::shared_ptr<const PoseAnchor> anchor() const { return anchor_; }

  // Bookkeeping of the local-map search (as MapPoint::local_search).
  std::int64_t local_search = -1;
  std::int64_t ba_local_for = -1, ba_fixed_for = -1;

  // Points tracking found on moving surfaces since the previous keyframe;
  // local mapping culls those that stay dynamic.
  std::vector<std::shared_ptr<MapPoint>> dynamic_suspects;

  // Its view as words (place recognition; empty without a vocabulary). Set
  // before the keyframe enters the map, or by Map::indexKeyFrame.
  features::BowVector bow;

  // The semantic module's result was applied (its features in movable masks
  // are flagged dynamic and hold no map point).
  bool segmented = false;
  // Its depth and colour at a quarter of the resolution, moving and movable
  // pixels marked (mapping.dense_views; null otherwise). Replaced, never
  // changed in place, under the exclusive lock.
  std::shared_ptr<const DenseView> dense;

  int trackedPoints(int min_observations) const;
  void addObservation(const std::shared_ptr<MapPoint>& point, int index);
  void eraseObservation(int index);

 private:
  friend class Map;
  std::shared_ptr<PoseAnchor> anchor_;
};

// Places in a map's world are kept by 10 cm cell (StaticSightings, and where
// the last masks were: Tracker::recentlyMasked): the cell holding p, and its
// key within one map (21 bits per coordinate: cells within 104 km of the
// map's origin have keys of their own).
constexpr double kPlaceCell = 0.1;  // m
Eigen::Vector3i placeCell(const Vec3& p);
std::uint64_t cellKey(const Eigen::Vector3i& cell);
Eigen::Vector3i cellOfKey(std::uint64_t key);
// Whether the cell of p, or one of its 26 neighbours, is among `places`
// (cell keys of one map).
bool nearPlace(const std::unordered_set<std::uint64_t>& places, const Vec3& p);

// Where the semantic module saw objects of static classes (a teddy bear, a
// chair) and movers, per map and 10 cm cell of its world: how many segmented
// keyframes had a feature there on a confident static instance
// (SemanticResult::static_mask), over what time, and how many had one there in
// an applied movable region or flagged by the geometry module. Detectors
// relabel an object from frame to frame (COCO calls the teddy bear a person
// while a person stands beside it); a place seen as a static object at least
// `min` times over at least `min_span_s`, and more often than a mover, is one
// the map has seen standing. The span keeps out a person who walks behind a
// static object and is painted with its mask for a moment. Kept by place, not
// by map point: each keyframe maps its own copy of a surface and points come
// and go, the place stays. Part of the map (Map::staticSightings) and of its
// file: a robot back in the same building knows its furniture from the first
// frame. Cells stay where they were seen when a loop closure moves keyframes.
class StaticSightings {
 public:
  struct Cell {
    int on_static = 0;
    int in_movable = 0;
    Timestamp first_static, last_static;  // the earliest and latest static sighting
  };
  // One keyframe's sightings: each cell counts once per keyframe and kind.
  void add(std::uint32_t map_id, Timestamp stamp, const std::vector<Vec3>& on_static,
           const std::vector<Vec3>& in_movable);
  bool seenStanding(std::uint32_t map_id, const Vec3& p, int min, double min_span_s) const;
  // Map `from` joined map `to`, its world moved by T_to_from (a merge).
  void moveMap(std::uint32_t from, std::uint32_t to, const SE3& T_to_from);
  std::size_t cells() const { return cells_; }
  // Each map's cells by cellKey (map files). Maps are kept apart by their
  // whole id: a map started thousands of losses into a run shares no cell
  // with the first.
  using Cells = std::unordered_map<std::uint64_t, Cell>;
  const std::unordered_map<std::uint32_t, Cells>& byMap() const { return maps_; }
  void restore(std::uint32_t map_id, const Eigen::Vector3i& cell, const Cell& c);

 private:
  // Bounded: past kMaxCells (a building's worth of surface many times over)
  // the memory starts afresh.
  static constexpr std::size_t kMaxCells = 1u << 21;
  std::unordered_map<std::uint32_t, Cells> maps_;
  std::size_t cells_ = 0;
};

class Map;
Status saveMap(const Map& map, const CameraModel& camera, const LevelInfo& levels, const std::string& path);
Status loadMap(const std::string& path, const CameraModel& camera, const LevelInfo& levels, Map* map);

class Map {
 public:
  std::shared_mutex& mutex() const { return mutex_; }

  // Keyframe ids count every keyframe ever made (freed ones included).
  std::int64_t nextKeyFrameId() const { return next_keyframe_id_; }
  KeyFrame* addKeyFrame(std::unique_ptr<KeyFrame> kf);  // ids must increase
  std::shared_ptr<MapPoint> createPoint(const Vec3& position, KeyFrame* reference);
  void erasePoint(const std::shared_ptr<MapPoint>& point);  // marks bad, drops observations
  // Culls a keyframe: it leaves the covisibility graph, the spanning tree and
  // its points' observations; its anchor is frozen relative to its parent's.
  // The object stays (others may still hold it) until releaseCulledKeyFrames().
  void setKeyFrameBad(KeyFrame* kf);
  // Frees the culled keyframes (and with them their features and their hold
  // on map points). The caller guarantees that nothing still holds a pointer
  // to one: tracking calls it under the exclusive lock after dropping its own,
  // and local mapping only culls keyframes it has processed. Returns how many.
  std::size_t releaseCulledKeyFrames();
  // The keyframe with this id, or null (never made, or culled and freed).
  KeyFrame* keyFrame(std::int64_t id) const;

  // In id order: the keyframes in the map and the culled ones not yet freed.
  const std::vector<std::unique_ptr<KeyFrame>>& keyframes() const { return keyframes_; }
  std::size_t goodKeyFrameCount() const;
  std::size_t goodKeyFrameCount(std::uint32_t map_id) const;
  // The map new keyframes join. A new map (tracking lost for too long) keeps
  // the old ones' keyframes and points; they share none with it.
  std::uint32_t activeMapId() const { return active_map_id_; }
  std::uint32_t mapsStarted() const { return maps_started_; }
  // Points of a map read from a file (adoptLoaded): they have stayed put
  // over a whole earlier run. Any thread; set before the first frame.
  bool fromLoadedMap(const MapPoint& p) const { return p.id >= 0 && p.id < loaded_points_end_; }
  bool fromLoadedMap(const KeyFrame& kf) const;
  bool hasLoadedMap() const { return loaded_points_end_ > 0; }
  // Called by tracking (exclusive lock) just before it makes a map's first
  // keyframe; the first map is 0.
  std::uint32_t beginMap();
  // Tracking goes on in map `id` (exclusive lock): the active map was moved
  // into its frame and joined it (a merge), or tracking relocalised in it and
  // the map that was active stays, as after a loss. New keyframes go to `id`,
  // and the world epoch changes.
  void activate(std::uint32_t id) {
    active_map_id_ = id;
    ++epoch_;
  }
  // Changes whenever the world frame of some keyframes moves as a whole (a
  // merge, a loop closure, a global BA's result): a bundle adjustment that
  // read poses before must not write them back, and tracking re-expresses
  // its last pose relative to its reference keyframe.
  std::uint64_t epoch() const { return epoch_; }
  void worldMoved() { ++epoch_; }  // exclusive lock
  // `by` takes over every observation of `old` (a keyframe that sees both
  // keeps `by`'s); `old` leaves the map. Exclusive lock.
  void replacePoint(const std::shared_ptr<MapPoint>& old, const std::shared_ptr<MapPoint>& by);
  // Takes over a map read from a file (map_io.cpp), exclusive lock held; this
  // map must be empty.
  void adoptLoaded(Map&& loaded);
  // Map files (map_io.cpp).
  friend Status saveMap(const Map& map, const CameraModel& camera, const LevelInfo& levels, const std::string& path);
  friend Status loadMap(const std::string& path, const CameraModel& camera, const LevelInfo& levels, Map* map);
  // Place recognition over the keyframes in the map (not culled, with a
  // KeyFrame::bow): those `accept` takes whose views share the most words
  // with `bow`, scoring at least `min_score` (features::bowScore), best
  // first, at most `max`. Shared lock.
  struct PlaceMatch {
    KeyFrame* keyframe;
    double score;
  };
  std::vector<PlaceMatch> similarKeyFrames(const features::BowVector& bow,
                                           const std::function<bool(const KeyFrame*)>& accept, double min_score,
                                           std::size_t max) const;
  // Indexes a keyframe whose bow was set after it entered the map (a loaded
  // map); exclusive lock.
  void indexKeyFrame(KeyFrame* kf);
  std::size_t pointCount() const;  // live (not bad) points
  std::size_t pointsInMemory() const;  // map points not yet freed (bad ones included)
  std::int64_t nextFrameId() { return next_frame_id_++; }
  // Where static objects and movers were seen (the semantic module): written
  // by local mapping under the exclusive lock, read under the shared one.
  StaticSightings& staticSightings() { return static_sightings_; }
  const StaticSightings& staticSightings() const { return static_sightings_; }
  // Semantic class names as small ids (Frame::movable_class), 1..255; 0 when
  // the table is full. Any thread; no map lock needed.
  std::uint8_t classId(const std::string& name);
  std::string className(std::uint8_t id) const;  // "unknown" for 0 or an unused id
  // The semantic module's progress over keyframe ids: the newest keyframe
  // sent for segmentation, and the newest whose result came back (applied,
  // failed, or its keyframe gone). Results come in keyframe order, so one
  // result also ends the wait of the keyframes the full queue dropped
  // before it. A point made by a keyframe in between awaits its mask, and
  // tracking without the geometry module keeps it out of pose fits (with
  // it, the point's probation does). Any thread; no map lock needed.
  void maskRequested(std::int64_t keyframe_id) { raiseTo(&mask_requested_, keyframe_id); }
  void maskResolved(std::int64_t keyframe_id) { raiseTo(&mask_resolved_, keyframe_id); }
  // Some keyframe was sent for segmentation: the semantic module runs.
  bool segmenting() const { return mask_requested_.load(std::memory_order_relaxed) >= 0; }
  bool awaitingMask(std::int64_t keyframe_id) const {
    return keyframe_id > mask_resolved_.load(std::memory_order_relaxed) &&
           keyframe_id <= mask_requested_.load(std::memory_order_relaxed);
  }

 private:
  static void raiseTo(std::atomic<std::int64_t>* value, std::int64_t to) {
    std::int64_t now = value->load(std::memory_order_relaxed);
    while (now < to && !value->compare_exchange_weak(now, to, std::memory_order_relaxed)) {
    }
  }
  std::atomic<std::int64_t> mask_requested_{-1}, mask_resolved_{-1};
  mutable std::mutex classes_mutex_;
  std::vector<std::string> classes_;
  mutable std::shared_mutex mutex_;
  std::vector<std::unique_ptr<KeyFrame>> keyframes_;
  std::vector<std::weak_ptr<MapPoint>> points_;  // for statistics only
  std::int64_t next_point_id_ = 0;
  std::int64_t loaded_points_end_ = 0;  // ids below these came from a map file
  std::int64_t loaded_keyframes_end_ = 0;
  std::int64_t next_keyframe_id_ = 0;
  std::int64_t next_frame_id_ = 0;
  std::uint32_t active_map_id_ = 0;
  std::uint32_t maps_started_ = 0;
  std::uint64_t epoch_ = 0;
  StaticSightings static_sightings_;
  // Word -> the keyframes in the map whose view has it.
  std::unordered_map<features::WordId, std::vector<KeyFrame*>> keyframes_by_word_;
  void unindexKeyFrame(KeyFrame* kf);
};

// How far along the view the frame's pose lies from where its depth says:
// the median of (measured - predicted depth) over the matched inliers with
// depth, in metres, and its standard error (from their median absolute
// deviation). A pose off along the view moves far points by a fraction of a
// pixel, which their reprojections cannot see; their depth can.
struct DepthOffset {
  double metres = 0;
  double standard_error = 0;
  int samples = 0;
};
DepthOffset depthOffset(const Frame& frame);
// A pose more than 5 cm along the view from where its inliers' depth puts
// it, beyond 3 standard errors, with at least 10 of them: a place found for
// the frame (relocalisation, a map merge's lookup) is refused then.
bool offAlongView(const DepthOffset& offset);

// Of the poses that several keyframes' local maps gave one lost frame, the
// one to take: among the poses that another one places within 5 cm and
// 3 degrees, the one with the most inliers (`inliers[k]` is pose k's). A
// single keyframe's pose can be wrong by much more than its inliers' spread
// when a mover pulls it; two keyframes seldom err alike. -1 when no two agree.
int agreedPlacement(const std::vector<SE3>& poses_c_w, const std::vector<int>& inliers);

}  // namespace stillpoint::slam
