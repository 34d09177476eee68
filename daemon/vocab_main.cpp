// stillpoint-vocab: trains, describes and checks the vocabulary of binary
// words that place recognition (relocalisation, map merging, loop closing)
// uses. See docs/place-recognition.md.
#include <algorithm>
#include <charconv>
#include <chrono>
#include <functional>
#include <cmath>
#include <cstdio>
#include <string>
#include <string_view>
#include <vector>

#include "stillpoint/core/program.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/eval/trajectory.hpp"
#include "stillpoint/features/orb_extractor.hpp"
#include "stillpoint/features/vocabulary.hpp"

namespace {

using namespace stillpoint;

constexpr int kExitBadInput = 1;
constexpr int kExitUsage = 2;

constexpr const char* kUsage =
    "usage: stillpoint-vocab train OUT.vocab SEQUENCE_DIR... [--every N] [--branching K] [--depth L]\n"
    "                              [--features N] [--seed S]\n"
    "       stillpoint-vocab info VOCAB\n"
    "       stillpoint-vocab check VOCAB SEQUENCE_DIR... [--every N] [--exclude-s S]\n"
    "\n"
    "train  builds a vocabulary from the ORB descriptors of every N-th colour frame (default 2) of\n"
    "       TUM-layout folders: hierarchical k-medians, K children per node (default 10), L levels\n"
    "       (default 4: up to 10^4 words), N features per image (default 1000), deterministic for\n"
    "       a seed.\n"
    "info   prints the shape of a vocabulary file and how long it takes to load.\n"
    "check  measures place recognition on sequences with ground truth: every N-th frame (default\n"
    "       5) is looked up among the others taken more than S s (default 3) apart; a revisit is a\n"
    "       frame with one within 0.3 m and 20 degrees, and its lookup is right when the best (or one\n"
    "       of the 5 best) scoring frames is within 0.5 m and 30 degrees. Prints one line per\n"
    "       sequence: revisits, top1 and top5 recall, and the share of lookups without a revisit\n"
    "       whose best score beats the median best score of the revisits (false alarms).\n"
    "\n"
    "exit status: 0 ok, 1 bad input, 2 usage error\n";

int usageError(const std::string& message) {
  std::fprintf(stderr, "stillpoint-vocab: %s\n%s", message.c_str(), kUsage);
  return kExitUsage;
}

int inputError(const std::string& message) {
  std::fprintf(stderr, "stillpoint-vocab: %s\n", message.c_str());
  return kExitBadInput;
}

template <typename T>
bool parseNumber(std::string_view text, T* out) {
  const char* end = text.data() + text.size();
  const auto [ptr, ec] = std::from_chars(text.data(), end, *out);
  return ec == std::errc() && ptr == end;
}

struct View {
  Timestamp stamp;
  features::BowVector bow;
  SE3 T_w_c = SE3::Identity();
  bool has_pose = false;
};

// ORB descriptors of every `every`-th readable frame of a sequence.
void forEachImage(const dataset::TumDataset& data, int every, features::OrbExtractor* orb,
                  const std::function<void(const dataset::RgbdFrame&, const cv::Mat&)>& use) {
  for (std::size_t i = 0; i < data.size(); i += static_cast<std::size_t>(every)) {
    auto frame = data.load(i);
    if (!frame) {
      std::fprintf(stderr, "stillpoint-vocab: skipped: %s\n", frame.error().c_str());
      continue;
    }
    std::vector<cv::KeyPoint> keys;
    cv::Mat descriptors;
    orb->extract(frame->gray, &keys, &descriptors);
    use(*frame, descriptors);
  }
}

// The ground-truth pose nearest in time (within 0.03 s).
bool poseAt(const eval::Trajectory& gt, Timestamp t, SE3* T_w_c) {
  auto it = std::lower_bound(gt.begin(), gt.end(), t, [](const eval::StampedPose& p, Timestamp s) { return p.stamp < s; });
  const eval::StampedPose* best = nullptr;
  double best_dt = 0.03;
  for (auto c : {it, it == gt.begin() ? it : std::prev(it)}) {
    if (c == gt.end()) continue;
    const double dt = std::abs(secondsBetween(c->stamp, t));
    if (dt <= best_dt) best_dt = dt, best = &*c;
  }
  if (best) *T_w_c = best->T_w_c;
  return best != nullptr;
}

bool near(const SE3& a, const SE3& b, double metres, double degrees) {
  const SE3 d = a.inverse() * b;
  const double angle = std::acos(std::clamp((d.linear().trace() - 1.0) / 2.0, -1.0, 1.0)) * 180.0 / M_PI;
  return d.translation().norm() <= metres && angle <= degrees;
}

int train(const std::vector<std::string>& args, int every, const features::VocabularyParams& params, int n_features) {
  if (args.size() < 2) return usageError("train needs OUT.vocab and at least one sequence folder");
  features::OrbOptions orb_options;
  orb_options.num_features = n_features;
  if (Status s = orb_options.validate(); !s) return usageError(s.error());
  features::OrbExtractor orb(orb_options);
  std::vector<cv::Mat> images;
  std::size_t descriptors = 0;
  for (std::size_t k = 1; k < args.size(); ++k) {
    auto data = dataset::TumDataset::open(args[k]);
    if (!data) return inputError(data.error());
    forEachImage(*data, every, &orb, [&](const dataset::RgbdFrame&, const cv::Mat& d) {
      if (d.empty()) return;
      images.push_back(d.clone());
      descriptors += static_cast<std::size_t>(d.rows);
    });
  }
  std::fprintf(stderr, "stillpoint-vocab: training on %zu images, %zu descriptors\n", images.size(), descriptors);
  const auto t0 = std::chrono::steady_clock::now();
  auto vocab = features::Vocabulary::train(images, params);
  if (!vocab) return inputError(vocab.error());
  const double train_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (Status s = vocab->save(args[0]); !s) return inputError(s.error());
  const features::VocabularyInfo info = vocab->info();
  std::printf("vocabulary=%s words=%zu nodes=%zu branching=%d depth=%d images=%zu descriptors=%zu train_s=%.1f\n",
              args[0].c_str(), info.words, info.nodes, info.branching, info.depth, images.size(), descriptors, train_s);
  return 0;
}

int info(const std::vector<std::string>& args) {
  if (args.size() != 1) return usageError("info needs one vocabulary file");
  const auto t0 = std::chrono::steady_clock::now();
  auto vocab = features::Vocabulary::load(args[0]);
  const double load_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  if (!vocab) return inputError(vocab.error());
  const features::VocabularyInfo i = vocab->info();
  std::printf("vocabulary=%s words=%zu nodes=%zu branching=%d depth=%d training_images=%llu "
              "training_descriptors=%llu load_ms=%.2f\n",
              args[0].c_str(), i.words, i.nodes, i.branching, i.depth, static_cast<unsigned long long>(i.training_images),
              static_cast<unsigned long long>(i.training_descriptors), load_ms);
  return 0;
}

int check(const std::vector<std::string>& args, int every, double exclude_s) {
  if (args.size() < 2) return usageError("check needs a vocabulary and at least one sequence folder");
  auto vocab = features::Vocabulary::load(args[0]);
  if (!vocab) return inputError(vocab.error());
  features::OrbExtractor orb(features::OrbOptions{});
  for (std::size_t k = 1; k < args.size(); ++k) {
    auto data = dataset::TumDataset::open(args[k]);
    if (!data) return inputError(data.error());
    if (!data->hasGroundTruth()) return inputError(args[k] + ": no groundtruth.txt to check against");
    auto gt = eval::readTumTrajectory(data->groundTruthPath());
    if (!gt) return inputError(gt.error());
    std::vector<View> views;
    double transform_ms = 0;
    forEachImage(*data, every, &orb, [&](const dataset::RgbdFrame& f, const cv::Mat& d) {
      View v;
      v.stamp = f.stamp;
      const auto t0 = std::chrono::steady_clock::now();
      v.bow = vocab->transform(d);
      transform_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      v.has_pose = poseAt(*gt, f.stamp, &v.T_w_c);
      views.push_back(std::move(v));
    });
    int revisits = 0, top1 = 0, top5 = 0;
    std::vector<double> revisit_best, other_best;
    for (const View& q : views) {
      if (!q.has_pose) continue;
      bool revisit = false;
      std::vector<std::pair<double, const View*>> scored;
      for (const View& c : views) {
        if (!c.has_pose || std::abs(secondsBetween(q.stamp, c.stamp)) <= exclude_s) continue;
        revisit |= near(q.T_w_c, c.T_w_c, 0.3, 20.0);
        scored.emplace_back(features::bowScore(q.bow, c.bow), &c);
      }
      if (scored.empty()) continue;
      const std::size_t n = std::min<std::size_t>(5, scored.size());
      std::partial_sort(scored.begin(), scored.begin() + n, scored.end(),
                        [](const auto& a, const auto& b) { return a.first > b.first; });
      if (!revisit) {
        other_best.push_back(scored[0].first);
        continue;
      }
      ++revisits;
      revisit_best.push_back(scored[0].first);
      top1 += near(q.T_w_c, scored[0].second->T_w_c, 0.5, 30.0);
      bool any = false;
      for (std::size_t i = 0; i < n; ++i) any |= near(q.T_w_c, scored[i].second->T_w_c, 0.5, 30.0);
      top5 += any;
    }
    double median = 0;
    if (!revisit_best.empty()) {
      std::nth_element(revisit_best.begin(), revisit_best.begin() + revisit_best.size() / 2, revisit_best.end());
      median = revisit_best[revisit_best.size() / 2];
    }
    const auto false_alarms = std::count_if(other_best.begin(), other_best.end(), [median](double s) { return s >= median; });
    std::printf("sequence=%s frames=%zu revisits=%d top1=%.3f top5=%.3f no_revisit=%zu false_alarm=%.3f transform_ms=%.2f\n",
                args[k].c_str(), views.size(), revisits, revisits ? static_cast<double>(top1) / revisits : 0.0,
                revisits ? static_cast<double>(top5) / revisits : 0.0, other_best.size(),
                other_best.empty() ? 0.0 : static_cast<double>(false_alarms) / other_best.size(),
                views.empty() ? 0.0 : transform_ms / views.size());
  }
  return 0;
}

int run(int argc, char** argv) {
  if (argc < 2) return usageError("expected a command: train, info or check");
  const std::string_view command = argv[1];
  if (command == "--help" || command == "-h") {
    std::fputs(kUsage, stdout);
    return 0;
  }
  if (command == "--version") {
    std::puts("stillpoint-vocab " STILLPOINT_VERSION " (" STILLPOINT_ARCH ")");
    return 0;
  }
  std::vector<std::string> positional;
  int every = command == "check" ? 5 : 2, n_features = 1000;
  double exclude_s = 3.0;
  features::VocabularyParams params;
  for (int k = 2; k < argc; ++k) {
    const std::string_view arg = argv[k];
    if (arg.size() > 1 && arg.front() == '-') {
      if (k + 1 >= argc) return usageError(std::string(arg) + " needs a value");
      const std::string_view value = argv[++k];
      bool ok = false;
      if (arg == "--every") ok = parseNumber(value, &every) && every >= 1;
      else if (arg == "--branching") ok = parseNumber(value, &params.branching);
      else if (arg == "--depth") ok = parseNumber(value, &params.depth);
      else if (arg == "--features") ok = parseNumber(value, &n_features) && n_features >= 50;
      else if (arg == "--seed") ok = parseNumber(value, &params.seed);
      else if (arg == "--exclude-s") ok = parseNumber(value, &exclude_s) && exclude_s >= 0;
      else return usageError("unknown option '" + std::string(arg) + "'");
      if (!ok) return usageError("bad value '" + std::string(value) + "' for " + std::string(arg));
      continue;
    }
    positional.emplace_back(arg);
  }
  if (Status s = params.validate(); !s) return usageError(s.error());
  if (command == "train") return train(positional, every, params, n_features);
  if (command == "info") return info(positional);
  if (command == "check") return check(positional, every, exclude_s);
  return usageError("unknown command '" + std::string(command) + "'");
}

}  // namespace

int main(int argc, char** argv) { return stillpoint::runProgram("stillpoint-vocab", run, argc, argv); }
