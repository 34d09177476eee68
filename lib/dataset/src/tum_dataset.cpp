#include "stillpoint/dataset/tum_dataset.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string_view>
#include <system_error>
#include <utility>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stillpoint/core/log.hpp"

namespace stillpoint::dataset {
namespace {

namespace fs = std::filesystem;

const log::Logger& logger() {
  static const log::Logger instance("dataset");
  return instance;
}

struct ListEntry {
  Timestamp stamp;
  std::string file;  // as written in the list, relative to the dataset folder
};

std::vector<std::string_view> splitWhitespace(std::string_view line) {
  std::vector<std::string_view> fields;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
    const std::size_t start = i;
    while (i < line.size() && line[i] != ' ' && line[i] != '\t') ++i;
    if (i > start) fields.push_back(line.substr(start, i - start));
  }
  return fields;
}

std::string quoted(std::string_view text) {
  constexpr std::size_t kMaxShown = 60;  // keep messages readable for binary junk
  std::string out = "'";
  out.append(text.substr(0, kMaxShown));
  if (text.size() > kMaxShown) out += "...";
  out += "'";
  return out;
}

// Reads a `timestamp filename` list. Comments (#) and blank lines are allowed;
// timestamps must increase strictly so association can binary-search them.
Result<std::vector<ListEntry>> readList(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) {
    return Error{"list file " + path.string() + " does not exist or is not a regular file"};
  }
  std::ifstream in(path);
  if (!in) return Error{"cannot open list file " + path.string()};

  std::vector<ListEntry> entries;
  std::string line;
  std::size_t line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    const std::string where = path.string() + ":" + std::to_string(line_number) + ": ";
    std::string_view view(line);
    if (!view.empty() && view.back() == '\r') view.remove_suffix(1);  // CRLF files
    const auto fields = splitWhitespace(view);
    if (fields.empty() || fields[0].front() == '#') continue;
    if (fields.size() != 2) {
      return Error{where + "expected 'timestamp filename', got " + std::to_string(fields.size()) +
                   " field(s) in " + quoted(view)};
    }
    const auto stamp = Timestamp::parseSeconds(fields[0]);
    if (!stamp) {
      const std::string text(fields[0]);
      char* end = nullptr;
      const double value = std::strtod(text.c_str(), &end);
      if (end && *end == '\0' && std::isfinite(value) && std::abs(value) > Timestamp::kMaxSeconds)
        return Error{where + "timestamp " + quoted(fields[0]) + " is out of range (at most 9e9 s)"};
      return Error{where + "bad timestamp " + quoted(fields[0])};
    }
    if (!entries.empty() && *stamp <= entries.back().stamp) {
      return Error{where + "timestamp " + std::string(fields[0]) +
                   " is not after the previous one (" + entries.back().stamp.toSecondsString() +
                   "); timestamps must increase strictly"};
    }
    entries.push_back({*stamp, std::string(fields[1])});
  }
  if (in.bad()) {
    return Error{"read error in " + path.string() + " after line " + std::to_string(line_number)};
  }
  if (entries.empty()) return Error{"list file " + path.string() + " has no entries"};
  return entries;
}

// |a - b| in ns, exact for any pair of stamps (no signed overflow on absurd input).
std::uint64_t absDifferenceNs(Timestamp a, Timestamp b) {
  const auto ua = static_cast<std::uint64_t>(a.nanoseconds());
  const auto ub = static_cast<std::uint64_t>(b.nanoseconds());
  return a >= b ? ua - ub : ub - ua;
}

// Index of the depth stamp nearest to `t` (ties go to the earlier one).
std::size_t nearestIndex(const std::vector<ListEntry>& sorted, Timestamp t) {
  const auto it = std::lower_bound(sorted.begin(), sorted.end(), t,
                                   [](const ListEntry& e, Timestamp s) { return e.stamp < s; });
  if (it == sorted.begin()) return 0;
  if (it == sorted.end()) return sorted.size() - 1;
  const auto before = std::prev(it);
  const bool take_before = absDifferenceNs(t, before->stamp) <= absDifferenceNs(it->stamp, t);
  return static_cast<std::size_t>((take_before ? before : it) - sorted.begin());
}

std::string sizeText(const cv::Mat& m) {
  return std::to_string(m.cols) + "x" + std::to_string(m.rows);
}

// imread without exceptions: OpenCV may throw on pathological headers.
cv::Mat readImage(const std::string& path, int flags, std::string* failure) {
  try {
    return cv::imread(path, flags);
  } catch (const cv::Exception& e) {
    *failure = e.what();
  } catch (const std::exception& e) {
    *failure = e.what();
  }
  return {};
}

// Reads an image file that must exist and decode to a non-empty image.
Result<cv::Mat> readExisting(const std::string& what, const std::string& path, int flags) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return Error{what + " " + path + " does not exist"};
  if (!fs::is_regular_file(path, ec)) return Error{what + " " + path + " is not a regular file"};
  std::string failure;
  cv::Mat image = readImage(path, flags, &failure);
  if (image.empty()) {
    std::string message =
        what + " " + path + " could not be decoded (unreadable, corrupt or truncated PNG)";
    if (!failure.empty()) message += ": " + failure;
    return Error{message};
  }
  if (image.rows <= 0 || image.cols <= 0) return Error{what + " " + path + " has zero size"};
  return image;
}

// A PNG's size, read from its header (IHDR) before anything is decoded: a
// small file can decode to gigabytes (1.1 MB -> 20000x20000 RGB). False when
// the file is no PNG or too short; the decoder then has its say.
bool pngSize(const std::string& path, std::uint32_t* width, std::uint32_t* height) {
  std::ifstream in(path, std::ios::binary);
  unsigned char h[24];
  if (!in.read(reinterpret_cast<char*>(h), sizeof(h))) return false;
  static const unsigned char kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  if (!std::equal(kSignature, kSignature + 8, h) || !std::equal(h + 12, h + 16, "IHDR")) return false;
  const auto be32 = [&](int at) {
    return std::uint32_t(h[at]) << 24 | std::uint32_t(h[at + 1]) << 16 | std::uint32_t(h[at + 2]) << 8 | h[at + 3];
  };
  *width = be32(16);
  *height = be32(20);
  return true;
}

// A JPEG's size, from its first frame header (SOFn) before anything is
// decoded, as pngSize. False when the file is no JPEG or has no such header.
bool jpegSize(const std::string& path, std::uint32_t* width, std::uint32_t* height) {
  std::ifstream in(path, std::ios::binary);
  unsigned char b[9];
  if (!in.read(reinterpret_cast<char*>(b), 2) || b[0] != 0xff || b[1] != 0xd8) return false;
  for (int segments = 0; segments < 1000 && in.read(reinterpret_cast<char*>(b), 2); ++segments) {
    if (b[0] != 0xff) return false;
    while (b[1] == 0xff)  // fill bytes before a marker
      if (!in.read(reinterpret_cast<char*>(b + 1), 1)) return false;
    const unsigned char marker = b[1];
    if (marker == 0x01 || (marker >= 0xd0 && marker <= 0xd7)) continue;  // no length follows
    if (marker == 0xd9 || marker == 0xda) return false;                 // image data before a frame header
    if (!in.read(reinterpret_cast<char*>(b + 2), 2)) return false;
    const int length = b[2] << 8 | b[3];
    if (length < 2) return false;
    const bool frame_header = marker >= 0xc0 && marker <= 0xcf && marker != 0xc4 && marker != 0xc8 && marker != 0xcc;
    if (frame_header) {
      if (length < 7 || !in.read(reinterpret_cast<char*>(b + 4), 5)) return false;
      *height = std::uint32_t(b[5]) << 8 | b[6];
      *width = std::uint32_t(b[7]) << 8 | b[8];
      return true;
    }
    in.seekg(length - 2, std::ios::cur);
  }
  return false;
}

// Images no camera of ours produces: refused before decoding.
constexpr std::uint64_t kMaxPixels = 8192ull * 8192ull;

// The PNG or JPEG header's size against the expected one (<= 0: any) and
// the limit. Other formats go to the decoder (OpenCV's own limit: 2^30 pixels).
std::optional<std::string> headerSizeError(const std::string& what, const std::string& path, int want_w,
                                           int want_h) {
  std::uint32_t w = 0, h = 0;
  if (!pngSize(path, &w, &h) && !jpegSize(path, &w, &h)) return std::nullopt;
  const std::string size = std::to_string(w) + "x" + std::to_string(h);
  if (std::uint64_t(w) * h > kMaxPixels) return what + " " + path + " is " + size + ": larger than any camera's (not decoded)";
  if ((want_w > 0 && w != std::uint32_t(want_w)) || (want_h > 0 && h != std::uint32_t(want_h)))
    return what + " " + path + " is " + size + "; expected " + (want_w > 0 ? std::to_string(want_w) : "any") + "x" +
           (want_h > 0 ? std::to_string(want_h) : "any");
  return std::nullopt;
}

Result<cv::Mat> loadColour(const std::string& path) {
  auto raw = readExisting("colour image", path, cv::IMREAD_UNCHANGED);
  if (!raw) return raw;
  cv::Mat& image = *raw;
  if (image.depth() != CV_8U) {
    return Error{"colour image " + path + " has pixel type " + cv::typeToString(image.type()) +
                 "; expected 8-bit colour (CV_8UC3)"};
  }
  cv::Mat bgr;
  switch (image.channels()) {
    case 3: bgr = image; break;
    case 1: cv::cvtColor(image, bgr, cv::COLOR_GRAY2BGR); break;
    case 4: cv::cvtColor(image, bgr, cv::COLOR_BGRA2BGR); break;
    default:
      return Error{"colour image " + path + " has " + std::to_string(image.channels()) +
                   " channels; expected 1, 3 or 4"};
  }
  return bgr;
}

Result<cv::Mat> loadRawDepth(const std::string& path) {
  auto raw = readExisting("depth image", path, cv::IMREAD_ANYDEPTH | cv::IMREAD_ANYCOLOR);
  if (!raw) return raw;
  if (raw->type() != CV_16UC1) {
    return Error{"depth image " + path + " has pixel type " + cv::typeToString(raw->type()) +
                 "; expected 16-bit single channel (CV_16UC1)"};
  }
  return raw;
}

Result<RgbdFrame> fail(SkipReason reason, std::string message, SkipReason* out) {
  if (out) *out = reason;
  return Error{std::move(message)};
}

}  // namespace

const char* toString(SkipReason reason) {
  switch (reason) {
    case SkipReason::kUnreadableColour: return "unreadable colour";
    case SkipReason::kUnreadableDepth: return "unreadable depth";
    case SkipReason::kWrongSize: return "wrong size";
    case SkipReason::kNoDepthMatch: return "no depth match";
    case SkipReason::kIndexOutOfRange: return "index out of range";
  }
  return "unknown";
}

Status DatasetOptions::validate() const {
  if (!std::isfinite(max_association_dt) || max_association_dt < 0 || max_association_dt > 1e6) {
    return Error{"DatasetOptions.max_association_dt must be finite, >= 0 and <= 1e6 s, got " +
                 std::to_string(max_association_dt)};
  }
  if (expected_width < 0) {
    return Error{"DatasetOptions.expected_width must be >= 0 (0 = don't check), got " +
                 std::to_string(expected_width)};
  }
  if (expected_height < 0) {
    return Error{"DatasetOptions.expected_height must be >= 0 (0 = don't check), got " +
                 std::to_string(expected_height)};
  }
  if (!std::isfinite(depth_factor) || depth_factor <= 0) {
    return Error{"DatasetOptions.depth_factor must be finite and > 0, got " +
                 std::to_string(depth_factor)};
  }
  return Status::success();
}

Result<TumDataset> TumDataset::open(const std::string& dir, const DatasetOptions& options) {
  if (Status valid = options.validate(); !valid) return Error{valid.error()};
  std::error_code ec;
  const fs::path root(dir);
  if (!fs::exists(root, ec)) return Error{"dataset directory " + dir + " does not exist"};
  if (!fs::is_directory(root, ec)) return Error{"dataset path " + dir + " is not a directory"};

  auto colour = readList(root / "rgb.txt");
  if (!colour) return Error{colour.error()};
  auto depth = readList(root / "depth.txt");
  if (!depth) return Error{depth.error()};

  TumDataset dataset;
  dataset.directory_ = dir;
  dataset.options_ = options;
  const auto max_dt_ns = static_cast<std::uint64_t>(std::llround(options.max_association_dt * 1e9));
  for (const ListEntry& c : *colour) {
    const ListEntry& d = (*depth)[nearestIndex(*depth, c.stamp)];
    if (absDifferenceNs(d.stamp, c.stamp) > max_dt_ns) {
      ++dataset.unassociated_colour_;
      continue;
    }
    dataset.pairs_.push_back(
        {c.stamp, d.stamp, (root / c.file).string(), (root / d.file).string()});
  }
  if (dataset.pairs_.empty()) {
    return Error{"dataset " + dir + ": none of the " + std::to_string(colour->size()) +
                 " colour frames has a depth frame within " +
                 std::to_string(options.max_association_dt) + " s"};
  }

  const fs::path ground_truth = root / "groundtruth.txt";
  if (fs::is_regular_file(ground_truth, ec)) dataset.ground_truth_path_ = ground_truth.string();

  SP_INFO(logger(), "opened " << dir << ": " << dataset.pairs_.size() << " colour/depth pairs from "
                              << colour->size() << " colour and " << depth->size()
                              << " depth frames"
                              << (dataset.hasGroundTruth() ? ", with ground truth" : ""));
  if (dataset.unassociated_colour_ > 0) {
    SP_WARN(logger(), dir << ": " << dataset.unassociated_colour_
                          << " colour frame(s) have no depth frame within "
                          << options.max_association_dt << " s and are skipped");
  }
  return dataset;
}

Result<RgbdFrame> TumDataset::load(std::size_t i, SkipReason* reason) const {
  if (i >= pairs_.size()) {
    return fail(SkipReason::kIndexOutOfRange,
                "frame index " + std::to_string(i) + " is out of range (dataset " + directory_ +
                    " has " + std::to_string(pairs_.size()) + " pairs)",
                reason);
  }
  const Pair& pair = pairs_[i];
  RgbdFrame frame;
  frame.index = i;
  frame.stamp = pair.colour_stamp;
  frame.depth_stamp = pair.depth_stamp;
  frame.rgb_path = pair.rgb_path;
  frame.depth_path = pair.depth_path;

  // cvtColor/convertTo only throw on allocation failure here; still never let
  // an exception cross the library boundary.
  try {
    const int want_w = options_.expected_width;
    const int want_h = options_.expected_height;
    if (auto e = headerSizeError("colour image", pair.rgb_path, want_w, want_h))
      return fail(SkipReason::kWrongSize, *e, reason);
    if (auto e = headerSizeError("depth image", pair.depth_path, want_w, want_h))
      return fail(SkipReason::kWrongSize, *e, reason);
    auto bgr = loadColour(pair.rgb_path);
    if (!bgr) return fail(SkipReason::kUnreadableColour, bgr.error(), reason);
    auto raw_depth = loadRawDepth(pair.depth_path);
    if (!raw_depth) return fail(SkipReason::kUnreadableDepth, raw_depth.error(), reason);

    if ((want_w > 0 && bgr->cols != want_w) || (want_h > 0 && bgr->rows != want_h)) {
      return fail(SkipReason::kWrongSize,
                  "colour image " + pair.rgb_path + " is " + sizeText(*bgr) + "; expected " +
                      (want_w > 0 ? std::to_string(want_w) : "any") + "x" +
                      (want_h > 0 ? std::to_string(want_h) : "any"),
                  reason);
    }
    if (raw_depth->size() != bgr->size()) {
      return fail(SkipReason::kWrongSize,
                  "depth image " + pair.depth_path + " is " + sizeText(*raw_depth) +
                      " but colour image " + pair.rgb_path + " is " + sizeText(*bgr),
                  reason);
    }
    // An all-zero depth image (a covered camera) is a frame: tracking says
    // it has no depth (TrackingState::kNoDepth) rather than never seeing it.
    frame.bgr = std::move(*bgr);
    cv::cvtColor(frame.bgr, frame.gray, cv::COLOR_BGR2GRAY);
    raw_depth->convertTo(frame.depth_m, CV_32F, 1.0 / options_.depth_factor);
  } catch (const std::exception& e) {
    return fail(SkipReason::kUnreadableColour,
                "frame " + std::to_string(i) + " (" + pair.rgb_path + ", " + pair.depth_path +
                    "): " + e.what(),
                reason);
  }
  return frame;
}

Result<cv::Mat> readImageFile(const std::string& what, const std::string& path, int flags) {
  if (auto e = headerSizeError(what, path, 0, 0)) return Error{*e};
  return readExisting(what, path, flags);
}

}  // namespace stillpoint::dataset
