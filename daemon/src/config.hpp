#pragma once
// stillpointd's configuration: one YAML file (see config/stillpointd.yaml).
// Every section feeds a plain struct; validate() and the parser name the bad
// field (and its line). The SLAM options come from a file or inline.
#include <cstdint>
#include <string>
#include <vector>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/result.hpp"
#include "stillpoint/ipc/options.hpp"
#include "stillpoint/platform/openni2_source.hpp"
#include "stillpoint/platform/replay_source.hpp"
#include "stillpoint/platform/v4l2_source.hpp"
#include "stillpoint/slam/options.hpp"
#include "stillpoint/slam/system.hpp"

namespace stillpoint::daemon {

// Where one thread runs. Empty cores: no pinning. priority 0: normal
// scheduling (SCHED_OTHER); 1..99: SCHED_FIFO at that priority. nice: the
// thread's nice value under normal scheduling (-20..19; 0 keeps what it
// inherited). A positive value needs no privilege and makes the thread yield
// the CPU to the others: the semantic thread's default (10) keeps a keyframe
// segmentation, hundreds of ms of CPU, from delaying tracking on a small board;
// mapping's (5) lets tracking go first when local BA and tracking share a core.
struct ThreadPlacement {
  std::vector<int> cores;
  int priority = 0;
  int nice = 0;
};

// The threads the daemon places. "mapping" covers the SLAM core's own threads
// (local mapping, geometry clustering) and "publisher" the IPC publisher's:
// those threads are started while the daemon's set-up thread carries that
// placement, and inherit it. "semantic" is the semantic module's segmentation
// thread, placed by a hook the SLAM core runs on it.
struct ThreadMap {
  ThreadPlacement source, tracking, publisher;
  ThreadPlacement mapping{.cores = {}, .priority = 0, .nice = 5};
  ThreadPlacement semantic{.cores = {}, .priority = 0, .nice = 10};
};

struct SourceConfig {
  std::string type = "replay";  // replay | openni2 | v4l2
  std::uint32_t queue_capacity = 4;  // frames between the source and tracking
  platform::ReplaySourceOptions replay;
  platform::OpenNI2SourceOptions openni2;
  platform::V4l2SourceOptions v4l2;
};

// The dynamic-object modules. These keys override the matching fields of the
// SLAM options (geometry.enabled, semantic.enabled, semantic.model_card,
// semantic.model_dirs); the other module options stay in `slam:`.
struct ModulesConfig {
  bool geometry = slam::GeometryOptions{}.enabled;  // the SLAM core's default
  bool semantic = false;  // keyframe segmentation (needs colour: sources deliver BGR when on)
  // Model card YAML; "" = the SLAM options' semantic.model_card, and when that
  // is empty too the recommended model (COCO if its .onnx is found, with the
  // person model where a map starts; else the in-tree person model). A
  // relative path that does not exist is looked up in the models folder
  // (/usr/share/stillpoint/models when installed).
  std::string semantic_model_card;
  // Folders searched first for the card's model file; empty = the SLAM options' semantic.model_dirs.
  std::vector<std::string> semantic_model_dirs;
};

struct OutputConfig {
  // TUM trajectory written on stop ("" = none). The SLAM core keeps the
  // frames' poses for it (slam tracking.trajectory_records, ~150 bytes per
  // frame: ~390 MB a day at 30 Hz; cap it for long runs). With none, it keeps none.
  std::string trajectory;
  std::string status;      // key=value summary written on stop ("" = none)
};

struct MapConfig {
  std::string load;  // map file read at start-up ("" = none): tracking relocalises against it
  std::string save;  // map file written on stop and on SIGUSR1 ("" = none)
  bool localisation = false;  // mode: localisation (tracks against `load` only) | slam
};

struct DaemonConfig {
  std::string camera_spec = "fr3";  // preset name or camera YAML path
  CameraModel camera;               // resolved from camera_spec
  SourceConfig source;
  std::string slam_options_file;    // "" = inline `slam.options` or defaults
  slam::SlamOptions slam;           // effective options
  ModulesConfig modules;
  slam::SemanticModelChoice semantic_model;  // checked at load when modules.semantic is on
  ThreadMap threads;
  ipc::IpcOptions ipc;
  OutputConfig output;
  MapConfig map;
  std::string log_level = "info";
  double shutdown_timeout_s = 5.0;  // a stop that takes longer forces exit (status 1)
  double status_period_s = 1.0;     // STATUS= and status messages
  bool lock_memory = false;         // mlockall with CAP_IPC_LOCK or unlimited RLIMIT_MEMLOCK (threads.hpp); the shipped config turns it on
};

// Loads and validates the file; errors read "PATH: line N: field 'a.b': ...".
Result<DaemonConfig> loadDaemonConfig(const std::string& path);
// The effective configuration as YAML (--print-config); loading it gives the same config.
std::string toYaml(const DaemonConfig& config);

}  // namespace stillpoint::daemon
