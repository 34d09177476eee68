#include "stillpoint/synth/score.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>

#include <opencv2/imgcodecs.hpp>

#include "stillpoint/dataset/tum_dataset.hpp"

namespace stillpoint::synth {
namespace {

namespace fs = std::filesystem;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

double ratio(int a, int b) { return b > 0 ? static_cast<double>(a) / b : kNaN; }

bool isSkippable(const std::string& line) {
  const auto p = line.find_first_not_of(" \t\r");
  return p == std::string::npos || line[p] == '#';
}

// Calls parse(fields, where) for every line of `path` that is not blank or a
// comment; where = "path:line: " for its error messages.
template <typename Parse>
Status forEachRecord(const std::string& path, const std::string& open_error, Parse&& parse) {
  std::ifstream in(path);
  if (!in) return Error{open_error};
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    if (isSkippable(line)) continue;
    std::istringstream fields(line);
    if (Status s = parse(fields, path + ":" + std::to_string(number) + ": "); !s) return s;
  }
  return Status::success();
}

bool isNumber(const std::string& text) {
  char* end = nullptr;
  std::strtod(text.c_str(), &end);
  return end != text.c_str() && *end == '\0';
}

}  // namespace

double FrameScore::precision() const { return ratio(true_positives + still_flagged, flagged); }
double FrameScore::recall() const { return ratio(true_positives, on_movers); }
double FrameScore::eligibleRecall() const { return ratio(eligible_flagged, eligible_features); }

FrameScore scoreFrame(const cv::Mat& mask, std::span<const FlaggedFeature> features, int min_mover_features,
                      std::span<const std::uint16_t> still) {
  FrameScore s;
  std::map<std::uint16_t, MoverFeatureCount> movers;
  for (const FlaggedFeature& f : features) {
    const long x = std::lround(f.u), y = std::lround(f.v);
    if (!std::isfinite(f.u) || !std::isfinite(f.v) || x < 0 || y < 0 || x >= mask.cols || y >= mask.rows) {
      ++s.outside;
      continue;
    }
    ++s.features;
    s.flagged += f.flagged;
    const std::uint16_t id = mask.at<std::uint16_t>(static_cast<int>(y), static_cast<int>(x));
    if (id == 0) continue;
    if (std::find(still.begin(), still.end(), id) != still.end()) {
      ++s.on_still;
      s.still_flagged += f.flagged;
      continue;
    }
    ++s.on_movers;
    s.true_positives += f.flagged;
    MoverFeatureCount& m = movers[id];
    m.id = id;
    ++m.features;
    m.flagged += f.flagged;
  }
  for (const auto& [id, m] : movers) {
    s.movers.push_back(m);
    if (m.features >= min_mover_features) {
      ++s.eligible_movers;
      s.eligible_features += m.features;
      s.eligible_flagged += m.flagged;
    }
  }
  return s;
}

SequenceScore averageScores(std::span<const FrameScore> frames, int min_mover_features) {
  SequenceScore q;
  q.frames = static_cast<int>(frames.size());
  double p = 0, r = 0, er = 0, ep = 0;
  for (const FrameScore& f : frames) {
    if (f.flagged > 0) {
      p += f.precision();
      ++q.precision_frames;
    }
    if (f.on_movers > 0) {
      r += f.recall();
      ++q.recall_frames;
    } else if (f.flagged > f.still_flagged) {
      ++q.static_frames_with_flags;
    }
    if (f.eligible_movers > 0) {
      er += f.eligibleRecall();
      ++q.eligible_frames;
      if (f.flagged > 0) {
        ep += f.precision();
        ++q.eligible_precision_frames;
      }
    }
    q.features += f.features;
    q.flagged += f.flagged;
    q.on_movers += f.on_movers;
    q.true_positives += f.true_positives;
    q.on_still += f.on_still;
    q.still_flagged += f.still_flagged;
    for (const MoverFeatureCount& m : f.movers) {
      MoverFeatureCount& t = q.movers[m.id];
      t.id = m.id;
      t.features += m.features;
      t.flagged += m.flagged;
      if (m.features >= min_mover_features) ++q.mover_eligible_frames[m.id];
    }
  }
  q.precision_mean = q.precision_frames ? p / q.precision_frames : kNaN;
  q.recall_mean = q.recall_frames ? r / q.recall_frames : kNaN;
  q.eligible_recall_mean = q.eligible_frames ? er / q.eligible_frames : kNaN;
  q.eligible_precision_mean = q.eligible_precision_frames ? ep / q.eligible_precision_frames : kNaN;
  return q;
}

Result<std::map<Timestamp, std::vector<FlaggedFeature>>> readFlaggedFeatures(const std::string& path) {
  std::map<Timestamp, std::vector<FlaggedFeature>> out;
  const Status read = forEachRecord(path, "cannot open feature file '" + path + "'",
                                    [&](std::istringstream& ss, const std::string& where) -> Status {
    std::string stamp_text, extra;
    FlaggedFeature f;
    int flagged = -1;
    if (!(ss >> stamp_text >> f.u >> f.v >> flagged)) return Error{where + "expected 'timestamp u v flagged(0/1)'"};
    // Further numeric columns (stillpoint-replay adds cluster and chi2) are allowed.
    while (ss >> extra)
      if (!isNumber(extra)) return Error{where + "unexpected extra field '" + extra + "'"};
    const std::optional<Timestamp> stamp = Timestamp::parseSeconds(stamp_text);
    if (!stamp) return Error{where + "bad timestamp '" + stamp_text + "'"};
    if (flagged != 0 && flagged != 1) return Error{where + "flagged must be 0 or 1"};
    if (!std::isfinite(f.u) || !std::isfinite(f.v)) return Error{where + "u and v must be finite"};
    f.flagged = flagged == 1;
    out[*stamp].push_back(f);
    return Status::success();
  });
  if (!read) return Error{read.error()};
  return out;
}

namespace {

// movers.txt: "timestamp id speed_m_s" per frame and mover -> the ids slower
// than min_speed per frame.
Result<std::map<Timestamp, std::vector<std::uint16_t>>> readStillMovers(const fs::path& path, double min_speed) {
  std::map<Timestamp, std::vector<std::uint16_t>> still;
  const Status read = forEachRecord(
      path.string(), "cannot open " + path.string() + " (--min-speed needs the mover speeds: regenerate the sequence)",
      [&](std::istringstream& ss, const std::string& where) -> Status {
        std::string stamp_text;
        long id = -1;
        double speed = -1;
        const bool parsed = static_cast<bool>(ss >> stamp_text >> id >> speed);
        const std::optional<Timestamp> stamp = parsed ? Timestamp::parseSeconds(stamp_text) : std::nullopt;
        if (!stamp || id < 1 || id > 65535 || !(speed >= 0)) return Error{where + "expected 'timestamp id speed_m_s'"};
        std::vector<std::uint16_t>& ids = still[*stamp];  // every listed frame gets an entry
        if (speed < min_speed) ids.push_back(static_cast<std::uint16_t>(id));
        return Status::success();
      });
  if (!read) return Error{read.error()};
  return still;
}

}  // namespace

Result<std::map<Timestamp, std::string>> readMaskList(const std::string& sequence_dir) {
  const fs::path list = fs::path(sequence_dir) / "mask.txt";
  std::map<Timestamp, std::string> masks;
  const Status listed = forEachRecord(list.string(), "cannot open " + list.string() + " (not a stillpoint-synth sequence?)",
                                      [&](std::istringstream& ss, const std::string& where) -> Status {
    std::string stamp_text, file;
    const std::optional<Timestamp> stamp = (ss >> stamp_text >> file) ? Timestamp::parseSeconds(stamp_text) : std::nullopt;
    if (!stamp) return Error{where + "expected 'timestamp filename'"};
    masks[*stamp] = (fs::path(sequence_dir) / file).string();
    return Status::success();
  });
  if (!listed) return Error{listed.error()};
  return masks;
}

Result<SequenceScoreReport> scoreSequence(const std::string& sequence_dir, const std::string& features_path,
                                          int min_mover_features, double min_speed_m_s) {
  const fs::path list = fs::path(sequence_dir) / "mask.txt";
  Result<std::map<Timestamp, std::string>> listed = readMaskList(sequence_dir);
  if (!listed.ok()) return Error{listed.error()};
  const std::map<Timestamp, std::string> masks = std::move(*listed);
  Result<std::map<Timestamp, std::vector<FlaggedFeature>>> features = readFlaggedFeatures(features_path);
  if (!features.ok()) return Error{features.error()};
  std::map<Timestamp, std::vector<std::uint16_t>> still;
  if (min_speed_m_s > 0) {
    Result<std::map<Timestamp, std::vector<std::uint16_t>>> s =
        readStillMovers(fs::path(sequence_dir) / "movers.txt", min_speed_m_s);
    if (!s.ok()) return Error{s.error()};
    still = std::move(*s);
  }
  SequenceScoreReport report;
  std::vector<FrameScore> scores;
  for (const auto& [stamp, list_features] : *features) {
    auto it = masks.find(stamp);
    if (it == masks.end()) {
      return Error{features_path + ": timestamp " + stamp.toSecondsString() + " is not in " + list.string()};
    }
    Result<cv::Mat> read = dataset::readImageFile("mask", it->second, cv::IMREAD_UNCHANGED);
    if (!read) return Error{read.error()};
    const cv::Mat& mask = *read;
    if (mask.type() != CV_16UC1) return Error{"mask " + it->second + " is not 16-bit"};
    std::span<const std::uint16_t> still_ids;
    if (min_speed_m_s > 0) {
      auto st = still.find(stamp);
      if (st == still.end()) return Error{"movers.txt has no speeds for timestamp " + stamp.toSecondsString()};
      still_ids = st->second;
    }
    report.frames.emplace_back(stamp, scoreFrame(mask, list_features, min_mover_features, still_ids));
    scores.push_back(report.frames.back().second);
  }
  report.frames_without_features = static_cast<int>(masks.size() - report.frames.size());
  report.score = averageScores(scores, min_mover_features);
  return report;
}

}  // namespace stillpoint::synth
