#include "stillpoint/synth/config.hpp"

#include <cmath>
#include <exception>
#include <filesystem>
#include <functional>
#include <map>
#include <set>

#include <yaml-cpp/yaml.h>

#include "stillpoint/core/yaml_file.hpp"

namespace stillpoint::synth {
namespace {

namespace fs = std::filesystem;

bool finite(const Vec3& v) { return v.allFinite(); }

// Strict reader: every map key must be known; errors carry file, line and field.
class Reader {
 public:
  explicit Reader(std::string path) : path_(std::move(path)) {}

  std::string where(const YAML::Node& n, const std::string& field) const {
    return "config '" + path_ + "': line " + std::to_string(n.Mark().line + 1) + ": field '" + field + "'";
  }

  Status checkKeys(const YAML::Node& map, const std::string& prefix, std::initializer_list<const char*> keys) const {
    if (!map.IsMap()) return Error{where(map, prefix) + " must be a map"};
    std::set<std::string> seen;
    for (const auto& kv : map) {
      if (!kv.first.IsScalar()) return Error{where(kv.first, prefix) + ": keys must be plain names"};
      const std::string key = kv.first.Scalar();
      if (!seen.insert(key).second)
        return Error{where(kv.first, prefix.empty() ? key : prefix + "." + key) + " is given twice"};
      bool known = false;
      for (const char* k : keys) known |= key == k;
      if (!known) return Error{where(kv.first, prefix.empty() ? key : prefix + "." + key) + " is not a known key"};
    }
    return Status::success();
  }

  template <typename T>
  Status read(const YAML::Node& map, const char* key, const std::string& field, T* out) const {
    const YAML::Node n = map[key];
    if (!n) return Status::success();
    try {
      *out = n.as<T>();
    } catch (const YAML::Exception&) {
      return Error{where(n, field) + " has the wrong type"};
    }
    return Status::success();
  }

  template <std::size_t N>
  Status readArray(const YAML::Node& map, const char* key, const std::string& field, std::array<double, N>* out) const {
    const YAML::Node n = map[key];
    if (!n) return Status::success();
    if (!n.IsSequence() || n.size() != N) return Error{where(n, field) + " must be a list of " + std::to_string(N) + " numbers"};
    try {
      for (std::size_t i = 0; i < N; ++i) (*out)[i] = n[i].as<double>();
    } catch (const YAML::Exception&) {
      return Error{where(n, field) + " must hold numbers"};
    }
    return Status::success();
  }

  Status readVec3(const YAML::Node& map, const char* key, const std::string& field, Vec3* out,
                  std::size_t min_size = 3) const {
    const YAML::Node n = map[key];
    if (!n) return Status::success();
    if (!n.IsSequence() || n.size() < min_size || n.size() > 3) {
      return Error{where(n, field) + " must be a list of " + std::to_string(min_size) +
                   (min_size == 3 ? "" : "-3") + " numbers"};
    }
    try {
      for (std::size_t i = 0; i < n.size(); ++i) (*out)[static_cast<int>(i)] = n[i].as<double>();
    } catch (const YAML::Exception&) {
      return Error{where(n, field) + " must hold numbers"};
    }
    return Status::success();
  }

 private:
  std::string path_;
};

#define SP_TRY(expr)                  \
  do {                                \
    if (Status s_ = (expr); !s_) return Error{s_.error()}; \
  } while (0)

Result<PathType> parsePathType(const std::string& s) {
  if (s == "static") return PathType::kStatic;
  if (s == "oscillate") return PathType::kOscillate;
  if (s == "walk") return PathType::kWalk;
  if (s == "stop_and_go") return PathType::kStopAndGo;
  if (s == "static_then_move") return PathType::kStaticThenMove;
  return Error{"unknown path type '" + s + "' (static, oscillate, walk, stop_and_go, static_then_move)"};
}

Result<MoverShape> parseShape(const std::string& s) {
  if (s == "poster") return MoverShape::kPoster;
  if (s == "box") return MoverShape::kBox;
  if (s == "walker") return MoverShape::kWalker;
  return Error{"unknown shape '" + s + "' (poster, box, walker)"};
}

Result<MoverSpec> readMover(const Reader& r, const YAML::Node& n, const std::string& f) {
  MoverSpec m;
  SP_TRY(r.checkKeys(n, f, {"name", "shape", "texture", "cutout", "crop", "video", "face_camera", "size", "yaw_deg", "yaw_rate_deg_s", "path"}));
  SP_TRY(r.read(n, "name", f + ".name", &m.name));
  std::string shape = "poster";
  SP_TRY(r.read(n, "shape", f + ".shape", &shape));
  Result<MoverShape> sh = parseShape(shape);
  if (!sh.ok()) return Error{r.where(n["shape"], f + ".shape") + ": " + sh.error()};
  m.shape = *sh;
  if (m.shape == MoverShape::kWalker) m.size = Vec3(0.45, 1.75, 0.25);
  SP_TRY(r.read(n, "texture", f + ".texture", &m.texture));
  SP_TRY(r.read(n, "cutout", f + ".cutout", &m.cutout));
  SP_TRY(r.readArray(n, "crop", f + ".crop", &m.crop));
  SP_TRY(r.read(n, "video", f + ".video", &m.video));
  SP_TRY(r.read(n, "face_camera", f + ".face_camera", &m.face_camera));
  SP_TRY(r.readVec3(n, "size", f + ".size", &m.size, 2));
  SP_TRY(r.read(n, "yaw_deg", f + ".yaw_deg", &m.yaw_deg));
  SP_TRY(r.read(n, "yaw_rate_deg_s", f + ".yaw_rate_deg_s", &m.yaw_rate_deg_s));
  if (const YAML::Node p = n["path"]) {
    const std::string pf = f + ".path";
    SP_TRY(r.checkKeys(p, pf, {"type", "start", "end", "speed", "period_s", "hold_s", "go_s", "stop_s", "phase_s"}));
    std::string type = "static";
    SP_TRY(r.read(p, "type", pf + ".type", &type));
    Result<PathType> pt = parsePathType(type);
    if (!pt.ok()) return Error{r.where(p["type"], pf + ".type") + ": " + pt.error()};
    m.path.type = *pt;
    SP_TRY(r.readVec3(p, "start", pf + ".start", &m.path.start));
    m.path.end = m.path.start;
    SP_TRY(r.readVec3(p, "end", pf + ".end", &m.path.end));
    SP_TRY(r.read(p, "speed", pf + ".speed", &m.path.speed_m_s));
    SP_TRY(r.read(p, "period_s", pf + ".period_s", &m.path.period_s));
    SP_TRY(r.read(p, "hold_s", pf + ".hold_s", &m.path.hold_s));
    SP_TRY(r.read(p, "go_s", pf + ".go_s", &m.path.go_s));
    SP_TRY(r.read(p, "stop_s", pf + ".stop_s", &m.path.stop_s));
    SP_TRY(r.read(p, "phase_s", pf + ".phase_s", &m.path.phase_s));
  }
  return m;
}

MoverSpec poster(const std::string& name, const std::string& tex, double w, double h, PathSpec path) {
  MoverSpec m;
  m.name = name;
  m.shape = MoverShape::kPoster;
  m.texture = tex;
  m.size = Vec3(w, h, 0.0);
  m.path = path;
  return m;
}

MoverSpec box(const std::string& name, const std::string& tex, const Vec3& size, PathSpec path,
              double yaw_rate = 0) {
  MoverSpec m;
  m.name = name;
  m.shape = MoverShape::kBox;
  m.texture = tex;
  m.size = size;
  m.path = path;
  m.yaw_rate_deg_s = yaw_rate;
  return m;
}

MoverSpec walker(const std::string& name, PathSpec path) {
  MoverSpec m;
  m.name = name;
  m.shape = MoverShape::kWalker;
  m.texture = "fabric";
  m.size = Vec3(0.45, 1.75, 0.25);
  m.path = path;
  return m;
}

PathSpec path(PathType type, const Vec3& a, const Vec3& b, double speed = 0.5) {
  PathSpec p;
  p.type = type;
  p.start = a;
  p.end = b;
  p.speed_m_s = speed;
  return p;
}

}  // namespace

Result<CameraMotion> parseCameraMotion(const std::string& name) {
  if (name == "static") return CameraMotion::kStatic;
  if (name == "xyz") return CameraMotion::kXyz;
  if (name == "rpy") return CameraMotion::kRpy;
  if (name == "halfsphere") return CameraMotion::kHalfsphere;
  if (name == "loop") return CameraMotion::kLoop;
  return Error{"unknown camera motion '" + name + "' (static, xyz, rpy, halfsphere, loop)"};
}

const char* toString(CameraMotion motion) {
  switch (motion) {
    case CameraMotion::kStatic: return "static";
    case CameraMotion::kXyz: return "xyz";
    case CameraMotion::kRpy: return "rpy";
    case CameraMotion::kHalfsphere: return "halfsphere";
    case CameraMotion::kLoop: return "loop";
  }
  return "?";
}

Status SynthConfig::validate() const {
  if (Status s = sensor.validate(); !s) return s;
  if (blur.samples < 1 || blur.samples > 64) return Error{"motion_blur.samples must be in [1, 64]"};
  if (!(blur.exposure_s >= 0 && blur.exposure_s < 1)) return Error{"motion_blur.exposure_s must be in [0, 1)"};
  if (room.frames < 1 || room.frames > 100000) return Error{"room.frames must be in [1, 100000]"};
  if (!(room.rate_hz > 0 && room.rate_hz <= 1000)) return Error{"room.rate_hz must be in (0, 1000]"};
  if (room.width < 16 || room.width > 4096) return Error{"room.width must be in [16, 4096]"};
  if (room.height < 16 || room.height > 4096) return Error{"room.height must be in [16, 4096]"};
  if (movers.size() > 1000) return Error{"movers: at most 1000"};
  for (std::size_t i = 0; i < movers.size(); ++i) {
    const MoverSpec& m = movers[i];
    const std::string f = "movers[" + std::to_string(i) + "]";
    auto bad = [&](const std::string& field, const std::string& rule) {
      return Status(Error{f + "." + field + " " + rule + " (mover '" + m.name + "')"});
    };
    const int dims = m.shape == MoverShape::kPoster ? 2 : 3;
    for (int d = 0; d < dims; ++d) {
      if (!(m.size[d] > 0.005 && m.size[d] < 20)) return bad("size", "must be in (0.005, 20) m");
    }
    if (m.texture.empty()) return bad("texture", "must not be empty");
    if (!m.cutout.empty() && m.shape != MoverShape::kPoster) return bad("cutout", "is for posters only");
    if (!m.video.empty() && m.shape != MoverShape::kPoster) return bad("video", "is for posters only");
    if (!m.video.empty() && !m.cutout.empty()) return bad("video", "cuts its own walker out: no cutout with it");
    const auto& c = m.crop;
    if (!(c[0] >= 0 && c[1] >= 0 && c[2] <= 1 && c[3] <= 1 && c[2] - c[0] >= 0.01 && c[3] - c[1] >= 0.01))
      return bad("crop", "must be [left, top, right, bottom] in [0, 1], right > left, bottom > top");
    if (m.cropped() && m.shape != MoverShape::kPoster) return bad("crop", "is for posters only");
    if (m.cropped() && !m.video.empty()) return bad("crop", "is for photos, not video");
    if (m.face_camera && m.shape != MoverShape::kPoster) return bad("face_camera", "is for posters only");
    if (!std::isfinite(m.yaw_deg)) return bad("yaw_deg", "must be finite");
    if (!std::isfinite(m.yaw_rate_deg_s)) return bad("yaw_rate_deg_s", "must be finite");
    const PathSpec& p = m.path;
    if (!finite(p.start) || !finite(p.end)) return bad("path.start/end", "must be finite");
    if ((p.end - p.start).norm() > 100) return bad("path.end", "must be within 100 m of start");
    if (!(p.speed_m_s > 0 && p.speed_m_s <= 20)) return bad("path.speed", "must be in (0, 20] m/s");
    if (!(p.period_s > 0.05 && p.period_s < 1e4)) return bad("path.period_s", "must be in (0.05, 1e4)");
    if (!(p.hold_s >= 0 && p.hold_s < 1e5)) return bad("path.hold_s", "must be in [0, 1e5)");
    if (!(p.go_s > 0.01 && p.go_s < 1e4)) return bad("path.go_s", "must be in (0.01, 1e4)");
    if (!(p.stop_s >= 0 && p.stop_s < 1e4)) return bad("path.stop_s", "must be in [0, 1e4)");
    if (!(p.phase_s >= 0 && p.phase_s < 1e4)) return bad("path.phase_s", "must be in [0, 1e4)");
  }
  return Status::success();
}

Result<SynthConfig> loadSynthConfig(const std::string& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return Error{"config '" + path + "' does not exist"};
  auto loaded = loadYamlFile(path, "config '" + path + "'");
  if (!loaded) return Error{loaded.error()};
  const YAML::Node root = *loaded;
  if (!root || root.IsNull()) return Error{"config '" + path + "' is empty"};
  SynthConfig c;
  c.base_dir = fs::absolute(fs::path(path)).parent_path().string();
  const Reader r(path);
  try {
    SP_TRY(r.checkKeys(root, "", {"seed", "movers", "sensor", "motion_blur", "room"}));
    long long seed = 1;
    SP_TRY(r.read(root, "seed", "seed", &seed));
    if (seed < 0) return Error{r.where(root["seed"], "seed") + " must be >= 0"};
    c.seed = static_cast<std::uint64_t>(seed);
    if (const YAML::Node s = root["sensor"]) {
      SP_TRY(r.checkKeys(s, "sensor", {"depth_factor", "min_depth_m", "max_depth_m", "sigma_at_1m",
                                       "edge_jump_m", "edge_dropout", "random_dropout"}));
      SP_TRY(r.read(s, "depth_factor", "sensor.depth_factor", &c.sensor.depth_factor));
      SP_TRY(r.read(s, "min_depth_m", "sensor.min_depth_m", &c.sensor.min_depth_m));
      SP_TRY(r.read(s, "max_depth_m", "sensor.max_depth_m", &c.sensor.max_depth_m));
      SP_TRY(r.read(s, "sigma_at_1m", "sensor.sigma_at_1m", &c.sensor.sigma_at_1m));
      SP_TRY(r.read(s, "edge_jump_m", "sensor.edge_jump_m", &c.sensor.edge_jump_m));
      SP_TRY(r.read(s, "edge_dropout", "sensor.edge_dropout", &c.sensor.edge_dropout));
      SP_TRY(r.read(s, "random_dropout", "sensor.random_dropout", &c.sensor.random_dropout));
    }
    if (const YAML::Node b = root["motion_blur"]) {
      SP_TRY(r.checkKeys(b, "motion_blur", {"enabled", "samples", "exposure_s"}));
      SP_TRY(r.read(b, "enabled", "motion_blur.enabled", &c.blur.enabled));
      SP_TRY(r.read(b, "samples", "motion_blur.samples", &c.blur.samples));
      SP_TRY(r.read(b, "exposure_s", "motion_blur.exposure_s", &c.blur.exposure_s));
    }
    if (const YAML::Node rm = root["room"]) {
      SP_TRY(r.checkKeys(rm, "room", {"motion", "frames", "rate_hz", "width", "height", "photos"}));
      std::string motion = toString(c.room.motion);
      SP_TRY(r.read(rm, "motion", "room.motion", &motion));
      Result<CameraMotion> cm = parseCameraMotion(motion);
      if (!cm.ok()) return Error{r.where(rm["motion"], "room.motion") + ": " + cm.error()};
      c.room.motion = *cm;
      SP_TRY(r.read(rm, "frames", "room.frames", &c.room.frames));
      SP_TRY(r.read(rm, "rate_hz", "room.rate_hz", &c.room.rate_hz));
      SP_TRY(r.read(rm, "width", "room.width", &c.room.width));
      SP_TRY(r.read(rm, "height", "room.height", &c.room.height));
      SP_TRY(r.read(rm, "photos", "room.photos", &c.room.photos));
    }
    if (const YAML::Node ms = root["movers"]) {
      if (!ms.IsSequence()) return Error{r.where(ms, "movers") + " must be a list"};
      for (std::size_t i = 0; i < ms.size(); ++i) {
        Result<MoverSpec> m = readMover(r, ms[i], "movers[" + std::to_string(i) + "]");
        if (!m.ok()) return Error{m.error()};
        c.movers.push_back(*m);
      }
    }
  } catch (const YAML::Exception& e) {
    return Error{"config '" + path + "': " + e.what()};
  }
  if (Status s = c.validate(); !s) return Error{"config '" + path + "': " + s.error()};
  return c;
}

std::vector<std::string> presetNames() {
  return {"poster-walk", "poster-oscillate", "poster-static-then-move", "poster-big", "book",
          "chair-push", "walker", "mix", "room-walker", "room-walker-near", "room-walkers", "room-static"};
}

Result<SynthConfig> synthPreset(const std::string& name, const std::string& photo_dir) {
  auto photo = [&](const std::string& file, const std::string& fallback) {
    const fs::path p = fs::path(photo_dir) / file;
    std::error_code ec;
    return fs::is_regular_file(p, ec) ? p.string() : fallback;
  };
  const std::string astronaut = photo("astronaut.png", "paper");
  const std::string coffee = photo("coffee.png", "paper");
  SynthConfig c;
  using enum PathType;
  // Overlay presets are laid out for tum_fr3_teddy_200 (camera 1.5 m above the
  // floor looking ~23 deg down at a teddy about 1.7 m ahead).
  const MoverSpec walk_poster = poster("person_poster", astronaut, 0.7, 1.0,
                                       path(kWalk, {-0.9, 1.3, 1.0}, {0.9, 1.3, 1.0}, 0.45));
  const MoverSpec book_box = [&] {
    PathSpec p = path(kOscillate, {-0.25, 0.9, 1.05}, {0.25, 1.0, 1.25});
    p.period_s = 2.5;
    return box("book", coffee, {0.24, 0.3, 0.05}, p, 40.0);
  }();
  const MoverSpec chair = [&] {
    PathSpec p = path(kStopAndGo, {-0.7, 1.5, 0.45}, {0.7, 1.5, 0.45}, 0.35);
    p.go_s = 1.2;
    p.stop_s = 0.8;
    return box("chair", "wood", {0.5, 0.9, 0.5}, p, 10.0);
  }();
  if (name == "poster-walk") {
    c.movers = {walk_poster};
  } else if (name == "poster-oscillate") {
    PathSpec p = path(kOscillate, {-0.45, 1.2, 1.0}, {0.45, 1.2, 1.0});
    p.period_s = 3.0;
    c.movers = {poster("person_poster", astronaut, 0.6, 0.9, p)};
  } else if (name == "poster-static-then-move") {
    PathSpec p = path(kStaticThenMove, {0.1, 1.2, 1.0}, {-1.2, 1.2, 1.0}, 0.5);
    p.hold_s = 3.0;
    c.movers = {poster("person_poster", astronaut, 0.7, 1.0, p)};
  } else if (name == "poster-big") {
    PathSpec p = path(kOscillate, {-0.3, 0.85, 1.0}, {0.3, 0.85, 1.0});
    p.period_s = 4.0;
    c.movers = {poster("person_poster", astronaut, 1.0, 1.3, p)};
  } else if (name == "book") {
    c.movers = {book_box};
  } else if (name == "chair-push") {
    c.movers = {chair};
  } else if (name == "walker") {
    // Walks to and fro on the right of the teddy, clear of the camera's arc on the left.
    c.movers = {walker("walker", path(kWalk, {1.0, 0.7, 0.0}, {0.5, 2.4, 0.0}, 0.6))};
  } else if (name == "mix") {
    c.movers = {walk_poster, book_box, chair};
  } else if (name == "room-walker") {
    c.movers = {walker("walker", path(kWalk, {-1.8, 2.3, 0.0}, {1.8, 2.3, 0.0}, 0.7))};
  } else if (name == "room-walker-near") {
    c.movers = {walker("walker", path(kWalk, {-1.4, 1.3, 0.0}, {1.4, 1.3, 0.0}, 0.6))};
  } else if (name == "room-walkers") {
    PathSpec p2 = path(kStopAndGo, {1.5, 3.2, 0.0}, {-1.5, 2.6, 0.0}, 0.6);
    p2.go_s = 2.0;
    p2.stop_s = 1.0;
    PathSpec pb = path(kOscillate, {-0.5, 1.6, 1.1}, {0.3, 1.8, 1.3});
    pb.period_s = 3.0;
    c.movers = {walker("walker_a", path(kWalk, {-1.8, 2.3, 0.0}, {1.8, 2.3, 0.0}, 0.7)),
                walker("walker_b", p2), box("book", coffee, {0.24, 0.3, 0.05}, pb, 40.0)};
  } else if (name == "room-static") {
    c.movers = {};
  } else {
    std::string list;
    for (const std::string& n : presetNames()) list += (list.empty() ? "" : ", ") + n;
    return Error{"unknown preset '" + name + "' (" + list + ")"};
  }
  if (name.rfind("room-", 0) == 0) {
    for (const char* f : {"astronaut.png", "coffee.png"}) {
      const std::string p = photo(f, "");
      if (!p.empty()) c.room.photos.push_back(p);
    }
  }
  if (Status s = c.validate(); !s) return Error{"preset '" + name + "': " + s.error()};
  return c;
}

}  // namespace stillpoint::synth
