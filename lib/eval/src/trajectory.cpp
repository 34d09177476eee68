#include "stillpoint/eval/trajectory.hpp"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string_view>
#include <vector>

#include "stillpoint/core/covariance.hpp"

namespace stillpoint::eval {
namespace {

constexpr double kUnitQuaternionTolerance = 1e-2;
constexpr std::size_t kFieldCount = 8;

Error lineError(const std::string& path, std::size_t line, const std::string& what) {
  return Error{path + ":" + std::to_string(line) + ": " + what};
}

// Splits on spaces, tabs and commas (the TUM tools accept all three); a
// table of whitespace-separated columns keeps commas within a field.
std::vector<std::string_view> splitFields(std::string_view line, bool commas = true) {
  std::vector<std::string_view> fields;
  std::size_t i = 0;
  const auto is_sep = [commas](char c) { return c == ' ' || c == '\t' || (commas && c == ',') || c == '\r'; };
  while (i < line.size()) {
    while (i < line.size() && is_sep(line[i])) ++i;
    const std::size_t start = i;
    while (i < line.size() && !is_sep(line[i])) ++i;
    if (i > start) fields.push_back(line.substr(start, i - start));
  }
  return fields;
}

bool parseFiniteDouble(std::string_view text, double* out) {
  if (!text.empty() && text.front() == '+') text.remove_prefix(1);
  double value = 0.0;
  const char* end = text.data() + text.size();
  const auto [ptr, ec] = std::from_chars(text.data(), end, value);
  if (ec != std::errc() || ptr != end || !std::isfinite(value)) return false;
  *out = value;
  return true;
}

// Exact decimal parse first; scientific notation falls back to double, which
// is as exact as the file itself.
std::optional<Timestamp> parseStamp(std::string_view text) {
  if (auto exact = Timestamp::parseSeconds(text)) return exact;
  double seconds = 0.0;
  if (parseFiniteDouble(text, &seconds) && std::abs(seconds) <= Timestamp::kMaxSeconds) {
    return Timestamp::fromSeconds(seconds);
  }
  return std::nullopt;
}

bool isBlankOrComment(std::string_view line) {
  for (char c : line) {
    if (c == '#') return true;
    if (c != ' ' && c != '\t' && c != '\r') return false;
  }
  return true;
}

// The column names of a header comment line ("# index timestamp ...").
std::vector<std::string_view> headerNames(std::string_view line) {
  return splitFields(line.substr(line.find('#') + 1), false);
}

}  // namespace

Result<Trajectory> readTumTrajectory(const std::string& path) {
  std::ifstream in(path);
  if (!in) return Error{path + ": cannot open trajectory file"};

  Trajectory trajectory;
  std::string line;
  std::size_t line_number = 0;
  std::uint32_t map_id = 0;
  while (std::getline(in, line)) {
    ++line_number;
    if (isBlankOrComment(line)) {
      unsigned id = 0;
      char extra = 0;
      if (std::sscanf(line.c_str(), " # map %u %c", &id, &extra) == 1) map_id = id;
      continue;
    }

    const auto fields = splitFields(line);
    if (fields.size() != kFieldCount) {
      return lineError(path, line_number,
                       "expected 8 fields (timestamp tx ty tz qx qy qz qw), found " +
                           std::to_string(fields.size()));
    }
    const auto stamp = parseStamp(fields[0]);
    if (!stamp) {
      return lineError(path, line_number, "bad timestamp '" + std::string(fields[0]) + "'");
    }
    std::array<double, 7> v{};
    for (std::size_t k = 0; k < v.size(); ++k) {
      if (!parseFiniteDouble(fields[k + 1], &v[k])) {
        return lineError(path, line_number,
                         "field " + std::to_string(k + 2) + " is not a finite number: '" +
                             std::string(fields[k + 1]) + "'");
      }
    }
    // Positions beyond 1000 km are corrupt (their squares overflow the errors).
    for (std::size_t k = 0; k < 3; ++k)
      if (std::abs(v[k]) > 1e6)
        return lineError(path, line_number, "position field " + std::to_string(k + 2) + " is out of range: '" +
                                                std::string(fields[k + 1]) + "' (at most 1e6 m)");
    // Eigen's constructor order is (w, x, y, z); the file order is x y z w.
    Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
    const double norm = q.norm();
    if (!(norm > 1e-12)) return lineError(path, line_number, "zero quaternion");
    if (std::abs(norm - 1.0) > kUnitQuaternionTolerance) {
      std::ostringstream os;
      os << "quaternion is not unit length (norm " << norm << ")";
      return lineError(path, line_number, os.str());
    }
    if (!trajectory.empty() && !(trajectory.back().stamp < *stamp)) {
      return lineError(path, line_number,
                       "timestamp " + std::string(fields[0]) +
                           " is not after the previous one (" +
                           trajectory.back().stamp.toSecondsString() + ")");
    }
    trajectory.push_back({*stamp, makeSE3(q, Vec3(v[0], v[1], v[2])), map_id});
  }
  if (in.bad()) return Error{path + ": read error after line " + std::to_string(line_number)};
  return trajectory;
}

Result<bool> namesColumn(const std::string& path, const std::string& column) {
  std::ifstream in(path);
  if (!in) return Error{path + ": cannot open"};
  std::string line;
  if (std::getline(in, line) && isBlankOrComment(line)) {
    const auto names = headerNames(line);
    return std::find(names.begin(), names.end(), column) != names.end();
  }
  return Error{path + ": no header comment naming the columns"};
}

Result<std::vector<StampedLabel>> readLabelColumn(const std::string& path, const std::string& column) {
  std::ifstream in(path);
  if (!in) return Error{path + ": cannot open"};
  std::string line;
  std::size_t line_number = 0;
  std::size_t stamp_at = 0, label_at = 0, needed = 0;
  bool header = false;
  std::vector<StampedLabel> labels;
  while (std::getline(in, line)) {
    ++line_number;
    if (isBlankOrComment(line)) {
      if (header) continue;
      auto names = headerNames(line);
      const auto find = [&names](std::string_view name) {
        return static_cast<std::size_t>(std::find(names.begin(), names.end(), name) - names.begin());
      };
      stamp_at = find("timestamp");
      label_at = find(column);
      if (stamp_at == names.size()) return lineError(path, line_number, "the header names no column 'timestamp'");
      if (label_at == names.size()) return lineError(path, line_number, "the header names no column '" + column + "'");
      needed = std::max(stamp_at, label_at) + 1;
      header = true;
      continue;
    }
    if (!header) return lineError(path, line_number, "a row before the header comment that names the columns");
    const auto fields = splitFields(line, false);
    if (fields.size() < needed) {
      return lineError(path, line_number, "expected at least " + std::to_string(needed) + " fields, found " +
                                              std::to_string(fields.size()));
    }
    const auto stamp = parseStamp(fields[stamp_at]);
    if (!stamp) return lineError(path, line_number, "bad timestamp '" + std::string(fields[stamp_at]) + "'");
    labels.push_back({*stamp, std::string(fields[label_at])});
  }
  if (in.bad()) return Error{path + ": read error after line " + std::to_string(line_number)};
  if (!header) return Error{path + ": no header comment naming the columns"};
  return labels;
}

Result<std::vector<StampedCovariance>> readCovarianceColumn(const std::string& path) {
  const auto fields = readLabelColumn(path, "covariance");
  if (!fields) return Error{fields.error()};
  std::vector<StampedCovariance> out;
  out.reserve(fields->size());
  for (const StampedLabel& field : *fields) {
    std::vector<double> values;
    std::istringstream numbers(field.label);
    for (std::string number; std::getline(numbers, number, ',');) {
      char* end = nullptr;
      const double value = std::strtod(number.c_str(), &end);
      if (number.empty() || *end != '\0' || !std::isfinite(value)) break;
      values.push_back(value);
    }
    std::array<double, 21> upper{};
    if (values.size() != upper.size() || !numbers.eof())
      return Error{path + ": frame " + field.stamp.toSecondsString() + ": the covariance is not 21 numbers joined by ','"};
    std::copy(values.begin(), values.end(), upper.begin());
    out.push_back({field.stamp, fromUpperTriangle(upper)});
  }
  return out;
}

Status writeTumTrajectory(const std::string& path, const Trajectory& trajectory) {
  std::FILE* file = std::fopen(path.c_str(), "w");
  if (file == nullptr) return Error{path + ": cannot open for writing"};

  bool ok = std::fputs("# timestamp tx ty tz qx qy qz qw\n", file) >= 0;
  std::uint32_t map_id = 0;
  for (const StampedPose& pose : trajectory) {
    if (!ok) break;
    if (pose.map_id != map_id) {
      map_id = pose.map_id;
      ok = std::fprintf(file, "# map %u\n", static_cast<unsigned>(map_id)) > 0;
    }
    Eigen::Quaterniond q(pose.T_w_c.linear());
    q.normalize();
    // q and -q are the same rotation; the positive-w half keeps files diffable.
    if (q.w() < 0.0) q.coeffs() = -q.coeffs();
    const Vec3 t = pose.T_w_c.translation();
    ok = std::fprintf(file, "%s %.9g %.9g %.9g %.9g %.9g %.9g %.9g\n",
                      pose.stamp.toSecondsString().c_str(), t.x(), t.y(), t.z(), q.x(), q.y(),
                      q.z(), q.w()) > 0;
  }
  const bool closed = std::fclose(file) == 0;
  if (!ok || !closed) return Error{path + ": write failed"};
  return Status::success();
}

}  // namespace stillpoint::eval
