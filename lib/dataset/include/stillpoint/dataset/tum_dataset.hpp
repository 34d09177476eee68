#pragma once
// Reader for sequences in the TUM RGB-D benchmark layout: rgb.txt and
// depth.txt list `timestamp filename` per line, images are PNGs relative to
// the dataset folder, depth is 16-bit with a fixed scale to metres.
// Colour and depth are not synchronised; each colour frame is paired with the
// depth frame nearest in time, if that is within a tolerance.
#include <cstddef>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "stillpoint/core/result.hpp"
#include "stillpoint/core/time.hpp"

namespace stillpoint::dataset {

struct RgbdFrame {
  std::size_t index = 0;  // position in the associated pair list
  Timestamp stamp;        // colour image time: the frame's time
  Timestamp depth_stamp;
  cv::Mat bgr;      // CV_8UC3
  cv::Mat gray;     // CV_8UC1
  cv::Mat depth_m;  // CV_32FC1 metres, 0 = no measurement
  std::string rgb_path, depth_path;  // dataset folder joined with the list entry
};

struct DatasetOptions {
  double max_association_dt = 0.02;  // s; colour-depth pairs further apart are dropped
  int expected_width = 0, expected_height = 0;  // 0 = don't check
  double depth_factor = 5000.0;  // raw depth value / depth_factor = metres

  // Names the offending field.
  Status validate() const;
};

// Why load() refused a frame, for callers that keep per-cause counters.
enum class SkipReason {
  kUnreadableColour,  // missing, corrupt/truncated, empty or not 8-bit colour
  kUnreadableDepth,   // missing, corrupt/truncated, empty or not 16-bit single channel
  kWrongSize,         // differs from the expected size or colour and depth differ
  kNoDepthMatch,      // association failures; counted at open(), never returned by load()
  kIndexOutOfRange,   // i >= size()
};
const char* toString(SkipReason reason);

// Reads an image file that must exist and decode to a non-empty image, as
// the frames are read: a PNG or JPEG larger than any camera's image is
// refused from its header before decoding, and nothing OpenCV throws
// escapes. `what` names the file's role in the error ("mover mask").
Result<cv::Mat> readImageFile(const std::string& what, const std::string& path, int flags);

class TumDataset {
 public:
  // Reads and associates the lists. Errors name the file and, for content
  // problems, the line: missing folder or list, malformed line, bad or
  // non-increasing timestamp, empty list, invalid options.
  static Result<TumDataset> open(const std::string& dir, const DatasetOptions& options = {});

  // Number of associated colour/depth pairs.
  std::size_t size() const { return pairs_.size(); }
  // The colour stamp of pair i (i < size()), from the list: known even when
  // its images cannot be read.
  Timestamp stamp(std::size_t i) const { return pairs_.at(i).colour_stamp; }

  // Loads pair i. A bad frame gives an Error naming the file and the cause
  // (missing, unreadable/corrupt PNG, wrong size, wrong pixel type, depth all
  // zero); the caller counts it as skipped. `reason`, when given, receives the
  // cause on failure. Never throws.
  Result<RgbdFrame> load(std::size_t i, SkipReason* reason = nullptr) const;

  // Colour frames with no depth frame within max_association_dt.
  std::size_t unassociatedColourFrames() const { return unassociated_colour_; }

  bool hasGroundTruth() const { return !ground_truth_path_.empty(); }
  // Path of groundtruth.txt, or "" when the dataset has none.
  std::string groundTruthPath() const { return ground_truth_path_; }
  const std::string& directory() const { return directory_; }

 private:
  struct Pair {
    Timestamp colour_stamp, depth_stamp;
    std::string rgb_path, depth_path;  // full paths
  };

  TumDataset() = default;

  std::string directory_;
  DatasetOptions options_;
  std::vector<Pair> pairs_;
  std::size_t unassociated_colour_ = 0;
  std::string ground_truth_path_;
};

}  // namespace stillpoint::dataset
