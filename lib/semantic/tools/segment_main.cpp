// stillpoint-segment: runs a segmentation model card on images (or on the
// colour frames of a TUM-layout folder), writes overlay PNGs and prints
// per-image and summary statistics of the movable mask.
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "stillpoint/core/program.hpp"
#include "stillpoint/semantic/depth_agreement.hpp"
#include "stillpoint/semantic/person_second_opinion.hpp"
#include "stillpoint/semantic/segmenter.hpp"

namespace fs = std::filesystem;
using namespace stillpoint;
using namespace stillpoint::semantic;

namespace {

const char* kUsage =
    "usage: stillpoint-segment (--card CARD.yaml | --recommended) [--model-dir DIR]\n"
    "                          [--out DIR] [--threshold P] [--score-threshold S]\n"
    "                          [--min-area FRACTION] [--min-confidence P] [--static-overlap IOU]\n"
    "                          [--furniture] [--threads N] [--person-card CARD.yaml]\n"
    "                          (IMAGE... | --tum DATASET_DIR [--from I] [--to J] [--depth])\n"
    "Prints one line per image and a summary line; --out writes <name>_overlay.png\n"
    "(movable pixels red, pixels the post-filter dropped yellow, boxes with class and score)\n"
    "and <name>_mask.png (255 movable, 0 not: e.g. a person cut-out for stillpoint-synth --cutout).\n"
    "--person-card: a person model's regions that the main model does not explain join as people.\n"
    "--depth (with --tum): cut mask pixels that disagree with the instance's depth (TUM depth, /5000).\n";

int usage(const std::string& why) {
  std::cerr << "stillpoint-segment: " << why << "\n" << kUsage;
  return 2;
}

bool parseNumber(const std::string& text, double* out) {
  try {
    std::size_t used = 0;
    *out = std::stod(text, &used);
    return used == text.size();
  } catch (...) {
    return false;
  }
}

// Timestamped file list (rgb.txt / depth.txt layout).
std::vector<std::pair<double, fs::path>> readList(const fs::path& dir, const char* name) {
  std::vector<std::pair<double, fs::path>> out;
  std::ifstream in(dir / name);
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ss(line);
    double t;
    std::string file;
    if (ss >> t >> file) out.emplace_back(t, dir / file);
  }
  return out;
}

// The depth image closest in time (within 20 ms), or an empty path.
fs::path nearestDepth(const std::vector<std::pair<double, fs::path>>& depths, double t) {
  fs::path best;
  double best_dt = 0.02;
  for (const auto& [td, path] : depths)
    if (std::abs(td - t) <= best_dt) best_dt = std::abs(td - t), best = path;
  return best;
}

Result<std::vector<fs::path>> tumFrames(const fs::path& dir, int from, int to) {
  const std::string list = (dir / "rgb.txt").string();
  std::ifstream in(list);
  if (!in) return Error{"'" + list + "': cannot be opened"};
  std::vector<fs::path> frames;
  std::string line;
  int index = 0;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ss(line);
    double t;
    std::string file;
    if (!(ss >> t >> file)) continue;
    if (index >= from && (to < 0 || index <= to)) frames.push_back(dir / file);
    ++index;
  }
  return frames;
}

cv::Mat overlay(const cv::Mat& bgr, const Segmentation& seg) {
  cv::Mat out = bgr.clone();
  cv::Mat red(bgr.size(), CV_8UC3, cv::Scalar(0, 0, 255)), yellow(bgr.size(), CV_8UC3, cv::Scalar(0, 255, 255));
  cv::Mat blend_red, blend_yellow;
  cv::addWeighted(bgr, 0.45, red, 0.55, 0, blend_red);
  cv::addWeighted(bgr, 0.45, yellow, 0.55, 0, blend_yellow);
  for (const Instance& inst : seg.instances)
    if (inst.movable && !inst.kept && !inst.mask.empty()) blend_yellow(inst.box).copyTo(out(inst.box), inst.mask);
  blend_red.copyTo(out, seg.movable_mask);
  for (const Instance& inst : seg.instances) {
    if (inst.area == 0) continue;
    const cv::Scalar colour = inst.movable ? (inst.kept ? cv::Scalar(0, 0, 255) : cv::Scalar(0, 200, 255))
                                           : cv::Scalar(255, 160, 0);
    cv::rectangle(out, inst.box, colour, 2);
    char text[96];
    std::snprintf(text, sizeof text, "%s %.2f", inst.class_name.c_str(), inst.score);
    cv::putText(out, text, inst.box.tl() + cv::Point(3, 16), cv::FONT_HERSHEY_SIMPLEX, 0.5, colour, 1);
  }
  return out;
}

}  // namespace

static int segmentMain(int argc, char** argv) {
  std::vector<std::string> args(argv + 1, argv + argc);
  fs::path card_path, person_card_path, out_dir, tum_dir;
  bool recommended = false, use_depth = false;
  ModelLookup lookup;
  SegmenterOptions options;
  int from = 0, to = -1;
  std::vector<fs::path> images;
  for (std::size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    auto value = [&](std::string* out) {
      if (i + 1 >= args.size()) return false;
      *out = args[++i];
      return true;
    };
    std::string v;
    double d = 0;
    if (a == "--card") {
      if (!value(&v)) return usage("--card needs a file");
      card_path = v;
    } else if (a == "--person-card") {
      if (!value(&v)) return usage("--person-card needs a file");
      person_card_path = v;
    } else if (a == "--recommended") {
      recommended = true;
    } else if (a == "--model-dir") {
      if (!value(&v)) return usage("--model-dir needs a folder");
      lookup.model_dirs.push_back(v);
    } else if (a == "--out") {
      if (!value(&v)) return usage("--out needs a folder");
      out_dir = v;
    } else if (a == "--tum") {
      if (!value(&v)) return usage("--tum needs a folder");
      tum_dir = v;
    } else if (a == "--depth") {
      use_depth = true;
    } else if (a == "--furniture") {
      options.movable_furniture = true;
    } else if (a == "--threshold" || a == "--score-threshold" || a == "--min-area" || a == "--min-confidence" || a == "--static-overlap" ||
               a == "--threads" || a == "--from" || a == "--to") {
      if (!value(&v) || !parseNumber(v, &d)) return usage(a + " needs a number");
      if (a == "--threshold") options.threshold = d;
      if (a == "--score-threshold") options.score_threshold = d;
      if (a == "--min-area") options.min_region_fraction = d;
      if (a == "--min-confidence") options.min_region_confidence = d;
      if (a == "--static-overlap") options.static_overlap_iou = d;
      if (a == "--threads") options.threads = int(d);
      if (a == "--from") from = int(d);
      if (a == "--to") to = int(d);
    } else if (!a.empty() && a[0] == '-') {
      return usage("unknown option " + a);
    } else {
      images.push_back(a);
    }
  }
  if (card_path.empty() == !recommended) return usage("give exactly one of --card and --recommended");
  if (images.empty() == tum_dir.empty()) return usage("give images or --tum, not both or neither");
  if (use_depth && tum_dir.empty()) return usage("--depth needs --tum");

  ModelCard card;
  if (recommended) {
    auto r = resolveRecommendedModel(lookup);
    if (!r) return std::cerr << "stillpoint-segment: " << r.error() << "\n", 1;
    std::cerr << "model: " << r->reason << "\n";
    card = r->card;
  } else {
    auto r = loadModelCard(card_path);
    if (!r) return std::cerr << "stillpoint-segment: " << r.error() << "\n", 1;
    card = *r;
    for (const auto& d : lookup.model_dirs)
      if (fs::is_regular_file(d / card.model_path.filename())) card.model_path = d / card.model_path.filename();
  }
  if (!tum_dir.empty()) {
    auto frames = tumFrames(tum_dir, from, to);
    if (!frames) return std::cerr << "stillpoint-segment: " << frames.error() << "\n", 1;
    images = *frames;
  }
  auto segmenter = createSegmenter(card, options);
  if (!segmenter) return std::cerr << "stillpoint-segment: " << segmenter.error() << "\n", 1;
  if (!person_card_path.empty()) {
    auto person = createSegmenter(person_card_path);
    if (!person) return std::cerr << "stillpoint-segment: " << person.error() << "\n", 1;
    segmenter = withPersonSecondOpinion(std::move(*segmenter), std::move(*person));
    if (!segmenter) return std::cerr << "stillpoint-segment: " << segmenter.error() << "\n", 1;
  }
  if (!out_dir.empty()) fs::create_directories(out_dir);

  std::vector<std::pair<double, fs::path>> depths, rgbs;
  if (use_depth) {
    depths = readList(tum_dir, "depth.txt");
    rgbs = readList(tum_dir, "rgb.txt");
  }
  long depth_removed = 0;
  int processed = 0, with_movable = 0, failed = 0;
  double sum_pct = 0, max_pct = 0, sum_filtered_pct = 0;
  std::vector<double> times;
  for (const auto& path : images) {
    const cv::Mat bgr = cv::imread(path.string(), cv::IMREAD_COLOR);
    if (bgr.empty()) {
      std::cerr << "stillpoint-segment: '" << path.string() << "': cannot be read as an image\n";
      ++failed;
      continue;
    }
    auto seg = (*segmenter)->segment(bgr);
    if (!seg) {
      std::cerr << "stillpoint-segment: '" << path.string() << "': " << seg.error() << "\n";
      ++failed;
      continue;
    }
    if (use_depth) {
      fs::path depth_path;
      for (const auto& [t, p] : rgbs)
        if (p == path) depth_path = nearestDepth(depths, t);
      const cv::Mat depth = depth_path.empty() ? cv::Mat() : cv::imread(depth_path.string(), cv::IMREAD_UNCHANGED);
      auto agreement = applyDepthAgreement(depth, DepthAgreementOptions{}, &*seg);
      if (!agreement) {
        std::cerr << "stillpoint-segment: '" << path.string() << "': no usable depth: " << agreement.error() << "\n";
      } else {
        for (const auto& d : *agreement) depth_removed += d.removed_pixels;
      }
    }
    ++processed;
    const double pct = 100.0 * seg->movableFraction();
    const double filtered_pct = 100.0 * seg->filtered_pixels / double(bgr.total());
    sum_pct += pct;
    sum_filtered_pct += filtered_pct;
    max_pct = std::max(max_pct, pct);
    with_movable += seg->movable_pixels > 0;
    times.push_back(seg->timing.total_ms);
    std::printf("image=%s movable_pct=%.2f filtered_pct=%.2f instances=%zu ms=%.1f", path.filename().c_str(), pct,
                filtered_pct, seg->instances.size(), seg->timing.total_ms);
    for (const Instance& inst : seg->instances)
      if (inst.area > 0)
        std::printf(" [%s %.3f %dpx%s%s%s]", inst.class_name.c_str(), inst.score, inst.area,
                    inst.second_opinion ? " second opinion" : "",
                    !inst.movable ? " static" : (inst.kept ? "" : " dropped: "), inst.drop_reason.c_str());
    std::printf("\n");
    if (!out_dir.empty()) {
      const fs::path out = out_dir / (path.stem().string() + "_overlay.png");
      if (!cv::imwrite(out.string(), overlay(bgr, *seg)))
        std::cerr << "stillpoint-segment: cannot write '" << out.string() << "'\n";
      const fs::path mask = out_dir / (path.stem().string() + "_mask.png");
      cv::Mat binary;
      cv::compare(seg->movable_mask, 0, binary, cv::CMP_GT);
      if (!cv::imwrite(mask.string(), binary)) std::cerr << "stillpoint-segment: cannot write '" << mask.string() << "'\n";
    }
  }
  if (processed == 0) return std::cerr << "stillpoint-segment: no image could be processed\n", 1;
  std::sort(times.begin(), times.end());
  std::printf("model=%s images=%d failed=%d with_movable=%d frac_with_movable=%.3f mean_movable_pct=%.2f "
              "max_movable_pct=%.2f mean_filtered_pct=%.2f ms_median=%.1f",
              card.name.c_str(), processed, failed, with_movable, with_movable / double(processed),
              sum_pct / processed, max_pct, sum_filtered_pct / processed, times[times.size() / 2]);
  if (use_depth) std::printf(" depth_removed_pixels=%ld", depth_removed);
  std::printf("\n");
  return 0;
}

int main(int argc, char** argv) { return stillpoint::runProgram("stillpoint-segment", segmentMain, argc, argv); }
