#pragma once
// Camera trajectories in the TUM RGB-D benchmark text format:
//   timestamp tx ty tz qx qy qz qw
// one pose per line, '#' starts a comment line, blank lines are ignored.
#include <cstdint>
#include <string>
#include <vector>

#include "stillpoint/core/geometry.hpp"
#include "stillpoint/core/result.hpp"
#include "stillpoint/core/time.hpp"

namespace stillpoint::eval {

struct StampedPose {
  Timestamp stamp;
  SE3 T_w_c = SE3::Identity();
  // The map the pose is in (a SLAM system that started a new map after a
  // loss); files mark a change with a comment line "# map N".
  std::uint32_t map_id = 0;
};

// Poses in strictly increasing time order.
using Trajectory = std::vector<StampedPose>;

// Reads a TUM trajectory. Fields may be separated by spaces, tabs or commas;
// a comment line "# map N" puts the poses after it in map N.
// Quaternions within 1e-2 of unit norm are normalised; others are rejected.
// Every error message names the file and, for content errors, the line number
// ("path:12: ...").
Result<Trajectory> readTumTrajectory(const std::string& path);

// One text label per timestamp.
struct StampedLabel {
  Timestamp stamp;
  std::string label;
};

// Reads one column of a whitespace-separated table whose first comment line
// names its columns, as the replay's frame log does ("# index timestamp state
// ... health ..."): for every row, its `timestamp` and its field in `column`.
// Rows in any time order. Errors name the file (and the line): no header, no
// such column, a short row, a bad timestamp.
Result<std::vector<StampedLabel>> readLabelColumn(const std::string& path, const std::string& column);
// Whether that header comment names `column` (a frame log written before a
// column was added does not). Errors: the file cannot be read, no header.
Result<bool> namesColumn(const std::string& path, const std::string& column);

// A pose covariance per timestamp: the frame log's `covariance` column (its
// upper triangle row by row, 21 numbers joined by ','; position, then
// rotation about the map's axes). All zero: the frame had no pose.
struct StampedCovariance {
  Timestamp stamp;
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
};
// Reads that column (readLabelColumn's errors, and a field that is not 21
// finite numbers, named with its timestamp).
Result<std::vector<StampedCovariance>> readCovarianceColumn(const std::string& path);

// Writes a TUM trajectory: timestamps with Timestamp::toSecondsString()
// (microseconds), numbers with 9 significant digits, quaternion sign chosen so
// that qw >= 0.
Status writeTumTrajectory(const std::string& path, const Trajectory& trajectory);

}  // namespace stillpoint::eval
