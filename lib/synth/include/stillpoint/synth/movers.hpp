#pragma once
// Movers: textured objects that move along smooth paths in a "stage" frame
// anchored at the first camera, and their triangle meshes at a given time.
//
// Stage frame S: origin on the floor (world z = 0) below the first camera's
// centre, z up (world z), y = the first camera's viewing direction projected
// onto the floor, x = y cross z (to the right). TUM fr3 and the synthetic rooms
// both have z up with the floor at z = 0.
#include <cstdint>
#include <array>
#include <string>
#include <vector>

#include "stillpoint/core/geometry.hpp"
#include "stillpoint/core/result.hpp"
#include "stillpoint/synth/raster.hpp"

namespace stillpoint::synth {

enum class PathType {
  kStatic,          // stays at start
  kOscillate,       // start <-> end, sinusoidal, period_s
  kWalk,            // start -> end -> start ... at speed, easing in and out at each end
  kStopAndGo,       // moves for go_s, stops for stop_s, back and forth between start and end
  kStaticThenMove,  // stays at start for hold_s, then walks
};

struct PathSpec {
  PathType type = PathType::kStatic;
  Vec3 start{0.0, 1.5, 1.2};  // stage coordinates (m)
  Vec3 end{0.0, 1.5, 1.2};
  double speed_m_s = 0.5;  // mean speed of walk legs
  double period_s = 4.0;   // oscillate
  double hold_s = 2.0;     // static_then_move
  double go_s = 1.0;       // stop_and_go
  double stop_s = 1.0;     // stop_and_go
  double phase_s = 0.0;    // added to the time before evaluating
};

struct PathState {
  Vec3 position = Vec3::Zero();
  Vec3 velocity = Vec3::Zero();  // m/s
  Vec3 heading = Vec3::UnitY();  // horizontal unit direction of the current (or last) motion
  double travelled_m = 0.0;      // path length covered since t = 0
};

// Position of the path at time t (s since the first frame).
PathState evaluatePath(const PathSpec& path, double t);

enum class MoverShape {
  kPoster,  // vertical plane, size = (width, height, -), faces the first camera at yaw 0
  kBox,     // size = (width along x, height along z, depth along y) at yaw 0
  kWalker,  // articulated person, size = (shoulder width, height, body depth)
};

struct MoverSpec {
  std::string name = "mover";
  MoverShape shape = MoverShape::kPoster;
  // A texture style (paper, wood, fabric, stone, skin) or an image file path.
  std::string texture = "paper";
  // Poster only: a mask image (any size; stretched over the poster like the
  // texture). The poster keeps the pixels where it is >= 128 and is transparent
  // elsewhere, in colour, depth and the ground-truth masks alike: e.g. a person
  // cut out of a photo (stillpoint-segment --out writes such masks). "" = none.
  std::string cutout;
  // Poster only: the part of the texture image (and of the cutout mask, at
  // the same place) the poster shows, as fractions of the image: left, top,
  // right, bottom in [0, 1]. One person out of a photo of several.
  std::array<double, 4> crop{0.0, 0.0, 1.0, 1.0};
  bool cropped() const { return crop[0] > 0 || crop[1] > 0 || crop[2] < 1 || crop[3] < 1; }
  // Poster only: a video of people walking past a still camera. The poster
  // shows one walker cut out of it frame by frame (video_walker.hpp), played
  // at the video's rate and looped; `texture` and `cutout` are not used. The
  // walker's window is 0.75 as wide as high and the walker about 0.8 of its
  // height: size [1.6, 2.15] shows a 1.75 m person. "" = none.
  std::string video;
  // Poster only: turn about the vertical to face the camera in every frame
  // (yaw_deg is added), as a person's cut-out would keep looking like a person
  // from any side; a flat poster seen edge-on is a sliver no network knows.
  bool face_camera = false;
  Vec3 size{0.6, 0.9, 0.05};
  double yaw_deg = 0.0;         // about z; poster/box only (walkers face where they walk)
  double yaw_rate_deg_s = 0.0;  // poster/box spin
  PathSpec path;                // poster/box: centre; walker: floor point between the feet
};

// The textures one mover needs, owned here, built once per sequence.
struct MoverTextures {
  std::vector<TexturePtr> textures;  // poster/box: [main]; walker: [shirt, trousers, skin, shoes]
  // A video poster: its walker's frames, cut out, and their rate.
  std::vector<TexturePtr> video_frames;
  double video_fps = 25.0;
};

// Resolves `spec.texture` and `spec.cutout` (relative paths against base_dir). Errors name the
// mover and file.
Result<MoverTextures> makeMoverTextures(const MoverSpec& spec, const std::string& base_dir,
                                        std::uint64_t seed);

// Appends the mover's triangles at time t; all carry `id`. camera_w: the camera centre
// (world), for face_camera posters.
void addMover(Mesh* mesh, const MoverSpec& spec, const MoverTextures& textures, const SE3& T_w_s,
              double t, std::uint16_t id, const Vec3& camera_w = Vec3::Zero());

// An upper bound on the speed of any point of the mover at time t (m/s): its
// path speed plus its spin (yaw_rate_deg_s) times half its width. A walker's
// limbs swing with the distance walked, so a walker on a still path is still.
// Written per frame to movers.txt, where the scorer tells moving movers from
// still ones (`stillpoint-synth score --min-speed`).
double moverSpeed(const MoverSpec& spec, double t);

// Stage frame of a first camera pose (see the file comment).
SE3 stageFromCamera(const SE3& T_w_c0);

const char* toString(PathType type);
const char* toString(MoverShape shape);

}  // namespace stillpoint::synth
