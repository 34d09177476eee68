#pragma once
// Real walking people for the generator: one walker cut out of a video of a
// still camera (e.g. Debian opencv-doc's examples/data/vtest.avi), frame by
// frame. The background is learned by a Gaussian-mixture model over the whole
// video; a walker is the largest upright foreground blob that stays clear of
// the image border, followed from frame to frame by its nearest blob. Each
// frame of the clip is a fixed window around the walker (its height 1.25x the
// walker's first bounding box, 0.75 as wide) with the walker's own blob as
// the cut-out: arms and legs swing as they did in the video.
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "stillpoint/core/result.hpp"

namespace stillpoint::synth {

struct WalkerClip {
  std::vector<cv::Mat> colour;  // CV_8UC3, all the window's size
  std::vector<cv::Mat> keep;    // CV_8UC1, 255 on the walker, 0 elsewhere
  double fps = 25.0;            // the video's frame rate
};

struct WalkerOptions {
  int min_frames = 30;          // a shorter track is not a walker (someone passing the border)
  double min_height = 0.15;     // of the image height: the blob a walker starts as
  int max_frames = 2000;        // of the video read
};

// Reads `path` and returns the longest walker clip in it. Errors: the file
// cannot be read as a video, or no walker is followed for min_frames.
Result<WalkerClip> cutWalkerFromVideo(const std::string& path, const WalkerOptions& options = {});

}  // namespace stillpoint::synth
