#pragma once
// The map on disk: a versioned, checksummed binary file holding every
// keyframe (features, depth, pose, map, spanning-tree parent) and every map
// point (position, observations) of the maps in memory, and where the
// semantic module saw static objects and movers (StaticSightings).
//
// Layout (little-endian):
//   header, 40 bytes: magic "STPMAP\r\n", u32 format version, u32 reserved (0),
//                     u64 payload bytes, u64 FNV-1a 64 of the payload, u64 reserved (0)
//   payload: camera (width, height, fx, fy, cx, cy), ORB pyramid (levels,
//            scale factor), (version 3) the camera's virtual baseline and
//            distortion, id counters, maps started and the active map,
//            then the points (id, position) and the keyframes (id, map,
//            origin, stamp, T_c_w, parent, thumbnail, features: keypoint,
//            undistorted position, depth, virtual right u, descriptor,
//            point id or -1, dynamic cause, colour when the frame had one),
//            then (version 2) the sightings (map id and cell, static and
//            moving counts, first and last static stamp; versions 2 and 3
//            name the map and cell by one 64-bit key, 10 bits of map id).
// Version 1 files (no sightings), version 2 files (no baseline and
// distortion: not checked) and version 3 files are read too. A file that is truncated,
// corrupt, of another version or for another
// camera is an error naming the file and what is wrong; the reader checks
// every count and index against the bytes that remain, never trusts them.
#include <string>

#include "map.hpp"
#include "stillpoint/core/result.hpp"

namespace stillpoint::slam {

inline constexpr std::uint32_t kMapFormatVersion = 4;

// Writes the map (caller holds the map's lock, shared at least).
Status saveMap(const Map& map, const CameraModel& camera, const LevelInfo& levels, const std::string& path);

// Reads a map file into an empty map. `camera` and `levels` must match the
// file's (they are the frames' camera and pyramid from now on).
Status loadMap(const std::string& path, const CameraModel& camera, const LevelInfo& levels, Map* map);

}  // namespace stillpoint::slam
