// stillpoint-bench: the accuracy and runtime tables of a list of sequences x
// module sets x runs, with plots and a Markdown report, in one folder. Every
// run is a stillpoint-replay process of its own: a crash is one row of the
// table, and the bench goes on with the rest.
#include <fcntl.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench/published.hpp"
#include "stillpoint_commit.h"
#include "stillpoint/core/program.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/eval/metrics.hpp"
#include "stillpoint/eval/plot.hpp"
#include "stillpoint/eval/trajectory.hpp"
#include "stillpoint/features/orb_extractor.hpp"

extern char** environ;

namespace {

namespace fs = std::filesystem;
using namespace stillpoint;
using eval::quantile;

constexpr const char* kUsage =
    "usage: stillpoint-bench --sequence DIR:CAMERA [--sequence DIR:CAMERA ...] --out DIR\n"
    "                        [--modules none,geometry,semantic,geometry+semantic] [--runs N]\n"
    "                        [--sequential | --paced] [--config SLAM.yaml] [--model-card CARD.yaml ...]\n"
    "                        [--max-frames N] [--render-every N] [--no-plots] [--replay PATH]\n"
    "       stillpoint-bench --help | --version\n"
    "\n"
    "Replays every sequence (a TUM RGB-D layout folder; CAMERA as stillpoint-replay --camera:\n"
    "fr1, fr2, fr3 or a camera YAML) with every module set, N times (default 3), each run in a\n"
    "stillpoint-replay process of its own, threaded as stillpointd runs (--sequential: one\n"
    "thread, deterministic; --paced: frames at their recorded rate, as a camera delivers them to\n"
    "stillpointd, so the modules' threads have the time a live run gives them). Writes into --out:\n"
    "  report.md     machine and its speed (ORB extraction time at start and end), commit,\n"
    "                command, the accuracy table (ATE RMSE, RPE: median and\n"
    "                min-max over runs, and the share of frames with a pose), the runtime table\n"
    "                (semantic part per keyframe, geometry part and tracking per frame, frames\n"
    "                over 33 ms, keyframes per second, segmentations dropped, the newest\n"
    "                masks' age), the pose health's drift by level and by what lowered\n"
    "                it, plots, and\n"
    "                published figures of other systems beside ours\n"
    "  results.csv   one row per sequence x module set x run\n"
    "  plots/        per sequence and module set (first run): trajectory and ATE over time,\n"
    "                tracking time per frame, dynamic features per frame\n"
    "  runs/         every run's trajectory, frame log and replay output\n"
    "--modules: comma list of none, geometry, semantic, geometry+semantic (default: all four).\n"
    "--model-card: run each set with the semantic module once per model card (default: the\n"
    "replay's choice). --max-frames: only the first N frames of each sequence. --render-every N:\n"
    "pictures of every N-th frame of each first run (stillpoint-replay --render). --no-plots: the\n"
    "report and results.csv without the PNG plots (e.g. for a report kept under version control).\n"
    "A missing folder, a sequence without ground truth or a crashed run is a row that says so.\n"
    "exit status: 0 report written (whatever the runs did), 1 report not written, 2 usage error\n";

struct SequenceArg {
  std::string dir, camera, name;
};

struct Args {
  std::vector<SequenceArg> sequences;
  std::vector<std::string> modules{"none", "geometry", "semantic", "geometry+semantic"};
  std::vector<std::string> model_cards;
  std::string out, config, replay;
  int runs = 3;
  long max_frames = 0, render_every = 0;
  bool sequential = false, paced = false, plots = true;
};

bool parsePositive(const std::string& text, long* out) {
  char* end = nullptr;
  errno = 0;
  *out = std::strtol(text.c_str(), &end, 10);
  return !text.empty() && !*end && errno == 0 && *out > 0;
}

std::vector<std::string> splitComma(const std::string& s) {
  std::vector<std::string> parts;
  std::stringstream in(s);
  for (std::string part; std::getline(in, part, ',');) parts.push_back(part);
  return parts;
}

bool parseArgs(int argc, char** argv, Args* args, std::string* error) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    std::string v;
    auto value = [&] {
      if (i + 1 >= argc) {
        *error = "option " + a + " needs a value";
        return false;
      }
      v = argv[++i];
      return true;
    };
    long n = 0;
    if (a == "--sequence") {
      if (!value()) return false;
      const std::size_t colon = v.rfind(':');
      if (colon == std::string::npos || colon == 0 || colon + 1 == v.size()) {
        *error = "--sequence needs DIR:CAMERA, got '" + v + "'";
        return false;
      }
      SequenceArg s{v.substr(0, colon), v.substr(colon + 1), ""};
      s.name = fs::path(s.dir).lexically_normal().filename().string();
      if (s.name.empty()) s.name = fs::path(s.dir).lexically_normal().parent_path().filename().string();
      args->sequences.push_back(s);
    } else if (a == "--modules") {
      if (!value()) return false;
      args->modules = splitComma(v);
      for (const std::string& m : args->modules)
        if (m != "none" && m != "geometry" && m != "semantic" && m != "geometry+semantic") {
          *error = "--modules: unknown set '" + m + "' (none, geometry, semantic, geometry+semantic)";
          return false;
        }
      if (args->modules.empty()) {
        *error = "--modules needs at least one set";
        return false;
      }
    } else if (a == "--model-card") {
      if (!value()) return false;
      args->model_cards.push_back(v);
    } else if (a == "--runs") {
      if (!value()) return false;
      if (!parsePositive(v, &n) || n > 100) {
        *error = "--runs needs an integer 1..100";
        return false;
      }
      args->runs = static_cast<int>(n);
    } else if (a == "--max-frames") {
      if (!value()) return false;
      if (!parsePositive(v, &args->max_frames)) {
        *error = "--max-frames needs a positive integer";
        return false;
      }
    } else if (a == "--render-every") {
      if (!value()) return false;
      if (!parsePositive(v, &args->render_every)) {
        *error = "--render-every needs a positive integer";
        return false;
      }
    } else if (a == "--out") {
      if (!value()) return false;
      args->out = v;
    } else if (a == "--config") {
      if (!value()) return false;
      args->config = v;
    } else if (a == "--replay") {
      if (!value()) return false;
      args->replay = v;
    } else if (a == "--sequential") {
      args->sequential = true;
    } else if (a == "--paced") {
      args->paced = true;
    } else if (a == "--no-plots") {
      args->plots = false;
    } else {
      *error = "unknown argument " + a;
      return false;
    }
  }
  if (args->sequences.empty()) *error = "no --sequence given";
  else if (args->out.empty()) *error = "missing --out";
  else if (args->sequential && args->paced) *error = "--sequential and --paced exclude each other";
  // Two sequences of one name would share a run folder: number them.
  std::map<std::string, int> seen;
  for (SequenceArg& s : args->sequences)
    if (int k = seen[s.name]++; k > 0) s.name += "-" + std::to_string(k + 1);
  return error->empty();
}

// ---------------------------------------------------------------------------
// One run: a replay process and what it left behind.

struct FrameRecord {
  double t = 0;  // seconds
  std::string state;
  double track_ms = 0, geometry_ms = 0;
  int features = 0, in_pose = 0, geometry_dynamic = 0, semantic_dynamic = 0;
  bool keyframe = false;
  std::string health;  // empty in a log without the column
  // The newest semantic masks' age (infinity: none near the camera; NaN: not
  // known or a log without the column).
  double mask_age_s = NAN;
  std::string causes;  // what lowered the health, names joined by '+'; empty in a log without the column
};

struct RunResult {
  std::string sequence, modules, model;
  std::string model_used;  // the semantic model the replay names
  int run = 0;
  std::string status = "ok";  // ok, or what went wrong (crashed, missing folder, ...)
  std::string dir;            // relative to the output folder
  std::size_t frames = 0, frames_with_pose = 0, keyframes = 0, segmentations_dropped = 0;
  double ate = NAN, rpe_trans = NAN, rpe_rot = NAN;
  std::size_t maps = 0;       // maps the run's poses are in (new maps after losses)
  double ate_one_frame = NAN;  // ATE with every map in one frame (EvalResult::ate_one_frame_rmse_m)
  double track_median = NAN, track_p95 = NAN, geometry_median = NAN, segment_median = NAN;
  std::size_t over_33ms = 0;
  double keyframes_per_s = NAN, duration_s = 0;
  // Frames with a pose: the age of their newest semantic masks.
  double mask_age_median = NAN, mask_age_p90 = NAN;
  std::vector<FrameRecord> log;
  eval::Trajectory gt, est;
  Result<eval::EvalResult> eval = Error{"not evaluated"};
  std::vector<eval::LabelledDrift> drift;  // each pose's health and drift
  std::vector<eval::LabelledDrift> cause_drift;  // each pose's drift under each of its health causes
  std::vector<eval::NormalisedDrift> covered;     // each pose's health and drift over its covariance
};

// Runs argv with stdout and stderr into files; returns the wait status, or -1.
int spawnAndWait(const std::vector<std::string>& argv, const std::string& out_path, const std::string& err_path,
                 std::string* error) {
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, 1, out_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_addopen(&actions, 2, err_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  std::vector<char*> cargv;
  for (const std::string& a : argv) cargv.push_back(const_cast<char*>(a.c_str()));
  cargv.push_back(nullptr);
  pid_t pid = 0;
  const int rc = posix_spawn(&pid, cargv[0], &actions, nullptr, cargv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) {
    *error = std::string("cannot start ") + argv[0] + ": " + std::strerror(rc);
    return -1;
  }
  int status = 0;
  while (waitpid(pid, &status, 0) < 0) {
    if (errno != EINTR) {
      *error = std::string("waitpid: ") + std::strerror(errno);
      return -1;
    }
  }
  return status;
}

std::string lastLine(const std::string& path) {
  std::ifstream in(path);
  std::string line, last;
  while (std::getline(in, line))
    if (!line.empty()) last = line;
  return last;
}

// key=value from the replay's last line.
double lineValue(const std::string& line, const std::string& key) {
  const std::size_t at = line.find(key + "=");
  if (at == std::string::npos) return NAN;
  return std::strtod(line.c_str() + at + key.size() + 1, nullptr);
}

Result<std::vector<FrameRecord>> readFrameLog(const std::string& path) {
  std::ifstream in(path);
  if (!in) return Error{path + ": cannot read"};
  std::vector<FrameRecord> log;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    if (line.empty() || line[0] == '#') continue;
    std::istringstream fields(line);
    std::size_t index = 0;
    FrameRecord r;
    int keyframe = 0;
    if (!(fields >> index >> r.t >> r.state >> r.track_ms >> r.geometry_ms >> r.features >> r.in_pose >>
          r.geometry_dynamic >> r.semantic_dynamic >> keyframe))
      return Error{path + ":" + std::to_string(number) + ": malformed frame record"};
    r.keyframe = keyframe != 0;
    fields >> r.health;
    // dynamic_share outlier_share reprojection_rms_px conditioning, then the age
    // ("inf" too, which operator>> would refuse).
    std::string skipped, age, found_movers;
    for (int k = 0; k < 4; ++k) fields >> skipped;
    if (fields >> age) {
      char* end = nullptr;
      const double value = std::strtod(age.c_str(), &end);
      if (end != age.c_str() && *end == '\0' && value >= 0) r.mask_age_s = value;
    }
    fields >> found_movers >> r.causes;
    log.push_back(r);
  }
  return log;
}

bool hasPose(const std::string& state) { return state == "ok" || state == "relocalised" || state == "new_map"; }

void runOnce(const Args& args, const std::string& replay, const SequenceArg& seq, const std::string& modules,
             const std::string& card, int run, RunResult* r) {
  r->sequence = seq.name;
  r->modules = modules;
  r->model = card.empty() ? "" : fs::path(card).stem().string();
  r->run = run;
  const std::string label = modules + (r->model.empty() ? "" : "." + r->model);
  r->dir = "runs/" + seq.name + "/" + label + "/run" + std::to_string(run);
  const fs::path dir = fs::path(args.out) / r->dir;
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) {
    r->status = "cannot create " + dir.string();
    return;
  }
  if (!fs::is_directory(seq.dir)) {
    r->status = "missing folder";
    return;
  }
  std::vector<std::string> argv{replay, seq.dir, "--camera", seq.camera, "--output", (dir / "trajectory.txt").string(),
                                "--frame-log", (dir / "frames.txt").string(), "--modules",
                                modules == "geometry+semantic" ? "geometry,semantic" : modules};
  if (args.sequential) argv.push_back("--sequential");
  if (args.paced) argv.push_back("--paced");
  if (!args.config.empty()) argv.insert(argv.end(), {"--config", args.config});
  if (!card.empty()) argv.insert(argv.end(), {"--model-card", card});
  if (args.max_frames > 0) argv.insert(argv.end(), {"--max-frames", std::to_string(args.max_frames)});
  if (args.render_every > 0 && run == 1)
    argv.insert(argv.end(), {"--render", (dir / "render").string(), "--render-every", std::to_string(args.render_every)});
  std::string error;
  const int status = spawnAndWait(argv, (dir / "replay.log").string(), (dir / "replay.err").string(), &error);
  if (status < 0) {
    r->status = error;
    return;
  }
  if (WIFSIGNALED(status)) {
    r->status = std::string("crashed (") + strsignal(WTERMSIG(status)) + ")";
    return;
  }
  if (WEXITSTATUS(status) != 0) {
    const std::string why = lastLine((dir / "replay.err").string());
    r->status = "failed (exit " + std::to_string(WEXITSTATUS(status)) + (why.empty() ? "" : ": " + why) + ")";
    return;
  }
  const std::string summary = lastLine((dir / "replay.log").string());
  auto log = readFrameLog((dir / "frames.txt").string());
  if (!log) {
    r->status = log.error();
    return;
  }
  r->log = std::move(*log);
  r->frames = r->log.size();
  std::vector<double> track, geometry, ages;
  for (const FrameRecord& f : r->log) {
    if (f.state == "skipped") continue;
    if (hasPose(f.state) && !std::isnan(f.mask_age_s)) ages.push_back(f.mask_age_s);
    track.push_back(f.track_ms);
    if (f.geometry_ms > 0) geometry.push_back(f.geometry_ms);
    r->over_33ms += f.track_ms > 33.0;
    r->keyframes += f.keyframe;
  }
  r->track_median = quantile(track, 0.5);
  r->track_p95 = quantile(track, 0.95);
  r->geometry_median = quantile(geometry, 0.5);
  if (!ages.empty()) {
    r->mask_age_median = quantile(ages, 0.5);
    r->mask_age_p90 = quantile(ages, 0.9);
  }
  const bool semantic = modules.find("semantic") != std::string::npos;
  if (modules.find("geometry") == std::string::npos) r->geometry_median = NAN;
  r->segment_median = semantic ? lineValue(summary, "segment_ms_median") : NAN;
  if (semantic) {
    std::ifstream replay_log(dir / "replay.log");
    for (std::string line; std::getline(replay_log, line);) {
      if (line.rfind("semantic:", 0) != 0) continue;
      const std::size_t begin = line.find_first_not_of(' ', 9);
      if (begin != std::string::npos) r->model_used = line.substr(begin, line.find(" (", begin) - begin);
      break;
    }
  }
  const double dropped = lineValue(summary, "segmentations_dropped");
  r->segmentations_dropped = std::isfinite(dropped) ? static_cast<std::size_t>(dropped) : 0;
  if (r->log.size() > 1) r->duration_s = r->log.back().t - r->log.front().t;
  if (r->duration_s > 0) r->keyframes_per_s = r->keyframes / r->duration_s;

  // Frames with a pose are the poses the trajectory file holds.
  auto est = eval::readTumTrajectory((dir / "trajectory.txt").string());
  if (!est) {
    r->status = est.error();
    return;
  }
  r->est = std::move(*est);
  r->frames_with_pose = r->est.size();
  const fs::path gt_path = fs::path(seq.dir) / "groundtruth.txt";
  if (!fs::exists(gt_path)) {
    r->status = "no ground truth";
    return;
  }
  auto gt = eval::readTumTrajectory(gt_path.string());
  if (!gt) {
    r->status = "ground truth unusable: " + gt.error();
    return;
  }
  r->gt = std::move(*gt);
  r->eval = eval::evaluate(r->gt, r->est);
  if (!r->eval) {
    r->status = "evaluation failed: " + r->eval.error();
    return;
  }
  r->ate = r->eval->ate_rmse_m;
  r->maps = r->eval->maps;
  r->ate_one_frame = r->eval->ate_one_frame_rmse_m;
  r->rpe_trans = r->eval->rpe_trans_m_s;
  r->rpe_rot = r->eval->rpe_rot_deg_s;
  std::vector<eval::StampedLabel> health;
  for (const FrameRecord& f : r->log)
    if (!f.health.empty()) health.push_back({Timestamp::fromSeconds(f.t), f.health});
  if (auto drift = eval::driftPerPose(*r->eval, health); drift) r->drift = std::move(*drift);
  if (auto covariances = eval::readCovarianceColumn((dir / "frames.txt").string()); covariances)
    if (auto covered = eval::normalisedDriftPerPose(*r->eval, r->est, *covariances, health); covered)
      r->covered = std::move(*covered);
  std::vector<eval::StampedLabel> causes;
  for (const FrameRecord& f : r->log)
    if (!f.causes.empty()) causes.push_back({Timestamp::fromSeconds(f.t), f.causes});
  if (causes.empty()) return;
  if (auto drift = eval::driftPerPose(*r->eval, causes); drift) r->cause_drift = eval::splitLabels(*drift);
}

// ---------------------------------------------------------------------------
// Tables, plots, report.

std::string fmt(double v, int decimals) {
  if (!std::isfinite(v)) return "-";
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", decimals, v);
  return buf;
}

// "median (min-max)" over the finite values.
std::string spread(const std::vector<double>& values, int decimals) {
  std::vector<double> v;
  for (double x : values)
    if (std::isfinite(x)) v.push_back(x);
  if (v.empty()) return "-";
  const auto [lo, hi] = std::minmax_element(v.begin(), v.end());
  if (v.size() == 1) return fmt(v[0], decimals);
  return fmt(quantile(v, 0.5), decimals) + " (" + fmt(*lo, decimals) + "-" + fmt(*hi, decimals) + ")";
}

std::string csvField(const std::string& s) {
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string q = "\"";
  for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
  return q + "\"";
}

std::string readText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

std::string cpuModel() {
  std::ifstream in("/proc/cpuinfo");
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("model name", 0) == 0 || line.rfind("Model", 0) == 0) {
      const std::size_t colon = line.find(':');
      if (colon != std::string::npos) return line.substr(colon + 2);
    }
  }
  return "unknown";
}

std::string loadAverage() {
  std::string text = readText("/proc/loadavg");
  std::istringstream in(text);
  std::string a, b, c;
  in >> a >> b >> c;
  return a.empty() ? "unknown" : a + " " + b + " " + c;
}

// The host's speed as the runs met it: the median time of ORB extraction
// (1000 features, 8 levels, as orb_benchmark's first case) on the first frame
// of the first sequence, over 15 extractions after 3 to warm up. Tracking and
// segmentation times scale with it, and with the semantic module so do a
// live run's mask delays and its accuracy: reports from different hosts, or
// from one host on a slower day, compare through it.
std::string orbExtractionMs(const std::string& dir) {
  try {
    auto data = dataset::TumDataset::open(dir);
    if (!data) return "not measured: " + data.error();
    if (data->size() == 0) return "not measured: no frame";
    auto frame = data->load(0);
    if (!frame) return "not measured: " + frame.error();
    features::OrbExtractor orb(features::OrbOptions{});
    std::vector<cv::KeyPoint> keys;
    cv::Mat descriptors;
    std::vector<double> ms;
    for (int k = 0; k < 18; ++k) {
      const auto t0 = std::chrono::steady_clock::now();
      orb.extract(frame->gray, &keys, &descriptors);
      if (k >= 3) ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
    return fmt(quantile(ms, 0.5), 1) + " ms";
  } catch (const std::exception& e) {
    return std::string("not measured: ") + e.what();
  }
}

std::string nowUtc() {
  const std::time_t t = std::time(nullptr);
  char buf[64];
  std::strftime(buf, sizeof(buf), "%Y-%m-%d %H:%M:%S UTC", std::gmtime(&t));
  return buf;
}

struct Group {
  std::string sequence, label;
  std::vector<const RunResult*> runs;
};

std::string slug(const std::string& s) {
  std::string out;
  for (char c : s) out += std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '.' ? c : '_';
  return out;
}

// The first run that has a trajectory evaluated: its plots.
std::vector<std::string> writePlots(const std::string& out_dir, const Group& g, std::vector<std::string>* failures) {
  std::vector<std::string> written;
  const RunResult* r = nullptr;
  for (const RunResult* c : g.runs)
    if (!c->log.empty()) {
      r = c;
      break;
    }
  if (!r) return written;
  const std::string base = "plots/" + slug(g.sequence) + "." + slug(g.label);
  auto note = [&](const Status& s, const std::string& file) {
    if (s) written.push_back(file);
    else failures->push_back(s.error());
  };
  if (r->eval) {
    std::vector<double> errors;
    for (const eval::PoseError& e : r->eval->pose_errors) errors.push_back(e.ate_m);
    eval::PlotOptions options;
    options.title = g.sequence + ", " + g.label + ", run " + std::to_string(r->run);
    note(eval::writeTrajectoryPlot(out_dir + "/" + base + ".trajectory.png", r->eval->gt_matched,
                                   r->eval->est_aligned, errors, options),
         base + ".trajectory.png");
  }
  const double t0 = r->log.front().t;
  eval::SeriesPlot timing;
  timing.title = "tracking time per frame: " + g.sequence + ", " + g.label + ", run " + std::to_string(r->run);
  timing.x_label = "time since the first frame [s]";
  timing.y_label = "time [ms]";
  timing.series.resize(2);
  timing.series[0].label = "tracking (ORB included)";
  timing.series[1].label = "geometry module (tracking thread)";
  eval::SeriesPlot dynamic;
  dynamic.title = "features per frame, out of the pose and in it: " + g.sequence + ", " + g.label + ", run " + std::to_string(r->run);
  dynamic.x_label = timing.x_label;
  dynamic.y_label = "features per frame";
  dynamic.series.resize(3);
  dynamic.series[0].label = "dynamic by geometry";
  dynamic.series[1].label = "dynamic by semantic masks";
  dynamic.series[2].label = "in the pose (map inliers)";
  for (const FrameRecord& f : r->log) {
    const double t = f.t - t0;
    const bool skipped = f.state == "skipped";
    timing.series[0].x.push_back(t);
    timing.series[0].y.push_back(skipped ? NAN : f.track_ms);
    timing.series[1].x.push_back(t);
    timing.series[1].y.push_back(skipped ? NAN : f.geometry_ms);
    for (int k = 0; k < 3; ++k) dynamic.series[k].x.push_back(t);
    dynamic.series[0].y.push_back(skipped ? NAN : f.geometry_dynamic);
    dynamic.series[1].y.push_back(skipped ? NAN : f.semantic_dynamic);
    dynamic.series[2].y.push_back(hasPose(f.state) ? f.in_pose : NAN);
  }
  timing.reference = 33.0;
  timing.reference_label = "33 ms (30 Hz)";
  note(eval::writeSeriesPlot(out_dir + "/" + base + ".tracking_ms.png", timing), base + ".tracking_ms.png");
  note(eval::writeSeriesPlot(out_dir + "/" + base + ".dynamic.png", dynamic), base + ".dynamic.png");
  return written;
}

std::string commandLine(int argc, char** argv) {
  std::string s;
  for (int i = 0; i < argc; ++i) {
    std::string a = argv[i];
    if (a.find_first_of(" '\"$") != std::string::npos) a = "'" + a + "'";
    s += (i ? " " : "") + a;
  }
  return s;
}

std::string framesWithPose(const std::vector<const RunResult*>& runs) {
  std::size_t frames = 0, with_pose = 0;
  for (const RunResult* r : runs) {
    frames += r->frames;
    with_pose += r->frames_with_pose;
  }
  if (frames == 0) return "-";
  char buf[96];
  std::snprintf(buf, sizeof(buf), "%.1f %% (%zu / %zu)", 100.0 * with_pose / frames, with_pose, frames);
  return buf;
}

std::string statusOf(const std::vector<const RunResult*>& runs) {
  std::map<std::string, int> counts;
  for (const RunResult* r : runs) ++counts[r->status];
  std::string s;
  for (const auto& [status, n] : counts) s += (s.empty() ? "" : "; ") + status + (runs.size() > 1 ? " x" + std::to_string(n) : "");
  return s;
}

// What the host was like when the runs began (and, for the report, ended).
struct HostState {
  std::string load;     // load average, 1, 5, 15 min
  std::string orb_ms;   // orbExtractionMs
};

HostState hostState(const Args& args) {
  return {loadAverage(), args.sequences.empty() ? "not measured: no sequence" : orbExtractionMs(args.sequences.front().dir)};
}

bool writeReport(const Args& args, const std::string& command, const std::string& started, const HostState& start,
                 const std::vector<Group>& groups, const std::vector<RunResult>& results, std::string* error) {
  const std::string out_dir = args.out;
  std::vector<std::string> plot_failures;
  std::map<std::string, std::vector<std::string>> plots;
  if (args.plots)
    for (const Group& g : groups) plots[g.sequence + "|" + g.label] = writePlots(out_dir, g, &plot_failures);

  std::ostringstream md;
  md << "# stillpoint bench report\n\n";
  md << "| | |\n|---|---|\n";
  md << "| stillpoint | " << STILLPOINT_VERSION << ", commit " << STILLPOINT_COMMIT << " (" << STILLPOINT_ARCH << ") |\n";
  md << "| machine | " << cpuModel() << ", " << std::thread::hardware_concurrency() << " cores |\n";
  const HostState end = hostState(args);
  md << "| load average (1, 5, 15 min) | at start " << start.load << "; at end " << end.load << " |\n";
  md << "| host speed: ORB extraction, 1000 features, first frame | at start " << start.orb_ms << "; at end "
     << end.orb_ms << " |\n";
  md << "| started | " << started << " |\n";
  md << "| mode | "
     << (args.sequential ? "sequential (one thread, deterministic)"
         : args.paced    ? "threaded (as stillpointd runs), paced at the recorded frame rate"
                         : "threaded (as stillpointd runs), as fast as tracking goes")
     << ", " << args.runs << (args.runs == 1 ? " run" : " runs") << " per cell"
     << (args.max_frames > 0 ? ", first " + std::to_string(args.max_frames) + " frames" : "") << " |\n";
  md << "| command | `" << command << "` |\n\n";

  md << "## Accuracy\n\n";
  md << "ATE RMSE after SE3 alignment, RPE over 1 s pose pairs: median over the runs (min-max). Frames with a pose: "
        "over all runs; a lost frame has none, and the ATE covers only the frames with a pose.\n\n";
  md << "<!-- bench-summary: begin -->\n";
  md << "| Sequence | Modules | ATE [m] | RPE [m/s] | RPE [deg/s] | Frames with a pose | Runs |\n";
  md << "|---|---|---|---|---|---|---|\n";
  for (const Group& g : groups) {
    std::vector<double> ate, rt, rr;
    for (const RunResult* r : g.runs) {
      ate.push_back(r->ate);
      rt.push_back(r->rpe_trans);
      rr.push_back(r->rpe_rot);
    }
    md << "| `" << g.sequence << "` | " << g.label << " | " << spread(ate, 4) << " | " << spread(rt, 4) << " | "
       << spread(rr, 3) << " | " << framesWithPose(g.runs) << " | " << statusOf(g.runs) << " |\n";
  }
  md << "<!-- bench-summary: end -->\n\n";
  // Runs whose poses are in more than one map: the table aligns each map on
  // its own; a consumer that ignores the map id takes them in one frame.
  std::ostringstream several;
  for (const RunResult& r : results)
    if (r.maps > 1)
      several << "| `" << r.sequence << "` | " << r.modules << " | " << r.run << " | " << r.maps << " | "
              << fmt(r.ate, 4) << " | " << fmt(r.ate_one_frame, 4) << " |\n";
  if (!several.str().empty()) {
    md << "Runs that started a new map after a loss, whose ATE above aligns each map on its own; a new map starts "
          "where the camera was last posed, and taken in one frame, as a consumer that ignores the map id takes "
          "them, the poses are off by what the camera moved unseen:\n\n";
    md << "| Sequence | Modules | Run | Maps | ATE, each map on its own [m] | ATE, in one frame [m] |\n";
    md << "|---|---|---|---|---|---|\n" << several.str() << "\n";
  }

  md << "## Pose health\n\n";
  md << "How far off the poses of each health level were, over all sequences and runs of a module set: the "
        "translation error of the motion over the last 1/3 s up to the pose (10 frames at 30 Hz; "
        "`stillpoint-eval --frame-log`), which a consumer trusting the level would have taken in.\n\n";
  // The module sets, and one module set's per-pose values over all its runs.
  std::vector<std::string> module_sets;
  for (const Group& g : groups)
    if (std::find(module_sets.begin(), module_sets.end(), g.label) == module_sets.end())
      module_sets.push_back(g.label);
  const auto pooled = [&groups]<typename T>(const std::string& label, std::vector<T> RunResult::*values) {
    std::vector<T> all;
    for (const Group& g : groups)
      if (g.label == label)
        for (const RunResult* r : g.runs) all.insert(all.end(), (r->*values).begin(), (r->*values).end());
    return all;
  };
  // One table per labelling of the poses: by health level, and by what lowered it.
  const auto driftTable = [&](const char* what, const eval::DriftOptions& drift_options,
                              std::vector<eval::LabelledDrift> RunResult::*drift) {
    md << "| Modules | " << what << " | Poses | Median [m] | p90 [m] | Max [m] | Over 2 cm |\n";
    md << "|---|---|---|---|---|---|---|\n";
    for (const std::string& label : module_sets) {
      for (const eval::LabelDrift& d : eval::summariseDrift(pooled(label, drift), drift_options))
        md << "| " << label << " | " << d.label << " | " << d.poses << " | " << fmt(d.median_m, 4) << " | "
           << fmt(d.p90_m, 4) << " | " << fmt(d.max_m, 4) << " | " << fmt(100.0 * d.share_over_bound, 1) << " % |\n";
    }
    md << "\n";
  };
  driftTable("Health", eval::poseHealthDriftOptions(), &RunResult::drift);
  md << "## What lowered the pose health\n\n";
  md << "The same poses by what lowered their health (`health_causes`, [pose-health.md](../pose-health.md)): a pose "
        "counts under each of its causes, and `none` holds the good ones.\n\n";
  driftTable("Cause", eval::healthCauseDriftOptions(), &RunResult::cause_drift);
  md << "## How well the pose covariance covers the drift\n\n";
  md << "The same drift against the covariance the poses carry ([pose-health.md](../pose-health.md), \"The "
        "covariance\"; `stillpoint-eval --frame-log` per run): the share of drifts inside the covariance's 95 % "
        "ellipsoid, and the median squared drift over the covariance, over a Gaussian's (1: as wide as it should be, "
        "above 1: too narrow), translation and rotation apart, per health level and for all poses.\n\n";
  md << "| Modules | Health | Poses | Position within | Position median | Rotation within | Rotation median |\n";
  md << "|---|---|---|---|---|---|---|\n";
  for (const std::string& label : module_sets)
    for (const eval::CovarianceCoverage& c :
         eval::summariseCoverage(pooled(label, &RunResult::covered), eval::poseHealthDriftOptions()))
      md << "| " << label << " | " << c.label << " | " << c.poses << " | " << fmt(100.0 * c.position_within, 1)
         << " % | " << fmt(c.position_median, 2) << " | " << fmt(100.0 * c.rotation_within, 1) << " % | "
         << fmt(c.rotation_median, 2) << " |\n";
  md << "\n";

  md << "## Runtime\n\n";
  md << "Per the paper's Table IV: the semantic part per segmented keyframe (its own thread), the geometry part "
        "per frame (in the tracking thread), tracking per frame (ORB extraction included): medians over the runs.\n\n";
  md << "| Sequence | Modules | Semantic model | Semantic per keyframe [ms] | Geometry per frame [ms] | "
        "Tracking median [ms] | Tracking p95 [ms] | Frames over 33 ms | Keyframes per s | Segmentations dropped | "
        "Masks' age median, p90 [s] |\n";
  md << "|---|---|---|---|---|---|---|---|---|---|---|\n";
  // Masks' age: infinity where no keyframe near the camera had masks.
  const auto seconds = [](double v) { return std::isinf(v) ? std::string("inf") : fmt(v, 2); };
  for (const Group& g : groups) {
    std::vector<double> seg, geo, med, p95, over, kfs, dropped, age, aged;
    for (const RunResult* r : g.runs) {
      if (r->log.empty()) continue;
      if (std::isfinite(r->segment_median)) seg.push_back(r->segment_median);
      if (std::isfinite(r->geometry_median)) geo.push_back(r->geometry_median);
      med.push_back(r->track_median);
      p95.push_back(r->track_p95);
      over.push_back(r->frames ? 100.0 * r->over_33ms / r->frames : NAN);
      kfs.push_back(r->keyframes_per_s);
      dropped.push_back(static_cast<double>(r->segmentations_dropped));
      if (!std::isnan(r->mask_age_median)) age.push_back(r->mask_age_median), aged.push_back(r->mask_age_p90);
    }
    std::string model = "-";
    for (const RunResult* r : g.runs)
      if (!r->model_used.empty()) model = r->model_used;
    md << "| `" << g.sequence << "` | " << g.label << " | " << model << " | " << fmt(quantile(seg, 0.5), 1) << " | "
       << fmt(quantile(geo, 0.5), 2) << " | " << fmt(quantile(med, 0.5), 2) << " | " << fmt(quantile(p95, 0.5), 2)
       << " | " << (over.empty() ? "-" : fmt(quantile(over, 0.5), 1) + " %") << " | " << fmt(quantile(kfs, 0.5), 2)
       << " | " << (g.label.find("semantic") != std::string::npos ? fmt(quantile(dropped, 0.5), 0) : "-") << " | "
       << (age.empty() ? "-" : seconds(quantile(age, 0.5)) + ", " + seconds(quantile(aged, 0.5))) << " |\n";
  }

  md << "\n## Published figures (other systems, other hardware)\n\n";
  const std::vector<bench::PublishedFigure> published = bench::publishedFigures();
  bool any = false;
  for (const SequenceArg& s : args.sequences) {
    for (const bench::PublishedFigure& p : published) {
      if (s.name.find(p.sequence_key) == std::string::npos) continue;
      if (!any)
        md << "ATE RMSE as published, on the full TUM sequences, on the authors' hardware; not measured here.\n\n"
              "| Sequence | System | ATE [m] | Source |\n|---|---|---|---|\n";
      any = true;
      md << "| `" << s.name << "` | " << p.system << " | " << fmt(p.ate_m, 4) << " | " << p.source << " |\n";
    }
  }
  if (!any)
    md << "None of these sequences is one of the TUM dynamic sequences with published figures (folder names "
          "containing e.g. `walking_xyz`, `sitting_static`).\n";

  md << "\n## Plots\n\n";
  if (!args.plots) md << "Not drawn (--no-plots).\n";
  for (const Group& g : groups) {
    const auto& files = plots[g.sequence + "|" + g.label];
    if (files.empty()) continue;
    md << "### `" << g.sequence << "`, " << g.label << "\n\n";
    for (const std::string& f : files) md << "![" << f << "](" << f << ")\n";
    md << "\n";
  }
  if (!plot_failures.empty()) {
    md << "Plots not written:\n\n";
    for (const std::string& f : plot_failures) md << "- " << f << "\n";
  }

  std::ofstream report(out_dir + "/report.md", std::ios::trunc);
  report << md.str();
  if (!report.flush()) {
    *error = out_dir + "/report.md: write failed";
    return false;
  }

  std::ofstream csv(out_dir + "/results.csv", std::ios::trunc);
  csv << "sequence,modules,model,run,status,ate_rmse_m,rpe_trans_m_s,rpe_rot_deg_s,maps,ate_one_frame_rmse_m,frames,"
         "frames_with_pose,track_ms_median,track_ms_p95,frames_over_33ms,geometry_ms_median,segment_ms_median,keyframes,"
         "keyframes_per_s,segmentations_dropped,trajectory\n";
  for (const RunResult& r : results) {
    csv << csvField(r.sequence) << "," << r.modules << "," << csvField(r.model) << "," << r.run << ","
        << csvField(r.status) << "," << fmt(r.ate, 6) << "," << fmt(r.rpe_trans, 6) << "," << fmt(r.rpe_rot, 6)
        << "," << r.maps << "," << fmt(r.ate_one_frame, 6) << "," << r.frames << "," << r.frames_with_pose << ","
        << fmt(r.track_median, 3) << ","
        << fmt(r.track_p95, 3) << "," << r.over_33ms << "," << fmt(r.geometry_median, 3) << ","
        << fmt(r.segment_median, 3) << "," << r.keyframes << "," << fmt(r.keyframes_per_s, 3) << ","
        << r.segmentations_dropped << "," << csvField(r.dir + "/trajectory.txt") << "\n";
  }
  if (!csv.flush()) {
    *error = out_dir + "/results.csv: write failed";
    return false;
  }
  return true;
}

fs::path replayBesideSelf() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  return ec ? fs::path("stillpoint-replay") : self.parent_path() / "stillpoint-replay";
}

int benchMain(int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--help") || !std::strcmp(argv[i], "-h")) {
      std::fputs(kUsage, stdout);
      return 0;
    }
    if (!std::strcmp(argv[i], "--version")) {
      std::puts("stillpoint-bench " STILLPOINT_VERSION " (" STILLPOINT_ARCH ")");
      return 0;
    }
  }
  Args args;
  std::string error;
  if (!parseArgs(argc, argv, &args, &error)) {
    std::fprintf(stderr, "stillpoint-bench: %s\n\n%s", error.c_str(), kUsage);
    return 2;
  }
  const std::string replay = args.replay.empty() ? replayBesideSelf().string() : args.replay;
  if (access(replay.c_str(), X_OK) != 0) {
    std::fprintf(stderr, "stillpoint-bench: %s is not an executable stillpoint-replay (--replay PATH)\n",
                 replay.c_str());
    return 1;
  }
  std::error_code ec;
  fs::create_directories(fs::path(args.out) / (args.plots ? "plots" : ""), ec);
  if (ec) {
    std::fprintf(stderr, "stillpoint-bench: cannot create %s: %s\n", args.out.c_str(), ec.message().c_str());
    return 1;
  }
  const std::string started = nowUtc();
  const HostState start = hostState(args);
  const std::string command = commandLine(argc, argv);

  std::vector<std::string> cards = args.model_cards;
  if (cards.empty()) cards.push_back("");
  std::vector<RunResult> results;
  std::vector<std::pair<std::string, std::string>> cells;  // modules, card
  for (const std::string& m : args.modules) {
    if (m.find("semantic") == std::string::npos) cells.push_back({m, ""});
    else
      for (const std::string& c : cards) cells.push_back({m, c});
  }
  const std::size_t total = args.sequences.size() * cells.size() * args.runs;
  results.reserve(total);
  const auto t0 = std::chrono::steady_clock::now();
  for (const SequenceArg& seq : args.sequences) {
    for (const auto& [modules, card] : cells) {
      for (int run = 1; run <= args.runs; ++run) {
        RunResult& r = results.emplace_back();
        runOnce(args, replay, seq, modules, card, run, &r);
        const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        std::fprintf(stderr, "[%zu/%zu %.0f s] %s %s%s run %d: %s ate=%s m, %zu/%zu frames with a pose\n",
                     results.size(), total, elapsed, seq.name.c_str(), modules.c_str(),
                     r.model.empty() ? "" : (" (" + r.model + ")").c_str(), run, r.status.c_str(),
                     fmt(r.ate, 4).c_str(), r.frames_with_pose, r.frames);
      }
    }
  }
  std::vector<Group> groups;
  for (const RunResult& r : results) {
    const std::string label = r.modules + (r.model.empty() ? "" : " (" + r.model + ")");
    if (groups.empty() || groups.back().sequence != r.sequence || groups.back().label != label)
      groups.push_back({r.sequence, label, {}});
    groups.back().runs.push_back(&r);
  }
  if (!writeReport(args, command, started, start, groups, results, &error)) {
    std::fprintf(stderr, "stillpoint-bench: %s\n", error.c_str());
    return 1;
  }
  std::printf("report: %s/report.md\nresults: %s/results.csv\n", args.out.c_str(), args.out.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) { return stillpoint::runProgram("stillpoint-bench", benchMain, argc, argv); }
