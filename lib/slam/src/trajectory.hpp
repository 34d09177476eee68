#pragma once
// Trajectory bookkeeping: each tracked frame's pose relative to its reference
// keyframe's anchor, so that it follows bundle adjustment and survives the
// keyframe's culling.
#include <deque>
#include <memory>
#include <optional>

#include "map.hpp"

namespace stillpoint::slam {

struct TrajectoryRecord {
  Timestamp stamp;
  std::shared_ptr<const PoseAnchor> reference;
  SE3 T_c_ref;
  std::uint32_t map_id = 0;
  SE3 T_c_w() const { return renormalized(T_c_ref * reference->T_c_w()); }
};

// The last tracked frame, and the most recent `keep` records (-1: all, 0:
// none; a long-running process that writes no trajectory keeps none).
class TrajectoryLog {
 public:
  explicit TrajectoryLog(int keep) : keep_(keep) {}
  void record(const TrajectoryRecord& r) {
    last_ = r;
    if (keep_ == 0) return;
    records_.push_back(r);
    if (keep_ > 0 && records_.size() > static_cast<std::size_t>(keep_)) records_.pop_front();
  }
  const std::optional<TrajectoryRecord>& last() const { return last_; }
  // Records of map `from` are in map `into` now (maps merged).
  void relabel(std::uint32_t from, std::uint32_t into) {
    for (TrajectoryRecord& r : records_)
      if (r.map_id == from) r.map_id = into;
    if (last_ && last_->map_id == from) last_->map_id = into;
  }
  const std::deque<TrajectoryRecord>& records() const { return records_; }

 private:
  int keep_;
  std::optional<TrajectoryRecord> last_;
  std::deque<TrajectoryRecord> records_;
};

}  // namespace stillpoint::slam
