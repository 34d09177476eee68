#pragma once
// Edits of a recorded TUM-layout sequence that make a camera lose track of
// the world: covered (black colour, zero depth) for a while as it keeps
// moving, a jump cut (frames left out, the stamps closing the gap: the camera
// jumps), and a revisit (the sequence played forwards, then backwards).
#include <string>
#include <vector>

#include "stillpoint/core/result.hpp"

namespace stillpoint::synth {

struct TimeSpan {
  double start_s = 0;     // from the first frame
  double duration_s = 0;
};

struct EditOptions {
  std::vector<TimeSpan> covers;  // frames in a span are black with no depth
  std::vector<TimeSpan> cuts;    // frames in a span are left out; later stamps move back by its length
  bool there_and_back = false;   // then the frames again in reverse order (stamps keep increasing)
  double depth_factor = 5000.0;  // of the input's depth PNGs (kept in the output)
};

struct EditSummary {
  std::size_t frames = 0, covered = 0, cut = 0, ground_truth = 0;
};

// Writes OUTPUT_DIR (rgb/, depth/, rgb.txt, depth.txt, groundtruth.txt when
// the input has one: its pose nearest each frame's original time within
// 20 ms, at the frame's new stamp). Images that are kept are hard-linked
// (copied across file systems). Errors name the file.
Result<EditSummary> editSequence(const std::string& input_dir, const std::string& output_dir,
                                 const EditOptions& options);

}  // namespace stillpoint::synth
