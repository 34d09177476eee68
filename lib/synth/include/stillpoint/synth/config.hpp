#pragma once
// Configuration of a generated sequence: movers, depth sensor model, motion
// blur and, for fully synthetic sequences, the room and camera motion. Read
// from YAML (see config/synth/*.yaml) or built from a named preset.
#include <cstdint>
#include <string>
#include <vector>

#include "stillpoint/core/result.hpp"
#include "stillpoint/synth/movers.hpp"
#include "stillpoint/synth/sensor.hpp"

namespace stillpoint::synth {

struct BlurOptions {
  bool enabled = false;
  int samples = 5;          // renders of the movers per frame, spread over the exposure
  double exposure_s = 0.02;  // shutter time centred on the frame time
};

enum class CameraMotion { kStatic, kXyz, kRpy, kHalfsphere, kLoop };
Result<CameraMotion> parseCameraMotion(const std::string& name);
const char* toString(CameraMotion motion);

// Fully synthetic mode only.
struct RoomOptions {
  CameraMotion motion = CameraMotion::kXyz;
  int frames = 300;
  double rate_hz = 30.0;
  int width = 640, height = 480;
  std::vector<std::string> photos;  // image files hung on the walls as pictures (optional)
};

struct SynthConfig {
  std::uint64_t seed = 1;
  std::vector<MoverSpec> movers;  // mover k gets mask id k + 1
  DepthSensorOptions sensor;
  BlurOptions blur;
  RoomOptions room;
  std::string base_dir;  // relative texture/photo paths resolve against this

  // Names the offending field ("movers[1].path.speed_m_s must be > 0").
  Status validate() const;
};

// Reads a YAML file; unknown keys, wrong types and bad values are errors that
// name the file, line and field. base_dir becomes the file's folder.
Result<SynthConfig> loadSynthConfig(const std::string& path);

// Named presets; `photo_dir` holds astronaut.png / coffee.png (a texture style
// replaces a photo that is missing there).
std::vector<std::string> presetNames();
Result<SynthConfig> synthPreset(const std::string& name, const std::string& photo_dir);

}  // namespace stillpoint::synth
