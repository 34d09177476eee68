#pragma once
// Small rules the dynamic-object pipeline applies in several places, each
// written once.
#include <cmath>

namespace stillpoint::geometry {

// The view veto: when `dynamic` of `total` (features, samples) would be
// dynamic and that is more than `max_fraction`, the pose the cue was judged
// under is what is wrong, not the world (geometry.max_dynamic_fraction).
constexpr bool mostOfViewDynamic(double dynamic, double total, double max_fraction) {
  return dynamic > max_fraction * total;
}

// The same-surface rule: a feature at depth `other_z` lies on the surface of
// one at depth `z` (m) when they are within 10 cm + 5 % of z. Masks and
// flags grow over features this close, never across a depth jump.
inline bool sameSurface(float other_z, float z) { return std::abs(other_z - z) < 0.1f + 0.05f * z; }

}  // namespace stillpoint::geometry
