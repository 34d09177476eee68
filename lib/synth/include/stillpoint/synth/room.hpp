#pragma once
// The fully synthetic scene: a textured room with furniture (floor at z = 0,
// z up) and camera trajectories that mirror the TUM RGB-D motions.
#include <cstdint>
#include <string>
#include <vector>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/geometry.hpp"
#include "stillpoint/core/result.hpp"
#include "stillpoint/synth/config.hpp"
#include "stillpoint/synth/raster.hpp"

namespace stillpoint::synth {

struct Room {
  Mesh mesh;  // every triangle has id 0 (static)
  std::vector<TexturePtr> textures;  // owned textures the mesh points into
};

// Builds the room; photos (RoomOptions::photos, relative to base_dir) hang on
// the walls. Errors name an unreadable photo.
Result<Room> buildRoom(const RoomOptions& options, const std::string& base_dir, std::uint64_t seed);

// Camera pose T_w_c at time t (s) for a TUM-like motion:
// static (tripod, sub-millimetre tremor), xyz (translations along the camera
// axes, fixed orientation), rpy (rotations about the camera axes, fixed
// position), halfsphere (orbit on a sphere around a point it keeps looking at),
// loop (laps round the room looking out at the walls, 20 s each: revisits).
SE3 roomCameraPose(CameraMotion motion, double t);

// TUM fr3 intrinsics scaled to width x height, no distortion.
CameraModel roomCamera(int width, int height);

}  // namespace stillpoint::synth
