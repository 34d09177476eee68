#include "map_io.hpp"

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <type_traits>
#include <unordered_map>
#include <vector>

#include "stillpoint/core/checksum.hpp"

namespace stillpoint::slam {
namespace {

constexpr char kMagic[8] = {'S', 'T', 'P', 'M', 'A', 'P', '\r', '\n'};
constexpr std::size_t kHeaderSize = 40;
constexpr int kThumbWidth = 40, kThumbHeight = 30;

class Writer {
 public:
  template <typename T>
  void put(T v) {
    static_assert(std::is_trivially_copyable_v<T>);
    const char* p = reinterpret_cast<const char*>(&v);
    bytes_.append(p, sizeof(T));
  }
  void bytes(const void* p, std::size_t n) { bytes_.append(static_cast<const char*>(p), n); }
  void pose(const SE3& T) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) put<double>(T.matrix()(r, c));
  }
  const std::string& data() const { return bytes_; }

 private:
  std::string bytes_;
};

// Bounds-checked reads: the first one past the end fails them all.
class Reader {
 public:
  Reader(const char* data, std::size_t size) : data_(data), size_(size) {}
  template <typename T>
  bool get(T* v) {
    static_assert(std::is_trivially_copyable_v<T>);
    if (size_ - pos_ < sizeof(T)) return fail();
    std::memcpy(v, data_ + pos_, sizeof(T));
    pos_ += sizeof(T);
    return true;
  }
  bool bytes(void* out, std::size_t n) {
    if (size_ - pos_ < n) return fail();
    std::memcpy(out, data_ + pos_, n);
    pos_ += n;
    return true;
  }
  bool pose(SE3* T) {
    Eigen::Matrix<double, 3, 4> m;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c)
        if (!get(&m(r, c)) || !std::isfinite(m(r, c))) return fail();
    *T = SE3::Identity();
    T->linear() = m.leftCols<3>();
    T->translation() = m.col(3);
    // A rotation, not any matrix: orthonormal within 1e-6.
    if ((T->linear().transpose() * T->linear() - Mat3::Identity()).norm() > 1e-6 || T->linear().determinant() < 0)
      return fail();
    return true;
  }
  // `count` items of at least `item_bytes` each must fit in what remains.
  bool fits(std::uint64_t count, std::size_t item_bytes) const { return count <= (size_ - pos_) / item_bytes; }
  std::size_t remaining() const { return size_ - pos_; }
  bool failed() const { return failed_; }

 private:
  bool fail() {
    failed_ = true;
    return false;
  }
  const char* data_;
  std::size_t size_;
  std::size_t pos_ = 0;
  bool failed_ = false;
};

// Bytes a keyframe's feature takes in the file.
constexpr std::size_t kFeatureBytes = 6 * 4 + 2 * 4 + 4 + 4 + 32 + 8 + 1;

}  // namespace

Status saveMap(const Map& map, const CameraModel& camera, const LevelInfo& levels, const std::string& path) {
  Writer w;
  w.put<std::int32_t>(camera.width);
  w.put<std::int32_t>(camera.height);
  for (double v : {camera.fx, camera.fy, camera.cx, camera.cy}) w.put<double>(v);
  w.put<std::int32_t>(levels.levels);
  w.put<double>(levels.scale_factor);
  w.put<double>(camera.baseline);
  for (double d : camera.dist) w.put<double>(d);
  w.put<std::int64_t>(map.next_point_id_);
  w.put<std::int64_t>(map.next_keyframe_id_);
  w.put<std::int64_t>(map.next_frame_id_);
  w.put<std::uint32_t>(map.maps_started_);
  w.put<std::uint32_t>(map.active_map_id_);

  // Points seen by a keyframe in the map (culled keyframes are not saved).
  std::vector<const MapPoint*> points;
  std::unordered_map<const MapPoint*, bool> listed;
  std::uint64_t keyframes = 0;
  for (const auto& kf : map.keyframes()) {
    if (kf->bad) continue;
    ++keyframes;
    for (const auto& p : kf->frame.points)
      if (p && !p->bad && !p->isTemporary() && listed.emplace(p.get(), true).second) points.push_back(p.get());
  }
  std::sort(points.begin(), points.end(), [](const MapPoint* a, const MapPoint* b) { return a->id < b->id; });
  w.put<std::uint64_t>(points.size());
  for (const MapPoint* p : points) {
    w.put<std::int64_t>(p->id);
    for (int k = 0; k < 3; ++k) w.put<double>(p->position[k]);
  }
  w.put<std::uint64_t>(keyframes);
  for (const auto& kf : map.keyframes()) {
    if (kf->bad) continue;
    const Frame& f = kf->frame;
    w.put<std::int64_t>(kf->id);
    w.put<std::int64_t>(f.id);
    w.put<std::uint32_t>(kf->map_id);
    w.put<std::uint8_t>(kf->origin ? 1 : 0);
    w.put<std::int64_t>(f.stamp.nanoseconds());
    w.pose(f.T_c_w);
    w.put<std::int64_t>(kf->parent && !kf->parent->bad ? kf->parent->id : -1);
    const bool thumb = f.thumbnail.rows == kThumbHeight && f.thumbnail.cols == kThumbWidth && f.thumbnail.type() == CV_32F;
    w.put<std::uint8_t>(thumb ? 1 : 0);
    if (thumb)
      for (int r = 0; r < kThumbHeight; ++r) w.bytes(f.thumbnail.ptr<float>(r), kThumbWidth * sizeof(float));
    const bool colour = static_cast<int>(f.colour.size()) == f.size();
    w.put<std::uint8_t>(colour ? 1 : 0);
    w.put<std::uint32_t>(static_cast<std::uint32_t>(f.size()));
    for (int i = 0; i < f.size(); ++i) {
      const cv::KeyPoint& k = f.keys[i];
      for (float v : {k.pt.x, k.pt.y, k.size, k.angle, k.response}) w.put<float>(v);
      w.put<std::int32_t>(k.octave);
      w.put<float>(f.un[i].x);
      w.put<float>(f.un[i].y);
      w.put<float>(f.depth[i]);
      w.put<float>(f.u_right[i]);
      w.bytes(f.descriptor(i), 32);
      const auto& p = f.points[i];
      w.put<std::int64_t>(p && !p->bad && !p->isTemporary() ? p->id : -1);
      w.put<std::uint8_t>(static_cast<std::uint8_t>(f.dynamic[i]));
      if (colour) w.bytes(&f.colour[i][0], 3);
    }
  }

  // Sightings by map and cell key, so that one map gives one file.
  const auto& maps = map.staticSightings().byMap();
  std::vector<std::pair<std::uint32_t, std::uint64_t>> keys;
  for (const auto& [map_id, cells] : maps)
    for (const auto& [k, cell] : cells) keys.emplace_back(map_id, k);
  std::sort(keys.begin(), keys.end());
  w.put<std::uint64_t>(keys.size());
  for (const auto& [map_id, k] : keys) {
    const StaticSightings::Cell& cell = maps.at(map_id).at(k);
    const Eigen::Vector3i c = cellOfKey(k);
    w.put<std::uint32_t>(map_id);
    w.put<std::int32_t>(c.x());
    w.put<std::int32_t>(c.y());
    w.put<std::int32_t>(c.z());
    w.put<std::int32_t>(cell.on_static);
    w.put<std::int32_t>(cell.in_movable);
    w.put<std::int64_t>(cell.first_static.nanoseconds());
    w.put<std::int64_t>(cell.last_static.nanoseconds());
  }

  const std::string& payload = w.data();
  Writer header;
  header.bytes(kMagic, sizeof(kMagic));
  header.put<std::uint32_t>(kMapFormatVersion);
  header.put<std::uint32_t>(0);
  header.put<std::uint64_t>(payload.size());
  header.put<std::uint64_t>(fnv1a64(payload.data(), payload.size()));
  header.put<std::uint64_t>(0);
  // Written next to the target and renamed: a crash mid-write leaves the old file.
  const std::string tmp = path + ".tmp";
  std::FILE* file = std::fopen(tmp.c_str(), "wb");
  if (!file) return Error{"cannot write the map " + path + ": " + std::strerror(errno)};
  bool ok = std::fwrite(header.data().data(), 1, header.data().size(), file) == header.data().size() &&
            std::fwrite(payload.data(), 1, payload.size(), file) == payload.size();
  ok = (std::fclose(file) == 0) && ok;
  if (!ok || std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    return Error{"cannot write the map " + path + ": " + std::strerror(errno)};
  }
  return Status::success();
}

Status loadMap(const std::string& path, const CameraModel& camera, const LevelInfo& levels, Map* map) {
  auto error = [&path](const std::string& what) { return Error{"map " + path + ": " + what}; };
  if (!map->keyframes().empty()) return error("a map can only be loaded before tracking starts");
  std::ifstream in(path, std::ios::binary);
  if (!in) return error("cannot open");
  std::string file((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) return error("read failed");
  if (file.size() < kHeaderSize) return error("truncated (" + std::to_string(file.size()) + " bytes, no header)");
  if (std::memcmp(file.data(), kMagic, sizeof(kMagic)) != 0) return error("not a stillpoint map file");
  Reader header(file.data() + sizeof(kMagic), kHeaderSize - sizeof(kMagic));
  std::uint32_t version = 0, reserved32 = 0;
  std::uint64_t payload_size = 0, checksum = 0, reserved64 = 0;
  header.get(&version);
  header.get(&reserved32);
  header.get(&payload_size);
  header.get(&checksum);
  header.get(&reserved64);
  if (version < 1 || version > kMapFormatVersion)
    return error("format version " + std::to_string(version) + ", this build reads versions 1 to " +
                 std::to_string(kMapFormatVersion));
  if (payload_size != file.size() - kHeaderSize)
    return error("truncated or padded: the header says " + std::to_string(payload_size) + " bytes of map, the file has " +
                 std::to_string(file.size() - kHeaderSize));
  const char* payload = file.data() + kHeaderSize;
  if (fnv1a64(payload, payload_size) != checksum) return error("checksum mismatch (corrupt file)");

  Reader r(payload, payload_size);
  std::int32_t width = 0, height = 0, num_levels = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0, scale = 0;
  r.get(&width);
  r.get(&height);
  r.get(&fx);
  r.get(&fy);
  r.get(&cx);
  r.get(&cy);
  r.get(&num_levels);
  r.get(&scale);
  if (r.failed()) return error("truncated camera record");
  if (width != camera.width || height != camera.height || std::abs(fx - camera.fx) > 1e-6 ||
      std::abs(fy - camera.fy) > 1e-6 || std::abs(cx - camera.cx) > 1e-6 || std::abs(cy - camera.cy) > 1e-6) {
    char text[256];
    std::snprintf(text, sizeof(text), "made with another camera (%dx%d fx %.2f fy %.2f cx %.2f cy %.2f)", width, height,
                  fx, fy, cx, cy);
    return error(text);
  }
  if (num_levels != levels.levels || std::abs(scale - levels.scale_factor) > 1e-9)
    return error("made with another ORB pyramid (" + std::to_string(num_levels) + " levels): set orb.num_levels and "
                 "orb.scale_factor as when it was made");
  if (version >= 3) {
    // The features hold depth as a right coordinate (u - fx baseline / z) and
    // undistorted positions: another baseline or lens would misread them.
    double baseline = 0;
    std::array<double, 5> dist{};
    r.get(&baseline);
    for (double& d : dist) r.get(&d);
    if (r.failed()) return error("truncated camera record");
    bool same = std::abs(baseline - camera.baseline) <= 1e-9;
    for (std::size_t k = 0; k < dist.size(); ++k) same = same && std::abs(dist[k] - camera.dist[k]) <= 1e-9;
    if (!same) {
      char text[256];
      std::snprintf(text, sizeof(text),
                    "made with another camera (baseline %.4f m, distortion %.4f %.4f %.4f %.4f %.4f)", baseline,
                    dist[0], dist[1], dist[2], dist[3], dist[4]);
      return error(text);
    }
  }
  std::int64_t next_point = 0, next_keyframe = 0, next_frame = 0;
  std::uint32_t maps_started = 0, active = 0;
  r.get(&next_point);
  r.get(&next_keyframe);
  r.get(&next_frame);
  r.get(&maps_started);
  r.get(&active);
  if (r.failed() || next_point < 0 || next_keyframe < 0 || next_frame < 0 || active >= std::max(maps_started, 1u))
    return error("bad map counters");

  std::uint64_t n_points = 0;
  if (!r.get(&n_points) || !r.fits(n_points, 8 + 24)) return error("bad point count");
  std::unordered_map<std::int64_t, std::shared_ptr<MapPoint>> points;
  points.reserve(n_points);
  for (std::uint64_t k = 0; k < n_points; ++k) {
    std::int64_t id = 0;
    Vec3 position;
    r.get(&id);
    for (int a = 0; a < 3; ++a) r.get(&position[a]);
    if (r.failed() || id < 0 || id >= next_point || !position.allFinite() || position.norm() > 1e6)
      return error("bad point " + std::to_string(k));
    auto p = std::make_shared<MapPoint>(id, position, nullptr);
    if (!points.emplace(id, p).second) return error("point id " + std::to_string(id) + " twice");
  }

  std::uint64_t n_keyframes = 0;
  if (!r.get(&n_keyframes) || !r.fits(n_keyframes, 8 + 8 + 4 + 1 + 8 + 96 + 8 + 1 + 4)) return error("bad keyframe count");
  std::vector<std::int64_t> parents;
  std::int64_t last_id = -1;
  for (std::uint64_t k = 0; k < n_keyframes; ++k) {
    const std::string which = "keyframe " + std::to_string(k) + ": ";
    std::int64_t id = 0, frame_id = 0, stamp_ns = 0, parent = -1;
    std::uint32_t map_id = 0;
    std::uint8_t origin = 0, has_thumb = 0;
    Frame f;
    r.get(&id);
    r.get(&frame_id);
    r.get(&map_id);
    r.get(&origin);
    r.get(&stamp_ns);
    if (r.failed() || id <= last_id || id >= next_keyframe || frame_id < 0 || frame_id >= next_frame ||
        map_id >= maps_started || origin > 1 || stamp_ns < 0 || stamp_ns > Timestamp::kMaxSeconds * 1'000'000'000LL)
      return error(which + "bad header");
    last_id = id;
    if (!r.pose(&f.T_c_w)) return error(which + "bad pose");
    r.get(&parent);
    r.get(&has_thumb);
    if (r.failed() || has_thumb > 1 || parent >= next_keyframe || parent < -1) return error(which + "bad parent");
    if (has_thumb) {
      f.thumbnail.create(kThumbHeight, kThumbWidth, CV_32F);
      for (int row = 0; row < kThumbHeight; ++row)
        if (!r.bytes(f.thumbnail.ptr<float>(row), kThumbWidth * sizeof(float))) return error(which + "truncated");
      if (!cv::checkRange(f.thumbnail)) return error(which + "bad thumbnail");
    }
    std::uint8_t has_colour = 0;
    std::uint32_t n = 0;
    if (!r.get(&has_colour) || has_colour > 1) return error(which + "bad colour flag");
    if (!r.get(&n) || !r.fits(n, kFeatureBytes) || n > 100000) return error(which + "bad feature count");
    if (has_colour) f.colour.resize(n);
    f.id = frame_id;
    f.stamp = Timestamp::fromNanoseconds(stamp_ns);
    f.camera = &camera;
    f.levels = &levels;
    f.keys.resize(n);
    f.un.resize(n);
    f.depth.resize(n);
    f.u_right.resize(n);
    f.descriptors.create(static_cast<int>(n), 32, CV_8U);
    f.points.assign(n, nullptr);
    f.outlier.assign(n, 0);
    f.dynamic.assign(n, kNotDynamic);
    f.cluster.assign(n, -1);
    std::vector<std::int64_t> point_ids(n);
    for (std::uint32_t i = 0; i < n; ++i) {
      cv::KeyPoint& kp = f.keys[i];
      r.get(&kp.pt.x);
      r.get(&kp.pt.y);
      r.get(&kp.size);
      r.get(&kp.angle);
      r.get(&kp.response);
      r.get(&kp.octave);
      r.get(&f.un[i].x);
      r.get(&f.un[i].y);
      r.get(&f.depth[i]);
      r.get(&f.u_right[i]);
      r.bytes(f.descriptors.ptr<std::uint8_t>(static_cast<int>(i)), 32);
      r.get(&point_ids[i]);
      std::uint8_t dynamic = 0;
      r.get(&dynamic);
      if (has_colour) r.bytes(&f.colour[i][0], 3);
      if (r.failed() || dynamic > kSemanticDynamic || kp.octave < 0 || kp.octave >= levels.levels ||
          !std::isfinite(kp.pt.x) || !std::isfinite(kp.pt.y) || !std::isfinite(f.un[i].x) ||
          !std::isfinite(f.un[i].y) || !std::isfinite(f.depth[i]) || !std::isfinite(f.u_right[i]) ||
          !std::isfinite(kp.angle) || std::abs(kp.pt.x) > 1e5 || std::abs(kp.pt.y) > 1e5 ||
          std::abs(f.un[i].x) > 1e5 || std::abs(f.un[i].y) > 1e5)
        return error(which + "bad feature " + std::to_string(i));
      f.dynamic[i] = static_cast<DynamicCause>(dynamic);
    }
    f.grid.build(f.un, camera.width, camera.height);
    auto kf = std::make_unique<KeyFrame>(id, f);
    KeyFrame* added = map->addKeyFrame(std::move(kf));
    added->map_id = map_id;
    added->origin = origin != 0;
    parents.push_back(parent);
    for (std::uint32_t i = 0; i < n; ++i) {
      if (point_ids[i] < 0) continue;
      const auto it = points.find(point_ids[i]);
      if (it == points.end()) return error(which + "feature " + std::to_string(i) + " names a point not in the file");
      if (it->second->observations.count(added)) return error(which + "two features hold one point");
      added->addObservation(it->second, static_cast<int>(i));
    }
  }
  if (version >= 2) {
    std::uint64_t n_cells = 0;
    // Versions 2 and 3 name a cell by one key: the map id from bit 54 up,
    // 18 bits per coordinate below.
    const std::size_t cell_bytes = (version >= 4 ? 4 + 3 * 4 : 8) + 4 + 4 + 8 + 8;
    if (!r.get(&n_cells) || !r.fits(n_cells, cell_bytes)) return error("bad sightings count");
    for (std::uint64_t k = 0; k < n_cells; ++k) {
      std::uint32_t map_id = 0;
      Eigen::Vector3i cell;
      if (version >= 4) {
        r.get(&map_id);
        r.get(&cell.x());
        r.get(&cell.y());
        r.get(&cell.z());
      } else {
        std::uint64_t key = 0;
        r.get(&key);
        map_id = static_cast<std::uint32_t>(key >> 54);
        const auto value = [key](int shift) {
          const int v = static_cast<int>((key >> shift) & 0x3ffff);
          return v >= (1 << 17) ? v - (1 << 18) : v;
        };
        cell = {value(36), value(18), value(0)};
      }
      std::int32_t on_static = 0, in_movable = 0;
      std::int64_t first_ns = 0, last_ns = 0;
      r.get(&on_static);
      r.get(&in_movable);
      r.get(&first_ns);
      r.get(&last_ns);
      constexpr std::int64_t kMaxNs = Timestamp::kMaxSeconds * 1'000'000'000LL;
      constexpr int kMaxCell = (1 << 20) - 1;  // cellKey's range
      if (r.failed() || map_id >= std::max(maps_started, 1u) || cell.cwiseAbs().maxCoeff() > kMaxCell ||
          on_static < 0 || in_movable < 0 || first_ns < 0 || last_ns < first_ns || last_ns > kMaxNs)
        return error("bad sighting " + std::to_string(k));
      map->staticSightings().restore(map_id, cell,
                                     StaticSightings::Cell{on_static, in_movable, Timestamp::fromNanoseconds(first_ns),
                                                           Timestamp::fromNanoseconds(last_ns)});
    }
  }
  if (r.remaining() != 0) return error(std::to_string(r.remaining()) + " bytes after the end of the map");

  // The graph: parents as saved, then covisibility; every point gets its
  // descriptor, normal and reference from its observations.
  const auto& keyframes = map->keyframes();
  for (std::size_t k = 0; k < keyframes.size(); ++k) {
    if (parents[k] < 0) continue;
    KeyFrame* parent = map->keyFrame(parents[k]);
    if (!parent || parent == keyframes[k].get() || parent->map_id != keyframes[k]->map_id)
      return error("keyframe " + std::to_string(keyframes[k]->id) + " has a bad parent");
    keyframes[k]->parent = parent;
    parent->children.push_back(keyframes[k].get());
  }
  // The parents must form a tree: a cycle would leave culling and the poses
  // expressed through culled keyframes (PoseAnchor) walking it forever.
  {
    std::unordered_map<const KeyFrame*, int> state;  // 1: on the chain being walked, 2: reaches a root
    for (const auto& kf : keyframes) {
      std::vector<const KeyFrame*> chain;
      for (const KeyFrame* a = kf.get(); a && state[a] != 2; a = a->parent) {
        if (state[a] == 1) return error("keyframe " + std::to_string(a->id) + " has a bad parent (a cycle)");
        state[a] = 1;
        chain.push_back(a);
      }
      for (const KeyFrame* a : chain) state[a] = 2;
    }
  }
  for (const auto& kf : keyframes) kf->updateConnections();
  for (auto& [id, p] : points) {
    if (p->observations.empty()) continue;
    p->reference = p->observations.begin()->first;
    p->first_keyframe_id = p->reference->id;
    p->updateFromObservations();
    map->points_.push_back(p);
  }
  map->next_point_id_ = next_point;
  map->next_keyframe_id_ = std::max(next_keyframe, map->next_keyframe_id_);
  map->next_frame_id_ = next_frame;
  map->maps_started_ = maps_started;
  map->active_map_id_ = active;
  return Status::success();
}

}  // namespace stillpoint::slam
