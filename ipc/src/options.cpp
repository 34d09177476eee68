#include "stillpoint/ipc/options.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <set>
#include <vector>

#include "stillpoint/core/yaml_file.hpp"

namespace stillpoint::ipc {

namespace {

// A shared-memory object name: 1-200 characters from [A-Za-z0-9._-], not
// starting with '.'.
bool ringName(const std::string& name) {
  return !name.empty() && name.size() <= 200 && name[0] != '.' &&
         name.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789._-") ==
             std::string::npos;
}

// ROS 2 maps topic /a/b to DDS topic rt/a/b.
bool ros2TopicForm(const std::string& topic) { return topic.rfind("rt/", 0) == 0 && topic.size() >= 4; }

}  // namespace

Status IpcOptions::validate() const {
  if (queue_capacity < 1 || queue_capacity > 4096) return Error{"ipc.queue_capacity must be in [1, 4096]"};
  if (shm.capacity < 2 || shm.capacity > (1u << 20) || (shm.capacity & (shm.capacity - 1)) != 0)
    return Error{"ipc.shm.capacity must be a power of two in [2, 1048576]"};
  if (!ringName(shm.name))
    return Error{"ipc.shm.name must be 1-200 characters from [A-Za-z0-9._-], not starting with '.'"};
  if (lcm.url.empty()) return Error{"ipc.lcm.url must not be empty"};
  if (lcm.pose_channel.empty() || lcm.status_channel.empty() || lcm.pose_channel == lcm.status_channel)
    return Error{"ipc.lcm.pose_channel and ipc.lcm.status_channel must be non-empty and differ"};
  // Cyclone accepts domain ids 0..230 (the RTPS port mapping overflows beyond).
  if (dds.domain_id > 230) return Error{"ipc.dds.domain_id must be in [0, 230]"};
  if (dds.pose_topic.empty() || dds.status_topic.empty() || dds.pose_topic == dds.status_topic)
    return Error{"ipc.dds.pose_topic and ipc.dds.status_topic must be non-empty and differ"};
  if (ros2.domain_id > 230) return Error{"ipc.ros2.domain_id must be in [0, 230]"};
  if (!ros2TopicForm(ros2.pose_topic))
    return Error{"ipc.ros2.pose_topic must be a DDS topic name of ROS 2's form, rt/<name> (ROS 2 topic /<name>)"};
  if (ros2.frame_id.empty()) return Error{"ipc.ros2.frame_id must not be empty"};
  for (const auto& [key, topic] : {std::pair<const char*, const std::string*>{"odometry_topic", &ros2.odometry_topic},
                                   {"tf_topic", &ros2.tf_topic},
                                   {"diagnostics_topic", &ros2.diagnostics_topic},
                                   {"objects_topic", &ros2.objects_topic},
                                   {"map_cloud_topic", &ros2.map_cloud_topic}})
    if (!topic->empty() && !ros2TopicForm(*topic))
      return Error{std::string("ipc.ros2.") + key + " must be empty (off) or of ROS 2's form, rt/<name>"};
  if (ros2.child_frame_id.empty() || ros2.child_frame_id == ros2.frame_id)
    return Error{"ipc.ros2.child_frame_id must be set and differ from frame_id"};
  if (!(ros2.map_cloud_period_s >= 0.1 && ros2.map_cloud_period_s <= 3600))
    return Error{"ipc.ros2.map_cloud_period_s must be in [0.1, 3600]"};
  {
    double n2 = 0;
    for (int k = 0; k < 7; ++k) {
      if (!std::isfinite(ros2.camera_extrinsic[k])) return Error{"ipc.ros2.camera_extrinsic must be finite"};
      if (k >= 3) n2 += ros2.camera_extrinsic[k] * ros2.camera_extrinsic[k];
    }
    if (std::abs(std::sqrt(n2) - 1.0) > 1e-3)
      return Error{"ipc.ros2.camera_extrinsic's quaternion (qx qy qz qw) must have unit norm, has " +
                   std::to_string(std::sqrt(n2))};
  }
  if (const std::string ring = shm.objectsRing(); !ring.empty() && (ring == shm.name || !ringName(ring)))
    return Error{"ipc.shm.objects_name ('" + ring +
                 "') must be 1-200 characters from [A-Za-z0-9._-], not starting with '.', and differ from "
                 "ipc.shm.name"};
  if (!lcm.objects_channel.empty() &&
      (lcm.objects_channel == lcm.pose_channel || lcm.objects_channel == lcm.status_channel))
    return Error{"ipc.lcm.objects_channel must differ from the pose and status channels"};
  if (!dds.objects_topic.empty() && (dds.objects_topic == dds.pose_topic || dds.objects_topic == dds.status_topic))
    return Error{"ipc.dds.objects_topic must differ from the pose and status topics"};
  return Status::success();
}

namespace {

struct Reader {
  const YAML::Node& node;
  std::string prefix;
  std::set<std::string> known;
  std::string error;

  template <typename T>
  void get(const std::string& key, T& field) {
    known.insert(key);
    if (!error.empty()) return;
    const YAML::Node v = node[key];
    if (!v.IsDefined() || v.IsNull()) return;
    try {
      field = v.as<T>();
    } catch (const YAML::Exception&) {
      error = "line " + std::to_string(v.Mark().line + 1) + ": field '" + prefix + key + "' has the wrong type";
    }
  }
  // Unknown keys are errors: a typo must not silently fall back to a default.
  // So are keys that are not plain names, and keys given twice (yaml-cpp
  // would keep the first silently).
  void checkUnknown() {
    if (!error.empty()) return;
    std::set<std::string> seen;
    for (const auto& kv : node) {
      const std::string line = "line " + std::to_string(kv.first.Mark().line + 1);
      if (!kv.first.IsScalar()) {
        error = line + ": keys of '" + prefix + "' must be plain names";
        return;
      }
      const std::string key = kv.first.Scalar();
      if (!seen.insert(key).second) {
        error = line + ": duplicate field '" + prefix + key + "'";
        return;
      }
      if (!known.count(key)) {
        error = "line " + std::to_string(kv.first.Mark().line + 1) + ": unknown field '" + prefix + key + "'";
        return;
      }
    }
  }
};

Status section(const YAML::Node& parent, const std::string& key, const std::string& prefix,
               const std::function<void(Reader&)>& fields) {
  const YAML::Node node = parent[key];
  if (!node.IsDefined() || node.IsNull()) return Status::success();
  if (!node.IsMap()) return Error{"line " + std::to_string(node.Mark().line + 1) + ": '" + prefix + "' must be a map"};
  Reader r{node, prefix + ".", {}, {}};
  fields(r);
  r.checkUnknown();
  if (!r.error.empty()) return Error{r.error};
  return Status::success();
}

}  // namespace

Result<IpcOptions> parseIpcOptions(const YAML::Node& node) {
  IpcOptions o;
  if (!node.IsDefined() || node.IsNull()) return o;
  if (!node.IsMap()) return Error{"'ipc' must be a map"};
  Reader top{node, "ipc.", {"shm", "lcm", "dds", "ros2"}, {}};
  top.get("queue_capacity", o.queue_capacity);
  top.checkUnknown();
  if (!top.error.empty()) return Error{top.error};
  Status s = section(node, "shm", "ipc.shm", [&](Reader& r) {
    r.get("enabled", o.shm.enabled);
    r.get("name", o.shm.name);
    r.get("capacity", o.shm.capacity);
    r.get("objects", o.shm.objects);
    r.get("objects_name", o.shm.objects_name);
  });
  if (s) s = section(node, "lcm", "ipc.lcm", [&](Reader& r) {
    r.get("enabled", o.lcm.enabled);
    r.get("url", o.lcm.url);
    r.get("pose_channel", o.lcm.pose_channel);
    r.get("status_channel", o.lcm.status_channel);
    r.get("objects_channel", o.lcm.objects_channel);
  });
  if (s) s = section(node, "dds", "ipc.dds", [&](Reader& r) {
    r.get("enabled", o.dds.enabled);
    r.get("domain_id", o.dds.domain_id);
    r.get("config", o.dds.config);
    r.get("pose_topic", o.dds.pose_topic);
    r.get("status_topic", o.dds.status_topic);
    r.get("objects_topic", o.dds.objects_topic);
  });
  if (s) s = section(node, "ros2", "ipc.ros2", [&](Reader& r) {
    r.get("enabled", o.ros2.enabled);
    r.get("domain_id", o.ros2.domain_id);
    r.get("config", o.ros2.config);
    r.get("pose_topic", o.ros2.pose_topic);
    r.get("frame_id", o.ros2.frame_id);
    r.get("odometry_topic", o.ros2.odometry_topic);
    r.get("tf_topic", o.ros2.tf_topic);
    r.get("child_frame_id", o.ros2.child_frame_id);
    r.get("diagnostics_topic", o.ros2.diagnostics_topic);
    r.get("objects_topic", o.ros2.objects_topic);
    r.get("map_cloud_topic", o.ros2.map_cloud_topic);
    r.get("map_cloud_period_s", o.ros2.map_cloud_period_s);
    std::vector<double> extrinsic;
    r.get("camera_extrinsic", extrinsic);
    if (!extrinsic.empty()) {
      if (extrinsic.size() != 7) {
        if (r.error.empty()) r.error = "field 'ipc.ros2.camera_extrinsic' must be [x, y, z, qx, qy, qz, qw]";
      } else {
        std::copy(extrinsic.begin(), extrinsic.end(), o.ros2.camera_extrinsic.begin());
      }
    }
  });
  if (!s) return Error{s.error()};
  if (Status v = o.validate(); !v) return Error{v.error()};
  return o;
}

Result<IpcOptions> loadIpcOptions(const std::string& path) {
  auto loaded = loadYamlFile(path, "config '" + path + "'");
  if (!loaded) return Error{loaded.error()};
  const YAML::Node root = *loaded;
  if (root.IsNull()) return IpcOptions{};
  if (!root.IsMap()) return Error{"config '" + path + "': expected a mapping at the top level"};
  auto parsed = parseIpcOptions(root["ipc"]);
  if (!parsed) return Error{"config '" + path + "': " + parsed.error()};
  return parsed;
}

}  // namespace stillpoint::ipc
