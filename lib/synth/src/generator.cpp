#include "stillpoint/core/files.hpp"
#include "stillpoint/synth/generator.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <thread>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <yaml-cpp/yaml.h>

#include "png_writer.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/eval/metrics.hpp"
#include "stillpoint/eval/trajectory.hpp"
#include "stillpoint/synth/room.hpp"
#include "stillpoint/synth/sensor.hpp"

namespace stillpoint::synth {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

struct FrameResult {
  std::vector<long> pixels;  // per mover id (index 0 unused)
  double load_ms = 0, render_ms = 0, write_ms = 0;
};

// Runs fn(i) for i in [0, n) on `threads` workers; stops at the first error.
Status runParallel(std::size_t n, int threads, const std::function<Status(std::size_t)>& fn) {
  std::atomic<std::size_t> next{0};
  std::atomic<bool> failed{false};
  std::mutex error_mutex;
  std::string error;
  auto work = [&] {
    for (;;) {
      const std::size_t i = next.fetch_add(1);
      if (i >= n || failed.load()) return;
      Status s;
      try {
        s = fn(i);
      } catch (const std::exception& e) {
        s = Error{std::string("frame ") + std::to_string(i) + ": " + e.what()};
      }
      if (!s) {
        std::lock_guard lock(error_mutex);
        if (!failed.exchange(true)) error = s.error();
        return;
      }
    }
  };
  {
    std::vector<std::jthread> pool;
    for (int k = 1; k < std::max(1, threads); ++k) pool.emplace_back(work);
    work();
  }  // joins
  if (failed) return Error{error};
  return Status::success();
}

Status writePng(const fs::path& path, const cv::Mat& image, int compression) {
  if (compression == 0) return writeStoredPng(path.string(), image);
  try {
    if (cv::imwrite(path.string(), image, {cv::IMWRITE_PNG_COMPRESSION, compression})) return Status::success();
  } catch (const std::exception& e) {
    return Error{"cannot write " + path.string() + ": " + e.what()};
  }
  return Error{"cannot write " + path.string()};
}

Status makeDirs(const fs::path& root) {
  std::error_code ec;
  for (const char* sub : {"rgb", "depth", "mask"}) {
    fs::create_directories(root / sub, ec);
    if (ec) return Error{"cannot create " + (root / sub).string() + ": " + ec.message()};
  }
  return Status::success();
}

// Pose at `t` by linear/slerp interpolation between ground-truth poses at most
// max_gap_s apart; nullopt outside the trajectory.
std::optional<SE3> interpolatePose(const eval::Trajectory& gt, Timestamp t, double max_gap_s) {
  auto it = std::lower_bound(gt.begin(), gt.end(), t,
                             [](const eval::StampedPose& p, Timestamp s) { return p.stamp < s; });
  if (it == gt.end()) return std::nullopt;
  if (it->stamp == t) return it->T_w_c;
  if (it == gt.begin()) return std::nullopt;
  const eval::StampedPose& b = *it;
  const eval::StampedPose& a = *(it - 1);
  const double span = secondsBetween(b.stamp, a.stamp);
  if (span > max_gap_s) return std::nullopt;
  const double f = secondsBetween(t, a.stamp) / span;
  const Eigen::Quaterniond qa(a.T_w_c.linear()), qb(b.T_w_c.linear());
  return makeSE3(qa.slerp(f, qb), (1 - f) * a.T_w_c.translation() + f * b.T_w_c.translation());
}

void countPixels(const cv::Mat& mask, std::vector<long>* pixels) {
  for (int y = 0; y < mask.rows; ++y) {
    const std::uint16_t* m = mask.ptr<std::uint16_t>(y);
    for (int x = 0; x < mask.cols; ++x) {
      if (m[x] && m[x] < pixels->size()) ++(*pixels)[m[x]];
    }
  }
}

void summarise(const std::vector<FrameResult>& results, const SynthConfig& config, int width,
               int height, GenerationReport* report) {
  const double total = static_cast<double>(width) * height;
  report->frames = static_cast<int>(results.size());
  report->movers.resize(config.movers.size());
  for (std::size_t k = 0; k < config.movers.size(); ++k) report->movers[k].name = config.movers[k].name;
  double cov_sum = 0;
  for (const FrameResult& r : results) {
    long any = 0;
    for (std::size_t k = 1; k < r.pixels.size(); ++k) {
      any += r.pixels[k];
      MoverStats& m = report->movers[k - 1];
      const double c = r.pixels[k] / total;
      if (r.pixels[k] > 0) ++m.frames_visible;
      m.mean_coverage += c;
      m.max_coverage = std::max(m.max_coverage, c);
    }
    const double c = any / total;
    if (any > 0) ++report->frames_with_movers;
    cov_sum += c;
    report->coverage_max = std::max(report->coverage_max, c);
    report->load_ms += r.load_ms;
    report->render_ms += r.render_ms;
    report->write_ms += r.write_ms;
  }
  if (!results.empty()) {
    report->coverage_mean = cov_sum / results.size();
    for (MoverStats& m : report->movers) m.mean_coverage /= results.size();
  }
}

void emitVec(YAML::Emitter& e, const Vec3& v) {
  e << YAML::Flow << YAML::BeginSeq << v.x() << v.y() << v.z() << YAML::EndSeq;
}

// movers.txt: one line per frame and mover, "timestamp id speed_m_s" (moverSpeed).
std::string moverSpeedLines(const SynthConfig& config, const std::string& stamp, double t) {
  std::string out;
  char line[160];
  for (std::size_t k = 0; k < config.movers.size(); ++k) {
    std::snprintf(line, sizeof(line), "%s %zu %.4f\n", stamp.c_str(), k + 1, moverSpeed(config.movers[k], t));
    out += line;
  }
  return out;
}

constexpr const char* kMoverSpeedHeader =
    "# mover speeds: an upper bound on the speed of any point of the mover (m/s)\n"
    "# timestamp id speed_m_s\n";

Status writeMoversYaml(const fs::path& path, const std::string& mode, const std::string& source,
                       const SynthConfig& c, const CameraModel& cam, const SE3& T_w_s,
                       const GenerationReport& r) {
  YAML::Emitter e;
  e.SetDoublePrecision(6);
  e << YAML::Comment("stillpoint-synth: what was placed; mask value = id");
  e << YAML::BeginMap;
  e << YAML::Key << "mode" << YAML::Value << mode;
  e << YAML::Key << "source" << YAML::Value << source;
  e << YAML::Key << "seed" << YAML::Value << c.seed;
  e << YAML::Key << "camera" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "width"
    << YAML::Value << cam.width << YAML::Key << "height" << YAML::Value << cam.height << YAML::Key << "fx"
    << YAML::Value << cam.fx << YAML::Key << "fy" << YAML::Value << cam.fy << YAML::Key << "cx"
    << YAML::Value << cam.cx << YAML::Key << "cy" << YAML::Value << cam.cy << YAML::EndMap;
  const Eigen::Quaterniond q(T_w_s.linear());
  e << YAML::Key << "stage_T_w_s" << YAML::Value << YAML::Flow << YAML::BeginSeq << T_w_s.translation().x()
    << T_w_s.translation().y() << T_w_s.translation().z() << q.x() << q.y() << q.z() << q.w() << YAML::EndSeq;
  e << YAML::Key << "frames" << YAML::Value << r.frames;
  e << YAML::Key << "frames_with_movers" << YAML::Value << r.frames_with_movers;
  e << YAML::Key << "coverage_mean" << YAML::Value << r.coverage_mean;
  e << YAML::Key << "coverage_max" << YAML::Value << r.coverage_max;
  e << YAML::Key << "motion_blur" << YAML::Value << c.blur.enabled;
  e << YAML::Key << "movers" << YAML::Value << YAML::BeginSeq;
  for (std::size_t k = 0; k < c.movers.size(); ++k) {
    const MoverSpec& m = c.movers[k];
    e << YAML::BeginMap;
    e << YAML::Key << "id" << YAML::Value << k + 1;
    e << YAML::Key << "name" << YAML::Value << m.name;
    e << YAML::Key << "shape" << YAML::Value << toString(m.shape);
    e << YAML::Key << "texture" << YAML::Value << m.texture;
    if (!m.cutout.empty()) e << YAML::Key << "cutout" << YAML::Value << m.cutout;
    if (m.cropped()) {
      e << YAML::Key << "crop" << YAML::Value << YAML::Flow << YAML::BeginSeq;
      for (double v : m.crop) e << v;
      e << YAML::EndSeq;
    }
    if (!m.video.empty()) e << YAML::Key << "video" << YAML::Value << m.video;
    if (m.face_camera) e << YAML::Key << "face_camera" << YAML::Value << true;
    e << YAML::Key << "size" << YAML::Value;
    emitVec(e, m.size);
    e << YAML::Key << "yaw_deg" << YAML::Value << m.yaw_deg;
    e << YAML::Key << "yaw_rate_deg_s" << YAML::Value << m.yaw_rate_deg_s;
    e << YAML::Key << "path" << YAML::Value << YAML::BeginMap;
    e << YAML::Key << "type" << YAML::Value << toString(m.path.type);
    e << YAML::Key << "start" << YAML::Value;
    emitVec(e, m.path.start);
    e << YAML::Key << "end" << YAML::Value;
    emitVec(e, m.path.end);
    e << YAML::Key << "speed" << YAML::Value << m.path.speed_m_s;
    e << YAML::Key << "period_s" << YAML::Value << m.path.period_s;
    e << YAML::Key << "hold_s" << YAML::Value << m.path.hold_s;
    e << YAML::Key << "go_s" << YAML::Value << m.path.go_s;
    e << YAML::Key << "stop_s" << YAML::Value << m.path.stop_s;
    e << YAML::Key << "phase_s" << YAML::Value << m.path.phase_s;
    e << YAML::EndMap;
    if (k < r.movers.size()) {
      e << YAML::Key << "frames_visible" << YAML::Value << r.movers[k].frames_visible;
      e << YAML::Key << "coverage_mean" << YAML::Value << r.movers[k].mean_coverage;
      e << YAML::Key << "coverage_max" << YAML::Value << r.movers[k].max_coverage;
    }
    e << YAML::EndMap;
  }
  e << YAML::EndSeq << YAML::EndMap;
  return writeTextFile(path, std::string(e.c_str()) + "\n");
}

// The trajectory at `path`, mapped into the ground truth's world by the rigid
// alignment of its positions (one map, at least 10 poses matched within 20 ms).
Result<eval::Trajectory> renderPoses(const std::string& path, const eval::Trajectory& gt) {
  Result<eval::Trajectory> poses = eval::readTumTrajectory(path);
  if (!poses.ok()) return Error{"--render-poses: " + poses.error()};
  if (poses->empty()) return Error{"--render-poses: " + path + ": no poses"};
  for (const eval::StampedPose& p : *poses)
    if (p.map_id != poses->front().map_id) return Error{"--render-poses: " + path + " holds more than one map"};
  const std::vector<eval::Match> matches = eval::associate(*poses, gt, 0.02);
  constexpr std::size_t kMinMatches = 10;
  if (matches.size() < kMinMatches)
    return Error{"--render-poses: " + path + ": " + std::to_string(matches.size()) +
                 " poses lie within 20 ms of groundtruth.txt, at least " + std::to_string(kMinMatches) + " needed"};
  std::vector<Vec3> from, to;
  for (const eval::Match& m : matches) {
    from.push_back((*poses)[m.est_index].T_w_c.translation());
    to.push_back(gt[m.gt_index].T_w_c.translation());
  }
  Result<eval::Alignment> a = eval::alignUmeyama(from, to, false);
  if (!a.ok()) return Error{"--render-poses: " + path + ": " + a.error()};
  for (eval::StampedPose& p : *poses) p.T_w_c = a->apply(p.T_w_c);
  return poses;
}

}  // namespace

std::uint64_t frameSeed(std::uint64_t seed, std::size_t index) {
  std::uint64_t x = seed * 0x9E3779B97F4A7C15ULL + index * 0xD1B54A32D192ED03ULL + 0x632BE59BD9B4E019ULL;
  x = (x ^ (x >> 29)) * 0xBF58476D1CE4E5B9ULL;
  return x ^ (x >> 32);
}

Result<MoverRenderer> MoverRenderer::create(const SynthConfig& config, const SE3& T_w_s) {
  if (Status s = config.validate(); !s) return Error{s.error()};
  MoverRenderer r;
  r.specs_ = config.movers;
  r.blur_ = config.blur;
  r.T_w_s_ = T_w_s;
  for (std::size_t k = 0; k < config.movers.size(); ++k) {
    Result<MoverTextures> t = makeMoverTextures(config.movers[k], config.base_dir, config.seed * 7919 + k);
    if (!t.ok()) return Error{t.error()};
    r.textures_.push_back(*t);
  }
  return r;
}

void MoverRenderer::drawAt(double t, const SE3& T_w_c, const CameraModel& camera, RenderTarget* target) const {
  Mesh mesh;
  for (std::size_t k = 0; k < specs_.size(); ++k) {
    addMover(&mesh, specs_[k], textures_[k], T_w_s_, t, static_cast<std::uint16_t>(k + 1), T_w_c.translation());
  }
  synth::render(mesh, T_w_c, camera, target);
}

void MoverRenderer::render(double t, const SE3& T_w_c, const CameraModel& camera, RenderTarget* target) const {
  if (!blur_.enabled || blur_.samples < 2 || blur_.exposure_s <= 0) {
    drawAt(t, T_w_c, camera, target);
    return;
  }
  const RenderTarget base{target->colour.clone(), target->depth.clone(), target->id.clone()};
  cv::Mat sum(base.colour.size(), CV_32FC3, cv::Scalar::all(0));
  cv::Mat touched(base.colour.size(), CV_16UC1, cv::Scalar(0));
  const int n = blur_.samples;
  const int centre = n / 2;
  for (int s = 0; s < n; ++s) {
    RenderTarget sub{base.colour.clone(), base.depth.clone(), base.id.clone()};
    const double ts = t + blur_.exposure_s * (static_cast<double>(s) / (n - 1) - 0.5);
    drawAt(ts, T_w_c, camera, &sub);
    cv::accumulate(sub.colour, sum);
    // Movers' ids where a sub-frame drew a mover (the background's id is kept).
    cv::Mat drawn = sub.id != base.id;
    sub.id.copyTo(touched, drawn & (touched == 0));
    if (s == centre) {
      sub.depth.copyTo(target->depth);
      sub.id.copyTo(target->id);
    }
  }
  cv::Mat average;
  sum.convertTo(average, CV_8UC3, 1.0 / n);
  const cv::Mat any = touched != 0;
  average.copyTo(target->colour, any);
  // Pixels only some sub-frames covered carry the id of one that did.
  touched.copyTo(target->id, any & (target->id == base.id));
}

CompositeFrame composeOverlay(const MoverRenderer& movers, const cv::Mat& bgr, const cv::Mat& depth_raw,
                              double t, const SE3& T_w_c, const CameraModel& camera,
                              const DepthSensorOptions& sensor, std::uint64_t noise_seed) {
  RenderTarget target;
  target.colour = bgr.clone();
  depth_raw.convertTo(target.depth, CV_32FC1, 1.0 / sensor.depth_factor);
  target.depth.setTo(std::numeric_limits<float>::infinity(), depth_raw == 0);
  target.id = cv::Mat(bgr.size(), CV_16UC1, cv::Scalar(0));
  movers.render(t, T_w_c, camera, &target);
  CompositeFrame out;
  out.bgr = target.colour;
  out.depth = depth_raw.clone();
  out.mask = target.id;
  const cv::Mat select = out.mask != 0;
  if (cv::countNonZero(select) > 0) applyDepthSensor(target.depth, select, sensor, noise_seed, &out.depth);
  return out;
}

Result<GenerationReport> generateOverlay(const std::string& input_dir, const std::string& output_dir,
                                         const CameraModel& camera, const SynthConfig& config,
                                         const GenerateOptions& options) {
  const auto wall_start = Clock::now();
  if (Status s = config.validate(); !s) return Error{s.error()};
  dataset::DatasetOptions dopt;
  dopt.expected_width = camera.width;
  dopt.expected_height = camera.height;
  dopt.depth_factor = camera.depth_factor;
  Result<dataset::TumDataset> data = dataset::TumDataset::open(input_dir, dopt);
  if (!data.ok()) return Error{data.error()};
  if (!data->hasGroundTruth()) return Error{"overlay input '" + input_dir + "' has no groundtruth.txt"};
  Result<eval::Trajectory> gt = eval::readTumTrajectory(data->groundTruthPath());
  if (!gt.ok()) return Error{gt.error()};
  if (gt->empty()) return Error{data->groundTruthPath() + ": no poses"};
  constexpr double kMaxPoseGap = 0.1;  // s between ground-truth samples
  // The poses the movers are placed by; only frames the ground truth scores
  // are written (the render poses may span more).
  Result<eval::Trajectory> rendered = eval::Trajectory{};
  if (!options.render_poses.empty()) rendered = renderPoses(options.render_poses, *gt);
  if (!rendered.ok()) return Error{rendered.error()};
  const bool by_gt = options.render_poses.empty();
  const eval::Trajectory& placed = by_gt ? *gt : *rendered;
  const auto placement = [&](Timestamp t) -> std::optional<SE3> {
    if (!by_gt && !interpolatePose(*gt, t, kMaxPoseGap)) return std::nullopt;
    return interpolatePose(placed, t, kMaxPoseGap);
  };

  // The first frame with a pose fixes the time origin and the stage frame.
  std::size_t first = data->size();
  Timestamp t0;
  SE3 T_w_c0 = SE3::Identity();
  for (std::size_t i = 0; i < data->size(); ++i) {
    Result<dataset::RgbdFrame> f = data->load(i);
    if (!f.ok()) continue;
    if (std::optional<SE3> T = placement(f->stamp)) {
      first = i;
      t0 = f->stamp;
      T_w_c0 = *T;
      break;
    }
  }
  if (first == data->size()) return Error{"overlay input '" + input_dir + "': no frame lies within groundtruth.txt"};
  std::size_t last = data->size();
  if (options.max_frames > 0) last = std::min(last, first + static_cast<std::size_t>(options.max_frames));
  const SE3 T_w_s = stageFromCamera(T_w_c0);
  Result<MoverRenderer> movers = MoverRenderer::create(config, T_w_s);
  if (!movers.ok()) return Error{movers.error()};
  const fs::path root(output_dir);
  if (options.write_images) {
    if (Status s = makeDirs(root); !s) return Error{s.error()};
  }

  const std::size_t n = last - first;
  std::vector<FrameResult> results(n);
  std::vector<std::string> rgb_lines(n), depth_lines(n), mask_lines(n), speed_lines(n);
  std::vector<char> used(n, 0);
  std::atomic<int> skipped_bad{0};
  Status status = runParallel(n, options.threads, [&](std::size_t j) -> Status {
    FrameResult& r = results[j];
    const auto t_load = Clock::now();
    Result<dataset::RgbdFrame> f = data->load(first + j);
    if (!f.ok()) {
      ++skipped_bad;
      return Status::success();
    }
    const std::optional<SE3> T_w_c = placement(f->stamp);
    if (!T_w_c) return Status::success();
    cv::Mat depth_raw;
    f->depth_m.convertTo(depth_raw, CV_16UC1, camera.depth_factor);  // exact: raw / factor round-trips
    r.load_ms = msSince(t_load);

    const auto t_render = Clock::now();
    const CompositeFrame frame = composeOverlay(*movers, f->bgr, depth_raw, secondsBetween(f->stamp, t0), *T_w_c,
                                                camera, config.sensor, frameSeed(config.seed, first + j));
    r.pixels.assign(config.movers.size() + 1, 0);
    countPixels(frame.mask, &r.pixels);
    r.render_ms = msSince(t_render);
    used[j] = 1;

    const std::string stamp = f->stamp.toSecondsString();
    const std::string rgb_name = "rgb/" + fs::path(f->rgb_path).filename().string();
    const std::string depth_name = "depth/" + fs::path(f->depth_path).filename().string();
    const std::string mask_name = "mask/" + stamp + ".png";
    rgb_lines[j] = stamp + " " + rgb_name + "\n";
    depth_lines[j] = f->depth_stamp.toSecondsString() + " " + depth_name + "\n";
    mask_lines[j] = stamp + " " + mask_name + "\n";
    speed_lines[j] = moverSpeedLines(config, stamp, secondsBetween(f->stamp, t0));
    if (!options.write_images) return Status::success();
    const auto t_write = Clock::now();
    long any = 0;
    for (long p : r.pixels) any += p;
    std::error_code ec;
    if (any == 0) {  // nothing drawn: the input files are the output
      fs::copy_file(f->rgb_path, root / rgb_name, fs::copy_options::overwrite_existing, ec);
      if (ec) return Error{"cannot copy " + f->rgb_path + ": " + ec.message()};
      fs::copy_file(f->depth_path, root / depth_name, fs::copy_options::overwrite_existing, ec);
      if (ec) return Error{"cannot copy " + f->depth_path + ": " + ec.message()};
    } else {
      if (Status s = writePng(root / rgb_name, frame.bgr, options.png_compression); !s) return s;
      if (Status s = writePng(root / depth_name, frame.depth, options.png_compression); !s) return s;
    }
    if (Status s = writePng(root / mask_name, frame.mask, options.png_compression); !s) return s;
    r.write_ms = msSince(t_write);
    return Status::success();
  });
  if (!status) return Error{status.error()};

  GenerationReport report;
  std::vector<FrameResult> kept;
  std::string rgb_list = "# color images\n# stillpoint-synth overlay of " + input_dir + "\n# timestamp filename\n";
  std::string depth_list = "# depth maps\n# stillpoint-synth overlay of " + input_dir + "\n# timestamp filename\n";
  std::string mask_list = "# mover masks (16-bit PNG, 0 = static, k = mover id in movers.yaml)\n# timestamp filename\n";
  std::string speed_list = kMoverSpeedHeader;
  for (std::size_t j = 0; j < n; ++j) {
    if (!used[j]) continue;
    kept.push_back(results[j]);
    rgb_list += rgb_lines[j];
    depth_list += depth_lines[j];
    mask_list += mask_lines[j];
    speed_list += speed_lines[j];
  }
  report.skipped_no_pose = static_cast<int>(first + (n - kept.size())) - skipped_bad.load();
  summarise(kept, config, camera.width, camera.height, &report);
  if (options.write_images) {
    if (Status s = writeTextFile(root / "rgb.txt", rgb_list); !s) return Error{s.error()};
    if (Status s = writeTextFile(root / "depth.txt", depth_list); !s) return Error{s.error()};
    if (Status s = writeTextFile(root / "mask.txt", mask_list); !s) return Error{s.error()};
    if (Status s = writeTextFile(root / "movers.txt", speed_list); !s) return Error{s.error()};
    std::error_code ec;
    fs::copy_file(data->groundTruthPath(), root / "groundtruth.txt", fs::copy_options::overwrite_existing, ec);
    if (ec) return Error{"cannot copy " + data->groundTruthPath() + ": " + ec.message()};
    report.wall_s = std::chrono::duration<double>(Clock::now() - wall_start).count();
    if (Status s = writeMoversYaml(root / "movers.yaml", "overlay", input_dir, config, camera, T_w_s, report); !s) {
      return Error{s.error()};
    }
  }
  report.wall_s = std::chrono::duration<double>(Clock::now() - wall_start).count();
  return report;
}

Result<GenerationReport> generateRoom(const std::string& output_dir, const SynthConfig& config,
                                      const GenerateOptions& options) {
  const auto wall_start = Clock::now();
  if (Status s = config.validate(); !s) return Error{s.error()};
  const RoomOptions& ro = config.room;
  const CameraModel camera = roomCamera(ro.width, ro.height);
  Result<Room> room = buildRoom(ro, config.base_dir, config.seed);
  if (!room.ok()) return Error{room.error()};
  const SE3 T_w_s = stageFromCamera(roomCameraPose(ro.motion, 0.0));
  Result<MoverRenderer> movers = MoverRenderer::create(config, T_w_s);
  if (!movers.ok()) return Error{movers.error()};
  const fs::path root(output_dir);
  if (options.write_images) {
    if (Status s = makeDirs(root); !s) return Error{s.error()};
  }
  std::size_t n = static_cast<std::size_t>(ro.frames);
  if (options.max_frames > 0) n = std::min(n, static_cast<std::size_t>(options.max_frames));
  // Whole microseconds so the lists read back exactly.
  auto stampOf = [&](std::size_t k) {
    return Timestamp::fromNanoseconds((1'000'000'000'000'000LL + std::llround(k * 1e6 / ro.rate_hz)) * 1000);
  };
  std::vector<FrameResult> results(n);
  Status status = runParallel(n, options.threads, [&](std::size_t k) -> Status {
    FrameResult& r = results[k];
    const double t = k / ro.rate_hz;
    const SE3 T_w_c = roomCameraPose(ro.motion, t);
    const auto t_render = Clock::now();
    RenderTarget target = RenderTarget::blank(camera.width, camera.height, {90, 90, 90});
    synth::render(room->mesh, T_w_c, camera, &target);
    movers->render(t, T_w_c, camera, &target);
    cv::Mat depth;
    applyDepthSensor(target.depth, cv::Mat(), config.sensor, frameSeed(config.seed, k), &depth);
    r.pixels.assign(config.movers.size() + 1, 0);
    countPixels(target.id, &r.pixels);
    r.render_ms = msSince(t_render);
    if (!options.write_images) return Status::success();
    const auto t_write = Clock::now();
    const std::string stamp = stampOf(k).toSecondsString();
    if (Status s = writePng(root / ("rgb/" + stamp + ".png"), target.colour, options.png_compression); !s) return s;
    if (Status s = writePng(root / ("depth/" + stamp + ".png"), depth, options.png_compression); !s) return s;
    if (Status s = writePng(root / ("mask/" + stamp + ".png"), target.id, options.png_compression); !s) return s;
    r.write_ms = msSince(t_write);
    return Status::success();
  });
  if (!status) return Error{status.error()};

  GenerationReport report;
  summarise(results, config, camera.width, camera.height, &report);
  if (options.write_images) {
    const std::string origin = "# stillpoint-synth room, motion " + std::string(toString(ro.motion)) + "\n";
    std::string rgb = "# color images\n" + origin + "# timestamp filename\n";
    std::string dep = "# depth maps\n" + origin + "# timestamp filename\n";
    std::string msk = "# mover masks (16-bit PNG, 0 = static, k = mover id in movers.yaml)\n# timestamp filename\n";
    std::string gt = "# ground truth trajectory\n" + origin + "# timestamp tx ty tz qx qy qz qw\n";
    std::string speeds = kMoverSpeedHeader;
    for (std::size_t k = 0; k < n; ++k) {
      const std::string stamp = stampOf(k).toSecondsString();
      rgb += stamp + " rgb/" + stamp + ".png\n";
      dep += stamp + " depth/" + stamp + ".png\n";
      msk += stamp + " mask/" + stamp + ".png\n";
      speeds += moverSpeedLines(config, stamp, k / ro.rate_hz);
      const SE3 T = roomCameraPose(ro.motion, k / ro.rate_hz);
      Eigen::Quaterniond q(T.linear());
      if (q.w() < 0) q.coeffs() *= -1;
      char line[200];
      std::snprintf(line, sizeof(line), "%s %.6f %.6f %.6f %.6f %.6f %.6f %.6f\n", stamp.c_str(),
                    T.translation().x(), T.translation().y(), T.translation().z(), q.x(), q.y(), q.z(), q.w());
      gt += line;
    }
    for (const auto& [name, text] : {std::pair<const char*, const std::string*>{"rgb.txt", &rgb},
                                     {"depth.txt", &dep}, {"mask.txt", &msk}, {"groundtruth.txt", &gt},
                                     {"movers.txt", &speeds}}) {
      if (Status s = writeTextFile(root / name, *text); !s) return Error{s.error()};
    }
    report.wall_s = std::chrono::duration<double>(Clock::now() - wall_start).count();
    const std::string source = std::string("room/") + toString(ro.motion);
    if (Status s = writeMoversYaml(root / "movers.yaml", "room", source, config, camera, T_w_s, report); !s) {
      return Error{s.error()};
    }
  }
  report.wall_s = std::chrono::duration<double>(Clock::now() - wall_start).count();
  return report;
}

}  // namespace stillpoint::synth
