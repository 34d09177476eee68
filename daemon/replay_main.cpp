// stillpoint-replay: runs the SLAM pipeline over a recorded TUM-layout
// sequence, writes the trajectory and prints a summary whose last line is
// machine-readable.
#include <Eigen/Eigenvalues>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cerrno>
#include <climits>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/covariance.hpp"
#include "stillpoint/core/log.hpp"
#include "stillpoint/core/program.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/eval/metrics.hpp"
#include "stillpoint/eval/trajectory.hpp"
#include "stillpoint/slam/options.hpp"
#include "stillpoint/slam/system.hpp"
#include "stillpoint/synth/score.hpp"
#include "render/frame_render.hpp"

namespace {

using namespace stillpoint;

constexpr const char* kUsage =
    "usage: stillpoint-replay DATASET_DIR --camera fr1|fr2|fr3|CAMERA.yaml --output TRAJ.txt\n"
    "                         [--config SLAM.yaml] [--sequential [--keyframe-spacing N]] [--paced]\n"
    "                         [--modules none|geometry,semantic] [--features-out FEATURES.txt]\n"
    "                         [--keyframes-out KEYFRAMES.txt] [--keyframe-trajectory KF_TRAJ.txt]\n"
    "                         [--known-movers] [--max-frames N] [--log-level debug|info|warn|error]\n"
    "                         [--frame-log FRAMES.txt] [--objects-out OBJECTS.txt] [--render DIR] [--render-every N]\n"
    "                         [--render-video FILE.mp4] [--model-card CARD.yaml]\n"
    "                         [--load-map MAP] [--localisation] [--save-map MAP] [--export-cloud CLOUD.ply]\n"
    "                         [--export-dense-cloud CLOUD.ply]\n"
    "       stillpoint-replay --help | --version | --options-reference\n"
    "\n"
    "Runs stillpoint over a TUM RGB-D layout folder (rgb.txt, depth.txt, rgb/, depth/) as fast\n"
    "as it can (--paced: at the recorded rate), writes the camera trajectory in TUM format and\n"
    "prints a summary. When the folder has groundtruth.txt, ATE/RPE are printed too.\n"
    "--sequential runs local mapping inline on one thread (deterministic). Local mapping is then\n"
    "always free, so a keyframe can come every frame; --keyframe-spacing N makes them at least N\n"
    "frames apart (but for those weak tracking forces), as a live run's busy mapper does (2-3 on a\n"
    "2-core CPU with the semantic module).\n"
    "--options-reference prints the SLAM options' YAML keys as a Markdown table.\n"
    "--modules picks the dynamic-object modules: 'none', or a comma list of geometry and semantic\n"
    "(default: as the config enables them; listed modules are on, the others off).\n"
    "--features-out writes every feature the geometry module judged, one line\n"
    "'timestamp u v dynamic(0|1) cluster chi2 evidence inherited depth distance ratio ru rv rz freespace explained\n"
    "baseline', for stillpoint-synth score.\n"
    "--keyframes-out writes the features of every segmented keyframe after the run, one line\n"
    "'timestamp u v unmapped(0|1)' (1: the feature holds no map point), for stillpoint-synth score.\n"
    "--keyframe-trajectory writes the final poses of the keyframes (culled ones included) in TUM\n"
    "format, to tell keyframe (map) error from per-frame tracking error.\n"
    "--known-movers gives tracking the sequence's own mover masks (mask.txt, written by\n"
    "stillpoint-synth) as known movers: their features stay out of the pose and the map. With\n"
    "--modules none it measures the best a detector could do (a perfect one).\n"
    "--model-card picks the semantic module's model (semantic.model_card).\n"
    "--load-map reads a map file (from --save-map) before the first frame: tracking relocalises\n"
    "against it; --localisation tracks against it only (no keyframes, points or maps are made).\n"
    "--save-map writes the maps after the run; --export-cloud writes the map points as a coloured\n"
    "PLY point cloud; --export-dense-cloud the keyframes' depth fused into a static cloud (1 cm\n"
    "voxels; moving and movable pixels, and voxels other keyframes saw through, left out).\n"
    "--objects-out writes every dynamic object of every frame with a pose, one line each: 'timestamp\n"
    "  id label sources cx cy cz ex ey ez vx vy vz has_velocity samples' (map frame, metres; sources\n"
    "  1 geometry, 2 semantic, 3 both).\n"
    "--frame-log writes one line per frame: 'index timestamp state track_ms geometry_ms features\n"
    "in_pose geometry_dynamic semantic_dynamic keyframe(0|1) health dynamic_share outlier_share\n"
    "reprojection_rms_px conditioning mask_age_s masks_found_movers health_causes position_sigma_m\n"
    "rotation_sigma_deg covariance' (health: good, degraded, unreliable, lost; health_causes: what\n"
    "lowered it, names joined by '+', or none; position_sigma_m and rotation_sigma_deg: the standard\n"
    "deviations along the pose covariance's weakest direction; covariance: its upper triangle row by\n"
    "row, 21 numbers joined by ',', position [m] then rotation [rad] about the map's axes, all 0\n"
    "without a pose;\n"
    "docs/pose-health.md) (state: ok, relocalised, new_map, lost, no_depth, initialising, or skipped\n"
    "for a frame that could not be read or tracked) (mask_age_s: seconds from the image of the newest\n"
    "semantic masks to the frame, inf when none is near the camera, -1 when not known;\n"
    "masks_found_movers 1 when they kept features out).\n"
    "--render DIR writes a picture of every frame (every N-th with --render-every): the colour\n"
    "image with each feature drawn by its fate (in the pose, dynamic by geometry, dynamic by a\n"
    "semantic mask, no depth, unmatched), the depth clusters, the newest semantic masks and the\n"
    "trajectory so far; --render-video writes the same pictures as a video (OpenCV VideoWriter,\n"
    "mp4v) at the sequence's frame rate.\n"
    "The last line is: frames=<n> tracked=<n> lost=<n> keyframes=<n> track_ms_median=<v> track_ms_p95=<v>\n"
    "geometry_ms_median=<v> segment_ms_median=<v> segmentations_dropped=<n> (one line).\n";

struct Args {
  std::string dataset, camera, output, config, modules, features_out, keyframes_out, keyframe_trajectory, log_level = "warn";
  std::string objects_out, frame_log, render_dir, render_video, model_card, load_map, save_map, export_cloud, export_dense;
  bool localisation = false;
  long render_every = 1;
  bool sequential = false, paced = false, known_movers = false;
  bool geometry = false, semantic = false;  // from --modules
  long max_frames = -1;
  long keyframe_spacing = 0;  // 0: not given
};

bool parseArgs(int argc, char** argv, Args* args, std::string* error) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&](std::string* out) {
      if (i + 1 >= argc) {
        *error = "option " + a + " needs a value";
        return false;
      }
      *out = argv[++i];
      return true;
    };
    // A whole number in 1..max as the option's value, else `message`.
    auto count = [&](long* out, long max, const char* message) {
      std::string v;
      if (!value(&v)) return false;
      char* end = nullptr;
      *out = std::strtol(v.c_str(), &end, 10);
      if (*end || *out <= 0 || *out > max) {
        *error = message;
        return false;
      }
      return true;
    };
    if (a == "--camera") {
      if (!value(&args->camera)) return false;
    } else if (a == "--output") {
      if (!value(&args->output)) return false;
    } else if (a == "--config") {
      if (!value(&args->config)) return false;
    } else if (a == "--modules") {
      if (!value(&args->modules)) return false;
    } else if (a == "--features-out") {
      if (!value(&args->features_out)) return false;
    } else if (a == "--keyframes-out") {
      if (!value(&args->keyframes_out)) return false;
    } else if (a == "--keyframe-trajectory") {
      if (!value(&args->keyframe_trajectory)) return false;
    } else if (a == "--log-level") {
      if (!value(&args->log_level)) return false;
    } else if (a == "--load-map") {
      if (!value(&args->load_map)) return false;
    } else if (a == "--save-map") {
      if (!value(&args->save_map)) return false;
    } else if (a == "--export-cloud") {
      if (!value(&args->export_cloud)) return false;
    } else if (a == "--export-dense-cloud") {
      if (!value(&args->export_dense)) return false;
    } else if (a == "--localisation") {
      args->localisation = true;
    } else if (a == "--model-card") {
      if (!value(&args->model_card)) return false;
    } else if (a == "--objects-out") {
      if (!value(&args->objects_out)) return false;
    } else if (a == "--frame-log") {
      if (!value(&args->frame_log)) return false;
    } else if (a == "--render") {
      if (!value(&args->render_dir)) return false;
    } else if (a == "--render-video") {
      if (!value(&args->render_video)) return false;
    } else if (a == "--render-every") {
      if (!count(&args->render_every, LONG_MAX, "--render-every needs a positive integer")) return false;
    } else if (a == "--max-frames") {
      if (!count(&args->max_frames, LONG_MAX, "--max-frames needs a positive integer")) return false;
    } else if (a == "--sequential") {
      args->sequential = true;
    } else if (a == "--keyframe-spacing") {
      if (!count(&args->keyframe_spacing, 1000, "--keyframe-spacing needs an integer in 1..1000")) return false;
    } else if (a == "--paced") {
      args->paced = true;
    } else if (a == "--known-movers") {
      args->known_movers = true;
    } else if (!a.empty() && a[0] == '-') {
      *error = "unknown option " + a;
      return false;
    } else if (args->dataset.empty()) {
      args->dataset = a;
    } else {
      *error = "unexpected argument " + a;
      return false;
    }
  }
  if (args->dataset.empty()) *error = "missing DATASET_DIR";
  else if (args->localisation && args->load_map.empty()) *error = "--localisation needs --load-map";
  else if (args->keyframe_spacing > 0 && !args->sequential) *error = "--keyframe-spacing needs --sequential";
  else if (args->camera.empty()) *error = "missing --camera";
  else if (args->output.empty()) *error = "missing --output";
  else if (!args->modules.empty() && args->modules != "none") {
    std::size_t start = 0;
    while (error->empty()) {
      const std::size_t comma = args->modules.find(',', start);
      const std::string name = args->modules.substr(start, comma == std::string::npos ? comma : comma - start);
      if (name == "geometry") args->geometry = true;
      else if (name == "semantic") args->semantic = true;
      else *error = "--modules: expected 'none' or a comma list of geometry, semantic; got '" + args->modules + "'";
      if (comma == std::string::npos) break;
      start = comma + 1;
    }
  }
  return error->empty();
}

struct Stats {
  double mean = 0, median = 0, p95 = 0, max = 0;
};

Stats stats(std::vector<double> v) {
  Stats s;
  if (v.empty()) return s;
  std::sort(v.begin(), v.end());
  double sum = 0;
  for (double x : v) sum += x;
  s.mean = sum / v.size();
  s.median = v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
  s.p95 = v[std::min(v.size() - 1, static_cast<std::size_t>(std::ceil(0.95 * v.size())) - 1)];
  s.max = v.back();
  return s;
}

// The standard deviation along the worst direction of the covariance's
// position (first = 0) or rotation (first = 3) block.
double largestSigma(const Eigen::Matrix<double, 6, 6>& covariance, int first) {
  const Eigen::Matrix3d block = covariance.block<3, 3>(first, first);
  return std::sqrt(std::max(0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(block, Eigen::EigenvaluesOnly).eigenvalues()(2)));
}

// The covariance's upper triangle, row by row, joined by commas (one column).
std::string covarianceColumn(const Eigen::Matrix<double, 6, 6>& covariance) {
  std::string column;
  char number[32];
  for (double v : upperTriangle<double>(covariance)) {
    std::snprintf(number, sizeof number, "%s%.4g", column.empty() ? "" : ",", v);
    column += number;
  }
  return column;
}

// The frame log's line of a frame that could not be read or tracked.
void logSkipped(std::FILE* log, std::size_t index, Timestamp stamp) {
  std::fprintf(log, "%zu %s skipped 0 0 0 0 0 0 0 lost 0 0 0 0 -1 0 none 0 0 %s\n", index,
               stamp.toSecondsString().c_str(), covarianceColumn(Eigen::Matrix<double, 6, 6>::Zero()).c_str());
}

}  // namespace

static int replayMain(int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--help") || !std::strcmp(argv[i], "-h")) {
      std::fputs(kUsage, stdout);
      return 0;
    }
    if (!std::strcmp(argv[i], "--version")) {
      std::puts("stillpoint-replay " STILLPOINT_VERSION " (" STILLPOINT_ARCH ")");
      return 0;
    }
    if (!std::strcmp(argv[i], "--options-reference")) {  // docs/configuration.md's table
      std::fputs(slam::optionsReference().c_str(), stdout);
      return 0;
    }
  }
  Args args;
  std::string error;
  if (!parseArgs(argc, argv, &args, &error)) {
    std::fprintf(stderr, "stillpoint-replay: %s\n\n%s", error.c_str(), kUsage);
    return 2;
  }
  log::Level level;
  if (!log::parseLevel(args.log_level, &level)) {
    std::fprintf(stderr, "stillpoint-replay: bad --log-level '%s'\n", args.log_level.c_str());
    return 2;
  }
  log::setLevel(level);
  // OpenCV's own thread pool would compete with local mapping for the cores.
  cv::setNumThreads(1);

  auto camera = loadCamera(args.camera);
  if (!camera) {
    std::fprintf(stderr, "stillpoint-replay: %s\n", camera.error().c_str());
    return 1;
  }
  slam::SlamOptions options;
  if (!args.config.empty()) {
    auto loaded = slam::loadSlamOptions(args.config);
    if (!loaded) {
      std::fprintf(stderr, "stillpoint-replay: %s\n", loaded.error().c_str());
      return 1;
    }
    options = *loaded;
  }
  if (args.sequential) options.sequential = true;
  if (args.keyframe_spacing > 0) options.keyframes.min_interval_frames = static_cast<int>(args.keyframe_spacing);
  if (!args.model_card.empty()) options.semantic.model_card = args.model_card;
  if (args.localisation) options.localisation = true;
  if (!args.export_dense.empty()) options.mapping.dense_views = true;
  // The keyframe file lists every keyframe made, culled ones included.
  if (!args.keyframes_out.empty()) options.mapping.keep_culled_keyframes = true;
  options.geometry.report_features = !args.features_out.empty();
  const bool rendering = !args.render_dir.empty() || !args.render_video.empty();
  options.report_fates = rendering;
  if (!args.modules.empty()) {
    options.geometry.enabled = args.geometry;
    options.semantic.enabled = args.semantic;
  }
  // Every output is opened (created) before the run: an unwritable path is
  // an error now, not after the whole sequence.
  if (!args.render_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(args.render_dir, ec);
    if (ec || !std::filesystem::is_directory(args.render_dir)) {
      std::fprintf(stderr, "stillpoint-replay: cannot create --render folder %s: %s\n", args.render_dir.c_str(),
                   ec ? ec.message().c_str() : "not a folder");
      return 1;
    }
  }
  for (const std::string* path :
       {&args.output, &args.keyframe_trajectory, &args.keyframes_out, &args.frame_log, &args.objects_out, &args.save_map, &args.export_cloud,
        &args.export_dense}) {
    if (path->empty()) continue;
    std::FILE* f = std::fopen(path->c_str(), "a");
    if (!f) {
      std::fprintf(stderr, "stillpoint-replay: cannot write %s: %s\n", path->c_str(), std::strerror(errno));
      return 1;
    }
    std::fclose(f);
  }
  std::FILE* features_out = nullptr;
  if (!args.features_out.empty()) {
    features_out = std::fopen(args.features_out.c_str(), "w");
    if (!features_out) {
      std::fprintf(stderr, "stillpoint-replay: cannot write %s\n", args.features_out.c_str());
      return 1;
    }
    std::fputs("# timestamp u v dynamic cluster chi2 evidence inherited depth distance ratio ru rv rz freespace\n"
               "# explained baseline: features with evidence the geometry module judged (cluster label, squared\n"
               "# reprojection error / sigma^2 against the initial pose, evidence 0 anchor frame | 1 map point |\n"
               "# 2 carried or reference keyframe, inherited 1 = matched to a feature dynamic before, keypoint\n"
               "# depth in m, Hamming distance of the evidence match, its ratio to the second best in the\n"
               "# projection search window, 0: none or not searched, chi2's components: u, v, depth term over\n"
               "# sigma, share of its cluster's depth samples in space the anchor frame saw empty, -1: not\n"
               "# tested, explained 1 = evidence disagreed but the static hypothesis explains it as well: left\n"
               "# out of the verdict, still reported, baseline: frames back of an anchor match, 0: other\n"
               "# evidence)\n",
               features_out);
  }

  dataset::DatasetOptions dataset_options;
  dataset_options.expected_width = camera->width;
  dataset_options.expected_height = camera->height;
  dataset_options.depth_factor = camera->depth_factor;
  auto data = dataset::TumDataset::open(args.dataset, dataset_options);
  if (!data) {
    std::fprintf(stderr, "stillpoint-replay: %s\n", data.error().c_str());
    return 1;
  }
  std::FILE* frame_log = nullptr;
  if (!args.frame_log.empty()) {
    frame_log = std::fopen(args.frame_log.c_str(), "w");
    if (!frame_log) {
      std::fprintf(stderr, "stillpoint-replay: cannot write %s\n", args.frame_log.c_str());
      return 1;
    }
    std::fputs("# index timestamp state track_ms geometry_ms features in_pose geometry_dynamic semantic_dynamic "
               "keyframe health dynamic_share outlier_share reprojection_rms_px conditioning mask_age_s masks_found_movers "
               "health_causes position_sigma_m rotation_sigma_deg covariance\n",
               frame_log);
  }
  std::FILE* objects_out = nullptr;
  if (!args.objects_out.empty()) {
    objects_out = std::fopen(args.objects_out.c_str(), "w");
    if (!objects_out) {
      std::fprintf(stderr, "stillpoint-replay: cannot write %s\n", args.objects_out.c_str());
      return 1;
    }
    std::fputs("# timestamp id label sources cx cy cz ex ey ez vx vy vz has_velocity samples\n", objects_out);
  }
  cv::VideoWriter video;
  if (!args.render_video.empty()) {
    // The sequence's own rate, from its first and last stamps.
    double fps = 30.0;
    if (data->size() > 1) {
      const double span = secondsBetween(data->stamp(data->size() - 1), data->stamp(0));
      if (span > 0) fps = std::clamp((data->size() - 1) / span, 1.0, 120.0);
    }
    try {
      video.open(args.render_video, cv::VideoWriter::fourcc('m', 'p', '4', 'v'), fps,
                 cv::Size(2 * camera->width, 2 * camera->height));
    } catch (const cv::Exception& e) {
      std::fprintf(stderr, "stillpoint-replay: %s\n", e.what());
    }
    if (!video.isOpened()) {
      std::fprintf(stderr, "stillpoint-replay: cannot write the video %s (OpenCV has no mp4v writer for it)\n",
                   args.render_video.c_str());
      return 1;
    }
  }
  eval::Trajectory rendered_poses;
  std::size_t render_failures = 0;
  std::map<Timestamp, std::string> mover_masks;
  if (args.known_movers) {
    auto listed = synth::readMaskList(args.dataset);
    if (!listed) {
      std::fprintf(stderr, "stillpoint-replay: --known-movers: %s\n", listed.error().c_str());
      return 1;
    }
    mover_masks = std::move(*listed);
  }
  // The SLAM system's threads run as under stillpointd's defaults, so that
  // tracking times mean the same here: local mapping, the depth clustering and
  // the tracker's helper at nice 5 (threads.mapping.nice; they inherit it from
  // the thread that creates the system), the segmentation thread at nice 10
  // (threads.semantic.nice). A keyframe's bundle adjustment or segmentation
  // must not take the CPU from tracking, which runs here (nice 0).
  slam::SlamThreadHooks hooks;
  hooks.semantic_start = [] { setpriority(PRIO_PROCESS, static_cast<id_t>(::gettid()), 10); };
  Result<std::unique_ptr<slam::SlamSystem>> system = Error{"not created"};
  std::thread([&] {
    setpriority(PRIO_PROCESS, static_cast<id_t>(::gettid()), 5);
    system = slam::SlamSystem::create(*camera, options, hooks);
  }).join();
  if (!system) {
    std::fprintf(stderr, "stillpoint-replay: %s\n", system.error().c_str());
    return 1;
  }
  double map_load_ms = 0;
  if (!args.load_map.empty()) {
    const auto t0 = std::chrono::steady_clock::now();
    if (Status s = (*system)->loadMap(args.load_map); !s) {
      std::fprintf(stderr, "stillpoint-replay: %s\n", s.error().c_str());
      return 1;
    }
    map_load_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  }

  std::size_t frames = 0, tracked = 0, lost = 0, skipped = 0, initialising = 0, no_depth = 0, relocalised = 0;
  std::vector<double> extract_ms, track_ms, initial_ms, local_map_ms, pose_opt_ms, keyframe_ms;
  std::vector<double> geometry_ms, clustering_ms, objects_ms, semantic_ms;
  std::vector<eval::StampedLabel> health, causes;  // of the frames with a pose
  std::vector<eval::StampedCovariance> covariances;
  std::size_t geometry_frames = 0, geometry_misses = 0, dynamic_clusters = 0, dynamic_features = 0, consensus = 0;
  std::size_t semantic_followed = 0;  // features matched to the last segmented keyframe's masks
  const std::size_t n = args.max_frames > 0 ? std::min<std::size_t>(data->size(), args.max_frames) : data->size();
  const auto start = std::chrono::steady_clock::now();
  auto pace_start = start;
  Timestamp first_stamp, last_stamp;
  for (std::size_t i = 0; i < n; ++i) {
    auto frame = data->load(i);
    if (!frame) {
      std::fprintf(stderr, "stillpoint-replay: skipping frame %zu: %s\n", i, frame.error().c_str());
      ++skipped;
      if (frame_log) logSkipped(frame_log, i, data->stamp(i));
      continue;
    }
    if (frames == 0) first_stamp = frame->stamp;
    if (args.paced) {
      // A gap over a second in the stamps (a paused recording, a corrupt
      // stamp) is not slept through: pacing starts again from this frame.
      if (frames > 0 && secondsBetween(frame->stamp, last_stamp) > 1.0) {
        std::fprintf(stderr, "stillpoint-replay: a gap of %.1f s before frame %zu is not waited for\n",
                     secondsBetween(frame->stamp, last_stamp), i);
        pace_start = std::chrono::steady_clock::now();
        first_stamp = frame->stamp;
      }
      const auto due = pace_start + std::chrono::nanoseconds(frame->stamp.nanoseconds() - first_stamp.nanoseconds());
      std::this_thread::sleep_until(due);
    }
    last_stamp = frame->stamp;
    cv::Mat movers;
    if (args.known_movers) {
      // Every frame needs its mask: one missing would silently let its movers into the map.
      const auto mask = mover_masks.find(frame->stamp);
      auto read = mask != mover_masks.end() ? dataset::readImageFile("mover mask", mask->second, cv::IMREAD_UNCHANGED)
                                            : Result<cv::Mat>(Error{"none in mask.txt"});
      if (!read) {
        std::fprintf(stderr, "stillpoint-replay: --known-movers: no readable mask for frame %zu (%s): %s\n", i,
                     frame->stamp.toSecondsString().c_str(), read.error().c_str());
        return 1;
      }
      movers = std::move(*read);
    }
    auto out = (*system)->track({frame->stamp, frame->gray, frame->depth_m, frame->bgr, movers});
    if (!out) {
      std::fprintf(stderr, "stillpoint-replay: skipping frame %zu: %s\n", i, out.error().c_str());
      ++skipped;
      if (frame_log) logSkipped(frame_log, i, frame->stamp);
      continue;
    }
    const bool has_pose = slam::hasPose(out->state);
    if (has_pose) {
      health.push_back({frame->stamp, slam::toString(out->quality.health)});
      causes.push_back({frame->stamp, health_cause::toString(out->quality.causes)});
      covariances.push_back({frame->stamp, out->quality.covariance});
    }
    if (frame_log)
      std::fprintf(frame_log, "%zu %s %s %.3f %.3f %d %d %d %d %d %s %.3f %.3f %.3f %.4f %.3f %d %s %.3g %.3g %s\n", i, frame->stamp.toSecondsString().c_str(),
                   slam::toString(out->state), out->track_ms, out->stages.geometry, out->features, out->tracked,
                   out->geometry.dynamic_features, out->semantic_features, out->new_keyframe ? 1 : 0, slam::toString(out->quality.health),
                   out->quality.dynamic_share, out->quality.outlier_share, out->quality.reprojection_rms_px,
                   out->quality.conditioning, out->quality.mask_age_s, out->quality.masks_found_movers ? 1 : 0,
                   health_cause::toString(out->quality.causes).c_str(), largestSigma(out->quality.covariance, 0),
                   largestSigma(out->quality.covariance, 3) * 180 / M_PI, covarianceColumn(out->quality.covariance).c_str());
    if (objects_out)
      for (const slam::DynamicObject& o : out->objects)
        std::fprintf(objects_out, "%s %u %s %d %.4f %.4f %.4f %.4f %.4f %.4f %.4f %.4f %.4f %d %d\n",
                     frame->stamp.toSecondsString().c_str(), o.id, o.label.c_str(), o.sources, o.centroid.x(),
                     o.centroid.y(), o.centroid.z(), o.extent.x(), o.extent.y(), o.extent.z(), o.velocity.x(),
                     o.velocity.y(), o.velocity.z(), o.has_velocity ? 1 : 0, o.samples);
    if (rendering && has_pose) rendered_poses.push_back({frame->stamp, out->T_w_c});
    if (rendering && i % static_cast<std::size_t>(args.render_every) == 0) {
      render::FrameInput in;
      in.bgr = &frame->bgr;
      in.gray = &frame->gray;
      in.out = &*out;
      in.index = i;
      in.estimate = &rendered_poses;
      in.geometry_enabled = options.geometry.enabled;
      in.semantic_enabled = options.semantic.enabled;
      const cv::Mat picture = render::renderFrame(in);
      if (!args.render_dir.empty()) {
        char name[32];
        std::snprintf(name, sizeof(name), "/%06zu.png", i);
        bool written = false;
        try {
          written = cv::imwrite(args.render_dir + name, picture);
        } catch (const cv::Exception&) {
        }
        if (!written && render_failures++ == 0)
          std::fprintf(stderr, "stillpoint-replay: cannot write %s%s (further failures counted)\n",
                       args.render_dir.c_str(), name);
      }
      if (video.isOpened()) video.write(picture);
    }
    ++frames;
    extract_ms.push_back(out->extract_ms);
    track_ms.push_back(out->track_ms);
    initial_ms.push_back(out->stages.initial_pose);
    local_map_ms.push_back(out->stages.local_map);
    pose_opt_ms.push_back(out->stages.pose_optimisation);
    keyframe_ms.push_back(out->stages.keyframe);
    objects_ms.push_back(out->stages.objects);
    semantic_ms.push_back(out->stages.semantic);
    semantic_followed += out->semantic_features;
    const slam::GeometryOutput& g = out->geometry;
    if (g.ran || g.deadline_missed) geometry_ms.push_back(out->stages.geometry);
    geometry_misses += g.deadline_missed;
    if (g.ran) {
      ++geometry_frames;
      clustering_ms.push_back(g.clustering_ms);
      dynamic_clusters += g.dynamic_clusters;
      dynamic_features += g.dynamic_features;
      consensus += g.consensus_pose;
      if (features_out)
        for (const slam::JudgedFeature& f : g.judged)
          std::fprintf(features_out, "%s %.2f %.2f %d %d %.3f %d %d %.3f %d %.3f %.2f %.2f %.2f %.3f %d %d\n",
                       frame->stamp.toSecondsString().c_str(), f.u, f.v, f.dynamic, f.cluster, f.chi2,
                       static_cast<int>(f.evidence), f.inherited ? 1 : 0, f.depth, f.distance, f.ratio,
                       f.residual.x(), f.residual.y(), f.residual.z(), f.freespace, f.explained ? 1 : 0,
                       f.baseline);
    }
    switch (out->state) {
      case slam::TrackingState::kOk:
      case slam::TrackingState::kNewMap: ++tracked; break;
      case slam::TrackingState::kRelocalised: ++tracked; ++relocalised; break;
      case slam::TrackingState::kLost: ++lost; break;
      case slam::TrackingState::kInitialising: ++initialising; break;
      case slam::TrackingState::kNoDepth: ++no_depth; break;
    }
  }
  (*system)->finish();
  if (video.isOpened()) video.release();
  if (objects_out && (std::ferror(objects_out) | std::fclose(objects_out))) {
    std::fprintf(stderr, "stillpoint-replay: writing %s failed: %s\n", args.objects_out.c_str(), std::strerror(errno));
    return 1;
  }
  if (frame_log && (std::ferror(frame_log) | std::fclose(frame_log))) {
    std::fprintf(stderr, "stillpoint-replay: writing %s failed: %s\n", args.frame_log.c_str(), std::strerror(errno));
    return 1;
  }
  if (render_failures > 0) {
    std::fprintf(stderr, "stillpoint-replay: %zu pictures could not be written to %s\n", render_failures,
                 args.render_dir.c_str());
    return 1;
  }
  // A full disk (or /dev/full) shows when the buffered writes are flushed.
  if (features_out && (std::ferror(features_out) | std::fclose(features_out))) {
    std::fprintf(stderr, "stillpoint-replay: writing %s failed: %s\n", args.features_out.c_str(), std::strerror(errno));
    return 1;
  }
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  eval::Trajectory trajectory;
  for (const auto& p : (*system)->trajectory()) trajectory.push_back({p.stamp, p.T_w_c, p.map_id});
  if (Status s = eval::writeTumTrajectory(args.output, trajectory); !s) {
    std::fprintf(stderr, "stillpoint-replay: %s\n", s.error().c_str());
    return 1;
  }
  const slam::MapStats map = (*system)->mapStats();
  if (!args.save_map.empty()) {
    if (Status s = (*system)->saveMap(args.save_map); !s) {
      std::fprintf(stderr, "stillpoint-replay: %s\n", s.error().c_str());
      return 1;
    }
  }
  if (!args.export_cloud.empty()) {
    if (Status s = (*system)->exportCloud(args.export_cloud); !s) {
      std::fprintf(stderr, "stillpoint-replay: %s\n", s.error().c_str());
      return 1;
    }
  }
  if (!args.export_dense.empty()) {
    if (Status s = (*system)->exportDenseCloud(args.export_dense); !s) {
      std::fprintf(stderr, "stillpoint-replay: %s\n", s.error().c_str());
      return 1;
    }
  }
  if (!args.keyframe_trajectory.empty()) {
    eval::Trajectory keyframes;
    for (const slam::KeyFrameView& kf : (*system)->keyframes()) keyframes.push_back({kf.stamp, kf.T_w_c});
    if (Status s = eval::writeTumTrajectory(args.keyframe_trajectory, keyframes); !s) {
      std::fprintf(stderr, "stillpoint-replay: %s\n", s.error().c_str());
      return 1;
    }
  }
  if (!args.keyframes_out.empty()) {
    std::FILE* kf_out = std::fopen(args.keyframes_out.c_str(), "w");
    if (!kf_out) {
      std::fprintf(stderr, "stillpoint-replay: cannot write %s\n", args.keyframes_out.c_str());
      return 1;
    }
    std::fputs("# timestamp u v unmapped: features of segmented keyframes; 1 = holds no map point\n", kf_out);
    for (const slam::KeyFrameView& kf : (*system)->keyframes()) {
      if (!kf.segmented) continue;
      for (const slam::KeyFrameFeature& f : kf.features)
        std::fprintf(kf_out, "%s %.2f %.2f %d\n", kf.stamp.toSecondsString().c_str(), f.u, f.v, f.mapped ? 0 : 1);
    }
    if (std::ferror(kf_out) | std::fclose(kf_out)) {
      std::fprintf(stderr, "stillpoint-replay: writing %s failed: %s\n", args.keyframes_out.c_str(), std::strerror(errno));
      return 1;
    }
  }
  const Stats ex = stats(extract_ms), tr = stats(track_ms);
  std::printf("sequence:     %s (%zu associated frames, %zu colour frames without depth)\n", args.dataset.c_str(),
              data->size(), data->unassociatedColourFrames());
  std::printf("frames:       %zu processed, %zu tracked, %zu lost, %zu initialising, %zu without depth, "
              "%zu skipped (bad input)\n",
              frames, tracked, lost, initialising, no_depth, skipped);
  std::printf("recovery:     %zu relocalisations (%d refused: depth disagreed), %u map%s (%u started after a loss)\n",
              relocalised, map.relocalisations_refused, map.maps, map.maps == 1 ? "" : "s",
              map.maps > 0 ? map.maps - 1 : 0);
  if (!args.load_map.empty())
    std::printf("map file:     %s loaded in %.1f ms%s\n", args.load_map.c_str(), map_load_ms,
                args.localisation ? ", localisation only" : "");
  std::printf("map:          %zu keyframes, %zu points, %d local BA runs, local mapping %.1f ms total\n",
              map.keyframes, map.points, map.local_ba_runs, map.local_mapping_ms_total);
  if (map.young_map_waits > 0)
    std::printf("young map:    %d frames waited for local mapping, %.1f ms in all\n", map.young_map_waits,
                map.young_map_wait_ms_total);
  std::printf("timing [ms]:  %-24s mean %6.2f  median %6.2f  p95 %6.2f  max %6.2f\n", "ORB extraction", ex.mean,
              ex.median, ex.p95, ex.max);
  const std::pair<const char*, const std::vector<double>*> stages[] = {
      {"initial pose matching", &initial_ms},
      {"local map search", &local_map_ms},
      {"pose optimisation", &pose_opt_ms},
      {"keyframe decision", &keyframe_ms},
      {"dynamic objects", &objects_ms}};
  for (const auto& [name, values] : stages) {
    const Stats st = stats(*values);
    std::printf("              %-24s mean %6.2f  median %6.2f  p95 %6.2f  max %6.2f\n", name, st.mean, st.median,
                st.p95, st.max);
  }
  if (options.geometry.enabled) {
    const Stats gm = stats(geometry_ms), cl = stats(clustering_ms);
    std::printf("              %-24s mean %6.2f  median %6.2f  p95 %6.2f  max %6.2f\n", "geometry (tracking)", gm.mean,
                gm.median, gm.p95, gm.max);
    std::printf("              %-24s mean %6.2f  median %6.2f  p95 %6.2f  max %6.2f\n", "K-Means (own thread)",
                cl.mean, cl.median, cl.p95, cl.max);
  }
  if (options.semantic.enabled) {
    const Stats sm = stats(semantic_ms);
    std::printf("              %-24s mean %6.2f  median %6.2f  p95 %6.2f  max %6.2f\n", "masks to the frame", sm.mean,
                sm.median, sm.p95, sm.max);
  }
  std::printf("              %-24s mean %6.2f  median %6.2f  p95 %6.2f  max %6.2f\n", "tracking (incl. ORB)",
              tr.mean, tr.median, tr.p95, tr.max);
  std::printf("              %-24s %.1f fps over %.2f s wall\n", "throughput", frames / wall_s, wall_s);
  if (options.geometry.enabled)
    std::printf("geometry:     %zu frames judged, %zu deadline misses, %.2f dynamic clusters and %.1f dynamic "
                "features per frame, %zu judged under the consensus pose, %d map points culled\n",
                geometry_frames, geometry_misses, geometry_frames ? double(dynamic_clusters) / geometry_frames : 0.0,
                geometry_frames ? double(dynamic_features) / geometry_frames : 0.0, consensus,
                map.dynamic_points_culled);
  else
    std::printf("geometry:     off\n");
  if (options.semantic.enabled) {
    std::printf("semantic:     %s\n", map.semantic_model.c_str());
    std::printf("              %d keyframes segmented, %d dropped (queue full), %d without colour, %d failed\n",
                map.semantic_keyframes_segmented, map.semantic_keyframes_dropped, map.semantic_keyframes_no_colour,
                map.semantic_failures);
    if (map.semantic_frames_segmented > 0)
      std::printf("              %d frames segmented where no keyframe is made (a mapped place), %d of their "
                  "regions on objects the map saw as static\n",
                  map.semantic_frames_segmented, map.semantic_frame_regions_known_static);
    std::printf("              %d instances applied (%d by hysteresis, %d the pose had followed), %d unconfirmed by "
                "geometry, %d over the removal cap, %d on objects the map saw as static\n",
                map.semantic_instances_applied, map.semantic_instances_continued, map.semantic_instances_followed,
                map.semantic_instances_unconfirmed, map.semantic_instances_capped, map.semantic_instances_known_static);
    std::printf("              %zu places (10 cm cells) in the map's memory of static objects and movers\n",
                map.semantic_sighting_cells);
    std::printf("              %d features dropped, %d map points removed, %d culled (mostly in masks); %d features of "
                "applied regions kept on places the map saw standing\n",
                map.semantic_features_removed, map.semantic_points_removed, map.semantic_points_culled,
                map.semantic_features_on_standing);
    std::printf("              %.1f features per frame followed from the last segmented keyframe's masks%s\n",
                frames ? double(semantic_followed) / frames : 0.0,
                options.semantic.propagate_masks ? "" : " (semantic.propagate_masks off)");
    std::printf("              segmentation per keyframe median %.1f ms p95 %.1f ms; keyframe -> mask applied "
                "median %.1f ms p95 %.1f ms\n",
                map.segmentation_ms_median, map.segmentation_ms_p95, map.semantic_latency_ms_median,
                map.semantic_latency_ms_p95);
  } else {
    std::printf("semantic:     off\n");
  }
  if (map.vocabulary.empty())
    std::printf("places:       no vocabulary: no loop closing\n");
  else
    std::printf("places:       %s; %d loops closed (%d candidates, %d failed the geometric check; %d of %d frames "
                "that came back to an older place), %d global BAs (%d dropped, %d cut at their time limit)\n",
                map.vocabulary.c_str(), map.loops_closed, map.loops_detected, map.loops_rejected,
                map.loops_crossings_closed, map.loops_crossings_checked, map.global_ba_runs, map.global_ba_dropped,
                map.global_ba_out_of_time);
  std::printf("trajectory:   %zu poses -> %s\n", trajectory.size(), args.output.c_str());
  if (data->hasGroundTruth()) {
    auto gt = eval::readTumTrajectory(data->groundTruthPath());
    if (!gt) {
      std::fprintf(stderr, "stillpoint-replay: ground truth unusable: %s\n", gt.error().c_str());
    } else if (auto ev = eval::evaluate(*gt, trajectory); ev) {
      std::printf("accuracy:     ate_rmse_m=%.6f rpe_trans_m_s=%.6f rpe_rot_deg_s=%.6f matched=%zu\n",
                  ev->ate_rmse_m, ev->rpe_trans_m_s, ev->rpe_rot_deg_s, ev->matched);
      if (ev->maps > 1)
        std::printf("              over %zu maps, each aligned on its own (%zu poses of maps too short to align left "
                    "out); all in one frame %.4f m\n",
                    ev->maps, ev->unaligned, ev->ate_one_frame_rmse_m);
      // How far off each health level's poses were, then the same poses by what
      // lowered their health (a pose under each of its causes).
      const auto print = [](const char* lead, const std::vector<eval::LabelDrift>& drift) {
        for (const eval::LabelDrift& d : drift) {
          std::printf("%s%s %zu poses: drift over 1/3 s median %.4f m, p90 %.4f m, max %.4f m, %.1f %% over 2 cm\n", lead,
                      d.label.c_str(), d.poses, d.median_m, d.p90_m, d.max_m, 100.0 * d.share_over_bound);
          lead = "              ";
        }
      };
      if (auto drift = eval::driftByLabel(*ev, health, eval::poseHealthDriftOptions()); drift) print("health:       ", *drift);
      const eval::DriftOptions cause_options = eval::healthCauseDriftOptions();
      if (auto drift = eval::driftPerPose(*ev, causes, cause_options); drift)
        print("causes:       ", eval::summariseDrift(eval::splitLabels(*drift), cause_options));
      // How well the poses' covariances covered that drift (all poses).
      if (auto covered = eval::normalisedDriftPerPose(*ev, trajectory, covariances, health); covered && !covered->empty()) {
        const eval::CovarianceCoverage all = eval::summariseCoverage(*covered).back();
        std::printf("covariance:   %zu poses: drift within its 95 %% ellipsoid %.1f %% (median %.2f of a Gaussian's), "
                    "rotation %.1f %% (%.2f)\n",
                    all.poses, 100.0 * all.position_within, all.position_median, 100.0 * all.rotation_within,
                    all.rotation_median);
      }
    } else {
      std::fprintf(stderr, "stillpoint-replay: evaluation failed: %s\n", ev.error().c_str());
    }
  }
  std::printf("frames=%zu tracked=%zu lost=%zu keyframes=%zu track_ms_median=%.3f track_ms_p95=%.3f "
              "geometry_ms_median=%.3f segment_ms_median=%.3f segmentations_dropped=%d\n",
              frames, tracked, lost, map.keyframes, tr.median, tr.p95, stats(geometry_ms).median,
              map.segmentation_ms_median, map.semantic_keyframes_dropped);
  return frames > 0 ? 0 : 1;
}

int main(int argc, char** argv) { return stillpoint::runProgram("stillpoint-replay", replayMain, argc, argv); }
