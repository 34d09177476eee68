#pragma once
// What moves, as 3D objects in the map frame (docs/dynamic-objects.md): the
// geometry module's dynamic depth clusters, split into connected regions of
// the image, and the features semantic masks keep out, grouped by class and
// place; both merged where they overlap, then followed from frame to frame
// for a stable id and a velocity.
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "frame.hpp"
#include "stillpoint/slam/outputs.hpp"

namespace stillpoint::slam {

class DynamicObjectTracker {
 public:
  explicit DynamicObjectTracker(const CameraModel& camera) : camera_(camera) {}

  // The objects of `frame` (tracked, its T_c_w set) from `geometry` (this
  // frame's module output; ignored unless it ran) and the frame's
  // kSemanticDynamic features. `class_name` names a Frame::movable_class id.
  // A changed `map_id` forgets every object followed so far.
  std::vector<DynamicObject> update(const Frame& frame, const GeometryOutput& geometry, std::uint32_t map_id,
                                    const std::function<std::string(std::uint8_t)>& class_name);
  // A frame without a pose: objects are followed on only across short gaps.
  void missed(Timestamp stamp);

 private:
  struct Followed {
    DynamicObject object;
    Timestamp seen;
  };
  const CameraModel& camera_;
  std::vector<Followed> followed_;
  std::uint32_t next_id_ = 1;
  std::uint32_t map_id_ = 0;
  bool any_ = false;
};

}  // namespace stillpoint::slam
