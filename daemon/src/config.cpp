#include "config.hpp"

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <set>
#include <sstream>

#include <yaml-cpp/yaml.h>

#include "stillpoint/core/yaml_file.hpp"
#include "stillpoint/core/log.hpp"

namespace stillpoint::daemon {
namespace {

// Reads one map section: remembers which keys were read so the rest can be
// reported as unknown, and turns yaml-cpp type errors into messages with the
// field and line.
class Section {
 public:
  Section(const YAML::Node& node, std::string prefix, std::string* error)
      : node_(node), prefix_(std::move(prefix)), error_(error) {}

  std::string field(const std::string& key) const { return prefix_.empty() ? key : prefix_ + "." + key; }

  // Present and not null?
  bool has(const std::string& key) {
    known_.insert(key);
    if (!node_.IsMap()) return false;
    const YAML::Node v = node_[key];
    return v.IsDefined() && !v.IsNull();
  }
  YAML::Node get(const std::string& key) { return has(key) ? node_[key] : YAML::Node(); }

  template <typename T>
  void read(const std::string& key, T* out) {
    if (!error_->empty() || !has(key)) return;
    const YAML::Node v = node_[key];
    try {
      if (!v.IsScalar()) throw YAML::Exception(v.Mark(), "");
      *out = v.as<T>();
    } catch (const YAML::Exception&) {
      fail(v, key, "has the wrong type");
    }
  }

  void fail(const YAML::Node& at, const std::string& key, const std::string& what) {
    if (error_->empty()) *error_ = "line " + std::to_string(at.Mark().line + 1) + ": field '" + field(key) + "' " + what;
  }
  // Call after every read: names the first key nobody asked for.
  // Keys that are not plain names and keys given twice are errors too
  // (yaml-cpp would keep the first silently).
  void checkUnknown() {
    if (!error_->empty() || !node_.IsMap()) return;
    std::set<std::string> seen;
    for (const auto& kv : node_) {
      const std::string line = "line " + std::to_string(kv.first.Mark().line + 1);
      if (!kv.first.IsScalar()) {
        *error_ = line + ": keys must be plain names";
        return;
      }
      const std::string key = kv.first.Scalar();
      if (!seen.insert(key).second) {
        *error_ = line + ": duplicate field '" + field(key) + "'";
        return;
      }
      if (!known_.count(key)) {
        *error_ = "line " + std::to_string(kv.first.Mark().line + 1) + ": unknown field '" + field(key) + "'";
        return;
      }
    }
  }
  const YAML::Node& node() const { return node_; }

 private:
  YAML::Node node_;
  std::string prefix_;
  std::string* error_;
  std::set<std::string> known_;
};

// A map section, or an error when the key holds something else.
bool subsection(Section& parent, const std::string& key, YAML::Node* out, std::string* error) {
  *out = parent.get(key);
  if (!error->empty()) return false;
  if (out->IsDefined() && !out->IsNull() && !out->IsMap()) {
    parent.fail(*out, key, "must be a mapping");
    return false;
  }
  return true;
}

void readPlacement(Section& threads, const std::string& name, ThreadPlacement* p, std::string* error) {
  YAML::Node node;
  if (!subsection(threads, name, &node, error) || !node.IsDefined() || node.IsNull()) return;
  Section s(node, threads.field(name), error);
  if (s.has("cores")) {
    const YAML::Node cores = node["cores"];
    if (!cores.IsSequence()) return s.fail(cores, "cores", "must be a list of core numbers, e.g. [2, 3]");
    p->cores.clear();
    for (const auto& c : cores) {
      try {
        const int core = c.as<int>();
        if (core < 0 || core > 1023) return s.fail(c, "cores", "holds " + std::to_string(core) + ": expected 0..1023");
        p->cores.push_back(core);
      } catch (const YAML::Exception&) {
        return s.fail(c, "cores", "must be a list of core numbers, e.g. [2, 3]");
      }
    }
  }
  s.read("priority", &p->priority);
  if (error->empty() && (p->priority < 0 || p->priority > 99))
    s.fail(node["priority"], "priority", "must be 0 (normal scheduling) or a SCHED_FIFO priority 1..99");
  s.read("nice", &p->nice);
  if (error->empty() && (p->nice < -20 || p->nice > 19))
    s.fail(node["nice"], "nice", "must be a nice value -20..19 (0: inherited)");
  s.checkUnknown();
}

void readStringList(Section& parent, const std::string& key, std::vector<std::string>* out, std::string* error) {
  if (!error->empty() || !parent.has(key)) return;
  const YAML::Node list = parent.node()[key];
  if (!list.IsSequence()) return parent.fail(list, key, "must be a list of folders, e.g. [/usr/share/stillpoint/models]");
  out->clear();
  for (const auto& item : list) {
    if (!item.IsScalar()) return parent.fail(item, key, "must be a list of folders, e.g. [/usr/share/stillpoint/models]");
    out->push_back(item.as<std::string>());
  }
}

// loadSlamOptions() reads files only: hand it the inline section through a
// private temporary file, and put our field path into its messages.
Result<slam::SlamOptions> inlineSlamOptions(const YAML::Node& node) {
  char tmpl[] = "/tmp/stillpointd-slam-XXXXXX";
  const int fd = ::mkstemp(tmpl);
  if (fd < 0) return Error{"cannot create a temporary file for slam.options"};
  YAML::Emitter out;
  out << node;
  const std::string text = std::string(out.c_str()) + "\n";
  const bool written = ::write(fd, text.data(), text.size()) == static_cast<ssize_t>(text.size());
  ::close(fd);
  if (!written) {
    ::unlink(tmpl);
    return Error{"cannot write a temporary file for slam.options"};
  }
  auto loaded = slam::loadSlamOptions(tmpl);
  ::unlink(tmpl);
  if (loaded) return loaded;
  std::string message = loaded.error();
  const std::string prefix = "config '" + std::string(tmpl) + "': ";
  if (message.rfind(prefix, 0) == 0) message = message.substr(prefix.size());
  // Lines refer to the emitted copy, not the daemon file: keep only the field.
  if (message.rfind("line ", 0) == 0) {
    const auto colon = message.find(": ");
    if (colon != std::string::npos) message = message.substr(colon + 2);
  }
  return Error{"slam.options: " + message};
}

Status parse(const YAML::Node& root, DaemonConfig* c, std::string* error) {
  Section top(root, "", error);
  top.read("camera", &c->camera_spec);
  top.read("log_level", &c->log_level);
  top.read("shutdown_timeout_s", &c->shutdown_timeout_s);
  top.read("status_period_s", &c->status_period_s);
  top.read("lock_memory", &c->lock_memory);

  YAML::Node node;
  if (subsection(top, "source", &node, error) && node.IsDefined()) {
    Section s(node, "source", error);
    s.read("type", &c->source.type);
    s.read("queue_capacity", &c->source.queue_capacity);
    YAML::Node replay;
    if (subsection(s, "replay", &replay, error) && replay.IsDefined()) {
      Section r(replay, "source.replay", error);
      r.read("path", &c->source.replay.path);
      r.read("paced", &c->source.replay.paced);
      r.read("loop", &c->source.replay.loop);
      r.read("max_frames", &c->source.replay.max_frames);
      r.read("as_live", &c->source.replay.as_live);
      r.checkUnknown();
    }
    YAML::Node oni;
    if (subsection(s, "openni2", &oni, error) && oni.IsDefined()) {
      Section o(oni, "source.openni2", error);
      o.read("uri", &c->source.openni2.uri);
      o.checkUnknown();
    }
    YAML::Node v4l2;
    if (subsection(s, "v4l2", &v4l2, error) && v4l2.IsDefined()) {
      Section v(v4l2, "source.v4l2", error);
      platform::V4l2SourceOptions& o = c->source.v4l2;
      v.read("colour_device", &o.colour_device);
      v.read("depth_device", &o.depth_device);
      v.read("width", &o.width);
      v.read("height", &o.height);
      v.read("fps", &o.fps);
      v.read("depth_scale", &o.depth_scale);
      v.read("pair_tolerance_ms", &o.pair_tolerance_ms);
      v.read("depth_registered", &o.depth_registered);
      v.checkUnknown();
    }
    s.checkUnknown();
  }
  YAML::Node slam_inline;
  if (subsection(top, "slam", &node, error) && node.IsDefined()) {
    Section s(node, "slam", error);
    s.read("options_file", &c->slam_options_file);
    if (error->empty() && s.has("options")) {
      slam_inline = node["options"];
      if (!slam_inline.IsMap()) s.fail(slam_inline, "options", "must be a mapping (the layout of config/slam.yaml)");
      else if (!c->slam_options_file.empty())
        s.fail(slam_inline, "options", "and slam.options_file are exclusive: use one");
    }
    s.checkUnknown();
  }
  if (subsection(top, "modules", &node, error) && node.IsDefined()) {
    Section s(node, "modules", error);
    s.read("geometry", &c->modules.geometry);
    s.read("semantic", &c->modules.semantic);
    s.read("semantic_model_card", &c->modules.semantic_model_card);
    readStringList(s, "semantic_model_dirs", &c->modules.semantic_model_dirs, error);
    s.checkUnknown();
  }
  if (subsection(top, "threads", &node, error) && node.IsDefined()) {
    Section s(node, "threads", error);
    readPlacement(s, "source", &c->threads.source, error);
    readPlacement(s, "tracking", &c->threads.tracking, error);
    readPlacement(s, "mapping", &c->threads.mapping, error);
    readPlacement(s, "publisher", &c->threads.publisher, error);
    readPlacement(s, "semantic", &c->threads.semantic, error);
    s.checkUnknown();
  }
  if (subsection(top, "map", &node, error) && node.IsDefined()) {
    Section s(node, "map", error);
    s.read("load", &c->map.load);
    s.read("save", &c->map.save);
    std::string mode = "slam";
    s.read("mode", &mode);
    if (error->empty() && mode != "slam" && mode != "localisation")
      *error = "field 'map.mode': expected slam or localisation, got '" + mode + "'";
    c->map.localisation = mode == "localisation";
    s.checkUnknown();
  }
  if (subsection(top, "output", &node, error) && node.IsDefined()) {
    Section s(node, "output", error);
    s.read("trajectory", &c->output.trajectory);
    s.read("status", &c->output.status);
    s.checkUnknown();
  }
  if (error->empty() && top.has("ipc")) {
    auto ipc = ipc::parseIpcOptions(root["ipc"]);
    if (!ipc) *error = "ipc: " + ipc.error();
    else c->ipc = *ipc;
  }
  top.checkUnknown();
  if (!error->empty()) return Error{*error};

  // Values, now that every key is known.
  log::Level level;
  if (!log::parseLevel(c->log_level, &level))
    return Error{"field 'log_level': '" + c->log_level + "' is not one of debug, info, warn, error, off"};
  if (!(c->shutdown_timeout_s > 0 && c->shutdown_timeout_s <= 300))
    return Error{"field 'shutdown_timeout_s': must be in (0, 300] seconds"};
  if (c->map.localisation && c->map.load.empty())
    return Error{"field 'map.mode': localisation needs a map to track against (map.load)"};
  if (!(c->status_period_s >= 0.05 && c->status_period_s <= 60))
    return Error{"field 'status_period_s': must be in [0.05, 60] seconds"};
  if (c->source.type != "replay" && c->source.type != "openni2" && c->source.type != "v4l2")
    return Error{"field 'source.type': '" + c->source.type + "' is not one of replay, openni2, v4l2"};
  if (c->source.queue_capacity < 1 || c->source.queue_capacity > 256)
    return Error{"field 'source.queue_capacity': must be 1..256"};
  if (c->source.type == "replay" && c->source.replay.path.empty())
    return Error{"field 'source.replay.path': required for source.type replay (a TUM-layout folder)"};

  auto camera = loadCamera(c->camera_spec);
  if (!camera) return Error{"field 'camera': " + camera.error()};
  c->camera = *camera;
  if (c->source.type == "v4l2") {
    if (Status s = c->source.v4l2.validate(); !s) {
      // "source.v4l2.x: message" -> "field 'source.v4l2.x': message"
      const std::string& m = s.error();
      const auto colon = m.find(": ");
      return Error{"field '" + m.substr(0, colon) + "': " + m.substr(colon + 2)};
    }
    if (c->source.v4l2.width != c->camera.width || c->source.v4l2.height != c->camera.height)
      return Error{"field 'source.v4l2.width': " + std::to_string(c->source.v4l2.width) + "x" +
                   std::to_string(c->source.v4l2.height) + " differs from the camera's " +
                   std::to_string(c->camera.width) + "x" + std::to_string(c->camera.height) + " (field 'camera')"};
  }

  if (!c->slam_options_file.empty()) {
    auto loaded = slam::loadSlamOptions(c->slam_options_file);
    if (!loaded) return Error{"field 'slam.options_file': " + loaded.error()};
    c->slam = *loaded;
  } else if (slam_inline.IsDefined()) {
    auto loaded = inlineSlamOptions(slam_inline);
    if (!loaded) return Error{loaded.error()};
    c->slam = *loaded;
  }
  c->slam.geometry.enabled = c->modules.geometry;
  c->slam.semantic.enabled = c->modules.semantic;
  c->slam.localisation = c->map.localisation;
  // Per-frame poses are kept only for a trajectory file: without one the
  // daemon's memory does not grow with its running time.
  if (c->output.trajectory.empty()) c->slam.tracking.trajectory_records = 0;
  if (!c->modules.semantic_model_card.empty()) c->slam.semantic.model_card = c->modules.semantic_model_card;
  if (!c->modules.semantic_model_dirs.empty()) c->slam.semantic.model_dirs = c->modules.semantic_model_dirs;
  if (c->modules.semantic) {
    // The card and its model file now; the network itself loads (and is
    // checked by a warm-up inference) when the daemon starts.
    std::string field = "modules.semantic_model_card", context;
    if (c->modules.semantic_model_card.empty() && !c->slam.semantic.model_card.empty()) {
      if (c->slam_options_file.empty()) field = "slam.options.semantic.model_card";
      else field = "slam.options_file", context = "semantic.model_card: ";
    }
    auto model = slam::checkSemanticModel(c->slam.semantic);
    if (!model) {
      std::string message = model.error();
      const std::string own = "semantic.model_card: ";
      if (message.rfind(own, 0) == 0) message = message.substr(own.size());
      if (c->slam.semantic.model_card.empty()) context = "no card given and the recommended model is not usable: ";
      return Error{"field '" + field + "': " + context + message};
    }
    c->semantic_model = *model;
    // Keyframes are segmented in colour: every source delivers BGR too.
    c->source.replay.colour = true;
    c->source.openni2.colour = true;
    c->source.v4l2.colour = true;
  }
  if (Status s = c->ipc.validate(); !s) return Error{"ipc: " + s.error()};
  return {};
}

void emitPlacement(YAML::Emitter& out, const char* name, const ThreadPlacement& p) {
  out << YAML::Key << name << YAML::Value << YAML::Flow << YAML::BeginMap;
  out << YAML::Key << "cores" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (int c : p.cores) out << c;
  out << YAML::EndSeq << YAML::Key << "priority" << YAML::Value << p.priority;
  out << YAML::Key << "nice" << YAML::Value << p.nice << YAML::EndMap;
}

}  // namespace

Result<DaemonConfig> loadDaemonConfig(const std::string& path) {
  auto loaded = loadYamlFile(path, path);
  if (!loaded) return Error{loaded.error()};
  const YAML::Node root = *loaded;
  if (!root.IsMap()) return Error{path + ": expected a mapping at the top level"};
  DaemonConfig config;
  std::string error;
  try {
    if (Status s = parse(root, &config, &error); !s) return Error{path + ": " + s.error()};
  } catch (const YAML::Exception& e) {
    return Error{path + ": " + yamlErrorText(e)};
  }
  return config;
}

std::string toYaml(const DaemonConfig& c) {
  YAML::Emitter out;
  out << YAML::BeginMap;
  out << YAML::Key << "camera" << YAML::Value << c.camera_spec;
  out << YAML::Key << "log_level" << YAML::Value << c.log_level;
  out << YAML::Key << "shutdown_timeout_s" << YAML::Value << c.shutdown_timeout_s;
  out << YAML::Key << "status_period_s" << YAML::Value << c.status_period_s;
  out << YAML::Key << "lock_memory" << YAML::Value << c.lock_memory;
  out << YAML::Key << "source" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "type" << YAML::Value << c.source.type;
  out << YAML::Key << "queue_capacity" << YAML::Value << c.source.queue_capacity;
  out << YAML::Key << "replay" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "path" << YAML::Value << c.source.replay.path;
  out << YAML::Key << "paced" << YAML::Value << c.source.replay.paced;
  out << YAML::Key << "loop" << YAML::Value << c.source.replay.loop;
  out << YAML::Key << "max_frames" << YAML::Value << c.source.replay.max_frames;
  out << YAML::Key << "as_live" << YAML::Value << c.source.replay.as_live;
  out << YAML::EndMap;
  out << YAML::Key << "openni2" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "uri" << YAML::Value << YAML::DoubleQuoted << c.source.openni2.uri;
  out << YAML::EndMap;
  const platform::V4l2SourceOptions& v = c.source.v4l2;
  out << YAML::Key << "v4l2" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "colour_device" << YAML::Value << YAML::DoubleQuoted << v.colour_device;
  out << YAML::Key << "depth_device" << YAML::Value << YAML::DoubleQuoted << v.depth_device;
  out << YAML::Key << "width" << YAML::Value << v.width;
  out << YAML::Key << "height" << YAML::Value << v.height;
  out << YAML::Key << "fps" << YAML::Value << v.fps;
  out << YAML::Key << "depth_scale" << YAML::Value << v.depth_scale;
  out << YAML::Key << "pair_tolerance_ms" << YAML::Value << v.pair_tolerance_ms;
  out << YAML::Key << "depth_registered" << YAML::Value << v.depth_registered;
  out << YAML::EndMap << YAML::EndMap;
  out << YAML::Key << "modules" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "geometry" << YAML::Value << c.modules.geometry;
  out << YAML::Key << "semantic" << YAML::Value << c.modules.semantic;
  out << YAML::Key << "semantic_model_card" << YAML::Value << YAML::DoubleQuoted << c.modules.semantic_model_card;
  out << YAML::Key << "semantic_model_dirs" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (const auto& d : c.modules.semantic_model_dirs) out << d;
  out << YAML::EndSeq;
  out << YAML::EndMap;
  out << YAML::Key << "threads" << YAML::Value << YAML::BeginMap;
  emitPlacement(out, "source", c.threads.source);
  emitPlacement(out, "tracking", c.threads.tracking);
  emitPlacement(out, "mapping", c.threads.mapping);
  emitPlacement(out, "publisher", c.threads.publisher);
  emitPlacement(out, "semantic", c.threads.semantic);
  out << YAML::EndMap;
  out << YAML::Key << "map" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "load" << YAML::Value << c.map.load;
  out << YAML::Key << "save" << YAML::Value << c.map.save;
  out << YAML::Key << "mode" << YAML::Value << (c.map.localisation ? "localisation" : "slam");
  out << YAML::EndMap;
  out << YAML::Key << "output" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "trajectory" << YAML::Value << c.output.trajectory;
  out << YAML::Key << "status" << YAML::Value << c.output.status;
  out << YAML::EndMap;
  const auto& i = c.ipc;
  out << YAML::Key << "ipc" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "queue_capacity" << YAML::Value << i.queue_capacity;
  out << YAML::Key << "shm" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "enabled" << YAML::Value
      << i.shm.enabled << YAML::Key << "name" << YAML::Value << i.shm.name << YAML::Key << "capacity" << YAML::Value
      << i.shm.capacity << YAML::EndMap;
  out << YAML::Key << "lcm" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "enabled" << YAML::Value
      << i.lcm.enabled << YAML::Key << "url" << YAML::Value << i.lcm.url << YAML::Key << "pose_channel"
      << YAML::Value << i.lcm.pose_channel << YAML::Key << "status_channel" << YAML::Value << i.lcm.status_channel
      << YAML::EndMap;
  out << YAML::Key << "dds" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "enabled" << YAML::Value
      << i.dds.enabled << YAML::Key << "domain_id" << YAML::Value << i.dds.domain_id << YAML::Key << "config"
      << YAML::Value << YAML::DoubleQuoted << i.dds.config << YAML::Key << "pose_topic" << YAML::Value
      << i.dds.pose_topic << YAML::Key << "status_topic" << YAML::Value << i.dds.status_topic << YAML::EndMap;
  out << YAML::EndMap;
  out << YAML::EndMap;
  // The effective SLAM options, in full, as an inline section.
  std::string text = std::string(out.c_str()) + "\nslam:\n  options:\n";
  std::istringstream slam_yaml(slam::toYaml(c.slam));
  for (std::string line; std::getline(slam_yaml, line);)
    if (!line.empty() && line[0] != '#') text += "    " + line + "\n";
  return text;
}

}  // namespace stillpoint::daemon
