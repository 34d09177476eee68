#include "stillpoint/synth/edit.hpp"

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/eval/trajectory.hpp"

namespace stillpoint::synth {
namespace {

namespace fs = std::filesystem;

bool inSpan(const std::vector<TimeSpan>& spans, double t) {
  return std::any_of(spans.begin(), spans.end(),
                     [t](const TimeSpan& s) { return t >= s.start_s && t < s.start_s + s.duration_s; });
}

Status linkOrCopy(const fs::path& from, const fs::path& to) {
  std::error_code ec;
  fs::create_hard_link(from, to, ec);
  if (!ec) return Status::success();
  fs::copy_file(from, to, fs::copy_options::overwrite_existing, ec);
  if (ec) return Error{"cannot copy " + from.string() + " to " + to.string() + ": " + ec.message()};
  return Status::success();
}

}  // namespace

Result<EditSummary> editSequence(const std::string& input_dir, const std::string& output_dir,
                                 const EditOptions& options) {
  for (const auto* spans : {&options.covers, &options.cuts})
    for (const TimeSpan& s : *spans)
      if (!(s.start_s >= 0) || !(s.duration_s > 0)) return Error{"spans need a start >= 0 s and a duration > 0 s"};
  dataset::DatasetOptions dataset_options;
  dataset_options.depth_factor = options.depth_factor;
  auto input = dataset::TumDataset::open(input_dir, dataset_options);
  if (!input) return Error{input.error()};
  if (input->size() == 0) return Error{input_dir + ": no colour/depth pairs"};
  eval::Trajectory gt;
  if (input->hasGroundTruth()) {
    auto read = eval::readTumTrajectory(input->groundTruthPath());
    if (!read) return Error{read.error()};
    gt = std::move(*read);
  }
  std::error_code ec;
  if (fs::exists(output_dir, ec)) return Error{output_dir + " exists: give a new folder"};
  fs::create_directories(fs::path(output_dir) / "rgb", ec);
  if (!ec) fs::create_directories(fs::path(output_dir) / "depth", ec);
  if (ec) return Error{"cannot create " + output_dir + ": " + ec.message()};

  // The output's frames: input index and output stamp.
  struct Out {
    std::size_t index;
    Timestamp stamp;
  };
  std::vector<Out> frames;
  const Timestamp first = input->stamp(0);
  std::int64_t shift_ns = 0;  // cuts so far
  EditSummary summary;
  for (std::size_t i = 0; i < input->size(); ++i) {
    const double t = secondsBetween(input->stamp(i), first);
    if (inSpan(options.cuts, t)) {
      ++summary.cut;
      // The frame after a cut keeps one frame interval to the one before it.
      if (i > 0) shift_ns += input->stamp(i).nanoseconds() - input->stamp(i - 1).nanoseconds();
      continue;
    }
    frames.push_back({i, Timestamp::fromNanoseconds(input->stamp(i).nanoseconds() - shift_ns)});
  }
  if (options.there_and_back && frames.size() > 1) {
    const Timestamp turn = frames.back().stamp;
    for (std::size_t k = frames.size() - 1; k-- > 0;)
      frames.push_back({frames[k].index,
                        Timestamp::fromNanoseconds(2 * turn.nanoseconds() - frames[k].stamp.nanoseconds())});
  }

  std::ofstream rgb_list(fs::path(output_dir) / "rgb.txt"), depth_list(fs::path(output_dir) / "depth.txt");
  std::ofstream gt_list;
  if (!gt.empty()) gt_list.open(fs::path(output_dir) / "groundtruth.txt");
  rgb_list << "# colour images (stillpoint-synth edit of " << input_dir << ")\n";
  depth_list << "# depth images\n";
  if (gt_list.is_open()) gt_list << "# timestamp tx ty tz qx qy qz qw\n";
  for (const Out& f : frames) {
    auto frame = input->load(f.index);
    if (!frame) return Error{frame.error()};
    const std::string name = f.stamp.toSecondsString() + ".png";
    const fs::path rgb = fs::path(output_dir) / "rgb" / name, depth = fs::path(output_dir) / "depth" / name;
    const double t = secondsBetween(frame->stamp, first);
    if (inSpan(options.covers, t)) {
      ++summary.covered;
      if (!cv::imwrite(rgb.string(), cv::Mat::zeros(frame->bgr.size(), CV_8UC3)) ||
          !cv::imwrite(depth.string(), cv::Mat::zeros(frame->bgr.size(), CV_16UC1)))
        return Error{"cannot write " + rgb.string()};
    } else {
      if (Status s = linkOrCopy(frame->rgb_path, rgb); !s) return Error{s.error()};
      if (Status s = linkOrCopy(frame->depth_path, depth); !s) return Error{s.error()};
    }
    rgb_list << f.stamp.toSecondsString() << " rgb/" << name << "\n";
    depth_list << f.stamp.toSecondsString() << " depth/" << name << "\n";
    ++summary.frames;
    if (gt.empty()) continue;
    const auto near = std::lower_bound(gt.begin(), gt.end(), frame->stamp,
                                       [](const eval::StampedPose& p, Timestamp s) { return p.stamp < s; });
    const eval::StampedPose* best = nullptr;
    for (auto it : {near, near == gt.begin() ? near : std::prev(near)}) {
      if (it == gt.end()) continue;
      if (!best || std::abs(secondsBetween(it->stamp, frame->stamp)) < std::abs(secondsBetween(best->stamp, frame->stamp)))
        best = &*it;
    }
    if (!best || std::abs(secondsBetween(best->stamp, frame->stamp)) > 0.02) continue;
    const Eigen::Quaterniond q(best->T_w_c.linear());
    const Vec3 p = best->T_w_c.translation();
    char line[256];
    std::snprintf(line, sizeof(line), "%s %.9g %.9g %.9g %.9g %.9g %.9g %.9g\n", f.stamp.toSecondsString().c_str(),
                  p.x(), p.y(), p.z(), q.x(), q.y(), q.z(), q.w());
    gt_list << line;
    ++summary.ground_truth;
  }
  if (!rgb_list.flush() || !depth_list.flush() || (gt_list.is_open() && !gt_list.flush()))
    return Error{"cannot write the lists in " + output_dir};
  return summary;
}

}  // namespace stillpoint::synth
