#include "stillpoint/core/files.hpp"
#include "stillpoint/dataset/testing.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <system_error>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace stillpoint::dataset::testing {
namespace {

namespace fs = std::filesystem;

Status validate(const SyntheticDatasetOptions& o) {
  auto bad = [](const std::string& field, const std::string& rule) {
    return Status(Error{"SyntheticDatasetOptions." + field + " " + rule});
  };
  if (o.n_frames < 1) return bad("n_frames", "must be >= 1");
  if (o.width < 8 || o.width > 4096) return bad("width", "must be in [8, 4096]");
  if (o.height < 8 || o.height > 4096) return bad("height", "must be in [8, 4096]");
  if (!std::isfinite(o.rate_hz) || o.rate_hz <= 0 || o.rate_hz > 1e4) {
    return bad("rate_hz", "must be in (0, 1e4]");
  }
  if (!std::isfinite(o.jitter_s) || o.jitter_s < 0 || 4 * o.jitter_s >= 1 / o.rate_hz) {
    return bad("jitter_s", "must be >= 0 and < 1 / (4 rate_hz) so stamps stay ordered");
  }
  if (!std::isfinite(o.start_time_s) || o.start_time_s < 0 || o.start_time_s > 4e9) {
    return bad("start_time_s", "must be in [0, 4e9]");
  }
  if (!std::isfinite(o.depth_factor) || o.depth_factor <= 0) {
    return bad("depth_factor", "must be > 0");
  }
  const double raw = o.plane_depth_m * o.depth_factor;
  if (!std::isfinite(raw) || raw < 1 || raw > 65535) {
    return bad("plane_depth_m", "times depth_factor must fit a 16-bit depth value in [1, 65535]");
  }
  if (!o.lateral_velocity_m_s.allFinite()) return bad("lateral_velocity_m_s", "must be finite");
  return Status::success();
}

// Whole microseconds, so the 6-digit text in the lists reads back exactly.
Timestamp roundToMicroseconds(double seconds) {
  return Timestamp::fromNanoseconds(std::llround(seconds * 1e6) * 1000);
}

// Random colour blocks, lightly blurred: many corners and no flat regions.
cv::Mat makeTexture(int width, int height, int block, cv::RNG& rng) {
  cv::Mat coarse((height + block - 1) / block, (width + block - 1) / block, CV_8UC3);
  rng.fill(coarse, cv::RNG::UNIFORM, cv::Scalar::all(20), cv::Scalar::all(236));
  cv::Mat fine;
  cv::resize(coarse, fine, cv::Size(coarse.cols * block, coarse.rows * block), 0, 0,
             cv::INTER_NEAREST);
  cv::GaussianBlur(fine, fine, cv::Size(3, 3), 0.8);
  return fine(cv::Rect(0, 0, width, height)).clone();
}

Status writePng(const fs::path& path, const cv::Mat& image) {
  try {
    if (cv::imwrite(path.string(), image)) return Status::success();
  } catch (const std::exception& e) {
    return Error{"cannot write " + path.string() + ": " + e.what()};
  }
  return Error{"cannot write " + path.string()};
}

}  // namespace

Result<SyntheticDataset> writeSyntheticTumDataset(const std::string& dir,
                                                  const SyntheticDatasetOptions& options) {
  if (Status valid = validate(options); !valid) return Error{valid.error()};
  const fs::path root(dir);
  std::error_code ec;
  for (const fs::path& sub : {root / "rgb", root / "depth"}) {
    fs::create_directories(sub, ec);
    if (ec) return Error{"cannot create " + sub.string() + ": " + ec.message()};
  }

  SyntheticDataset out;
  out.directory = dir;
  CameraModel& cam = out.camera;
  cam.name = "synthetic";
  cam.width = options.width;
  cam.height = options.height;
  cam.fx = cam.fy = 0.8 * options.width;
  cam.cx = 0.5 * (options.width - 1);
  cam.cy = 0.5 * (options.height - 1);
  cam.depth_factor = options.depth_factor;

  cv::RNG rng(options.seed);
  const double period = 1.0 / options.rate_hz;
  for (int k = 0; k < options.n_frames; ++k) {
    const double jitter = options.jitter_s;
    const Timestamp colour =
        roundToMicroseconds(options.start_time_s + k * period + rng.uniform(-jitter, jitter));
    out.colour_stamps.push_back(colour);
    const double depth_seconds = colour.seconds() + rng.uniform(-jitter, jitter);
    out.depth_stamps.push_back(roundToMicroseconds(depth_seconds));
  }

  // The texture covers every view: the image plus the largest shift either way.
  const double z = options.plane_depth_m;
  const double span = secondsBetween(out.colour_stamps.back(), out.colour_stamps.front());
  const Vec2 max_shift_px(cam.fx * std::abs(options.lateral_velocity_m_s.x()) * span / z,
                          cam.fy * std::abs(options.lateral_velocity_m_s.y()) * span / z);
  const int margin_x = static_cast<int>(std::ceil(max_shift_px.x())) + 4;
  const int margin_y = static_cast<int>(std::ceil(max_shift_px.y())) + 4;
  const int block = std::max(4, options.width / 16);
  const cv::Mat texture =
      makeTexture(options.width + 2 * margin_x, options.height + 2 * margin_y, block, rng);

  const auto raw_depth = static_cast<std::uint16_t>(std::lround(z * options.depth_factor));
  const cv::Mat depth(options.height, options.width, CV_16UC1, cv::Scalar(raw_depth));

  const std::string origin = "# synthetic stillpoint test sequence\n";
  std::string rgb_list = "# color images\n" + origin + "# timestamp filename\n";
  std::string depth_list = "# depth maps\n" + origin + "# timestamp filename\n";
  std::string gt_list =
      "# ground truth trajectory\n" + origin + "# timestamp tx ty tz qx qy qz qw\n";
  for (int k = 0; k < options.n_frames; ++k) {
    const Timestamp t = out.colour_stamps[static_cast<std::size_t>(k)];
    const double dt = secondsBetween(t, out.colour_stamps.front());
    const Vec2 xy = options.lateral_velocity_m_s * dt;
    SE3 T_w_c = SE3::Identity();
    T_w_c.translation() = Vec3(xy.x(), xy.y(), 0.0);
    out.T_w_c.push_back(T_w_c);

    // A pixel u sees world X = (u - cx) z / fx + tx, i.e. texture column u + fx tx / z + margin.
    const cv::Matx23d shift(1, 0, cam.fx * xy.x() / z + margin_x,  //
                            0, 1, cam.fy * xy.y() / z + margin_y);
    cv::Mat bgr;
    cv::warpAffine(texture, bgr, shift, cv::Size(options.width, options.height),
                   cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_REFLECT);

    const std::string rgb_name = "rgb/" + t.toSecondsString() + ".png";
    const std::string depth_stamp = out.depth_stamps[static_cast<std::size_t>(k)].toSecondsString();
    const std::string depth_name = "depth/" + depth_stamp + ".png";
    if (Status s = writePng(root / rgb_name, bgr); !s) return Error{s.error()};
    if (Status s = writePng(root / depth_name, depth); !s) return Error{s.error()};
    rgb_list += t.toSecondsString() + " " + rgb_name + "\n";
    depth_list += depth_stamp + " " + depth_name + "\n";
    char line[160];
    // "+ 0.0" turns -0.0 into 0.0 so the first pose prints as zeros.
    std::snprintf(line, sizeof(line), "%s %.6f %.6f %.6f 0 0 0 1\n", t.toSecondsString().c_str(),
                  xy.x() + 0.0, xy.y() + 0.0, 0.0);
    gt_list += line;
  }
  if (Status s = writeTextFile(root / "rgb.txt", rgb_list); !s) return Error{s.error()};
  if (Status s = writeTextFile(root / "depth.txt", depth_list); !s) return Error{s.error()};
  if (options.write_ground_truth) {
    if (Status s = writeTextFile(root / "groundtruth.txt", gt_list); !s) return Error{s.error()};
  } else {
    fs::remove(root / "groundtruth.txt", ec);  // don't leave a stale one behind
  }
  return out;
}

Result<SyntheticDataset> writeSyntheticTumDataset(const std::string& dir, int n_frames, int width,
                                                  int height) {
  SyntheticDatasetOptions options;
  options.n_frames = n_frames;
  options.width = width;
  options.height = height;
  return writeSyntheticTumDataset(dir, options);
}

}  // namespace stillpoint::dataset::testing
