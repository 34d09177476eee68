#include "stillpoint/synth/video_walker.hpp"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>
#include <opencv2/video/background_segm.hpp>
#include <opencv2/videoio.hpp>

namespace stillpoint::synth {

namespace {

struct Blob {
  cv::Rect box;
  cv::Point2d centre;
  int label = 0;
  int area = 0;
};

std::vector<Blob> blobsOf(const cv::Mat& foreground, cv::Mat* labels) {
  cv::Mat stats, centroids;
  const int n = cv::connectedComponentsWithStats(foreground, *labels, stats, centroids, 8, CV_32S);
  std::vector<Blob> out;
  for (int k = 1; k < n; ++k) {
    Blob b;
    b.box = cv::Rect(stats.at<int>(k, cv::CC_STAT_LEFT), stats.at<int>(k, cv::CC_STAT_TOP),
                     stats.at<int>(k, cv::CC_STAT_WIDTH), stats.at<int>(k, cv::CC_STAT_HEIGHT));
    b.centre = cv::Point2d(centroids.at<double>(k, 0), centroids.at<double>(k, 1));
    b.label = k;
    b.area = stats.at<int>(k, cv::CC_STAT_AREA);
    out.push_back(b);
  }
  return out;
}

// The window of `size` centred on `centre`, or an empty rect where it would
// leave the image.
cv::Rect windowAt(const cv::Point2d& centre, const cv::Size& size, const cv::Size& image) {
  const cv::Rect r(cvRound(centre.x - size.width / 2.0), cvRound(centre.y - size.height / 2.0), size.width,
                   size.height);
  return (r & cv::Rect(0, 0, image.width, image.height)) == r ? r : cv::Rect();
}

// One followed walker: its first frame and, per frame, its window and blob
// (in the half-resolution analysis images).
struct Track {
  std::size_t start = 0;
  std::vector<cv::Rect> windows;
  std::vector<cv::Point2d> centres;
};

// Follows the walker seeded by `seed` in frame `start`: in each next frame the
// largest blob within a quarter window width of its last centre.
Track follow(const std::vector<std::vector<Blob>>& blobs, std::size_t start, const Blob& seed, const cv::Size& image) {
  Track t;
  t.start = start;
  const int h = static_cast<int>(std::lround(1.25 * seed.box.height));
  const cv::Size window(static_cast<int>(std::lround(0.75 * h)), h);
  cv::Point2d centre = seed.centre;
  for (std::size_t i = start; i < blobs.size(); ++i) {
    const Blob* next = nullptr;
    for (const Blob& b : blobs[i]) {
      const double d = std::hypot(b.centre.x - centre.x, b.centre.y - centre.y);
      if (d < 0.25 * window.width && b.area > seed.area / 3 && (!next || b.area > next->area)) next = &b;
    }
    if (!next) break;
    const cv::Rect r = windowAt(next->centre, window, image);
    if (r.empty()) break;
    centre = next->centre;
    t.windows.push_back(r);
    t.centres.push_back(centre);
  }
  return t;
}

}  // namespace

Result<WalkerClip> cutWalkerFromVideo(const std::string& path, const WalkerOptions& options) {
  try {
    cv::VideoCapture video(path);
    if (!video.isOpened()) return Error{"cannot read video '" + path + "'"};
    WalkerClip clip;
    const double fps = video.get(cv::CAP_PROP_FPS);
    if (fps > 1 && fps < 1000) clip.fps = fps;

    // Pass 1: the background model learns over the whole video (people walk
    // through, the background stays). Frames are analysed at half resolution.
    auto subtractor = cv::createBackgroundSubtractorMOG2(500, 16.0, true);
    cv::Size full, half;
    int frames = 0;
    cv::Mat frame, small, ignored;
    while (frames < options.max_frames && video.read(frame) && !frame.empty()) {
      if (frame.type() != CV_8UC3) return Error{"video '" + path + "': frames are not 8-bit colour"};
      if (frames == 0) full = frame.size(), half = cv::Size(full.width / 2, full.height / 2);
      if (frame.size() != full) return Error{"video '" + path + "': frame sizes differ"};
      cv::resize(frame, small, half, 0, 0, cv::INTER_AREA);
      subtractor->apply(small, ignored);
      ++frames;
    }
    if (frames < options.min_frames || half.height < 16)
      return Error{"video '" + path + "': " + std::to_string(frames) + " frames of " + std::to_string(full.width) +
                   "x" + std::to_string(full.height) + ", too few or too small"};

    // Pass 2: each frame's foreground (shadows are background) and its blobs.
    video.release();
    video.open(path);
    if (!video.isOpened()) return Error{"cannot read video '" + path + "' again"};
    const cv::Mat open = cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(3, 3));
    const cv::Mat close = cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(7, 7));
    std::vector<cv::Mat> foreground;
    std::vector<std::vector<Blob>> blobs;
    for (int i = 0; i < frames && video.read(frame) && !frame.empty(); ++i) {
      cv::resize(frame, small, half, 0, 0, cv::INTER_AREA);
      cv::Mat fg, labels;
      subtractor->apply(small, fg, 0.0);
      cv::threshold(fg, fg, 200, 255, cv::THRESH_BINARY);
      cv::morphologyEx(fg, fg, cv::MORPH_OPEN, open);
      cv::morphologyEx(fg, fg, cv::MORPH_CLOSE, close);
      blobs.push_back(blobsOf(fg, &labels));
      foreground.push_back(fg);
    }

    // The longest track from a seed: a large upright blob clear of the border.
    const double min_height = options.min_height * half.height;
    Track best;
    for (std::size_t start = 0; start < blobs.size(); start += 5) {
      for (const Blob& b : blobs[start]) {
        const bool upright = b.box.height >= min_height && b.box.height > 1.5 * b.box.width;
        const bool clear = b.box.x > 2 && b.box.y > 2 && b.box.br().x < half.width - 2 && b.box.br().y < half.height - 2;
        if (!upright || !clear) continue;
        Track t = follow(blobs, start, b, half);
        if (t.windows.size() > best.windows.size()) best = std::move(t);
      }
    }
    if (static_cast<int>(best.windows.size()) < options.min_frames)
      return Error{"video '" + path + "': no walker followed for " + std::to_string(options.min_frames) +
                   " frames (the longest: " + std::to_string(best.windows.size()) + ")"};

    // Pass 3: the walker's frames at full resolution, cut out by its blob
    // (the one at its centre in the frame's foreground).
    video.release();
    video.open(path);
    if (!video.isOpened()) return Error{"cannot read video '" + path + "' again"};
    const double sx = static_cast<double>(full.width) / half.width, sy = static_cast<double>(full.height) / half.height;
    const cv::Size window(cvRound(best.windows.front().width * sx), cvRound(best.windows.front().height * sy));
    for (std::size_t i = 0; i < best.start + best.windows.size() && video.read(frame) && !frame.empty(); ++i) {
      if (i < best.start) continue;
      const std::size_t k = i - best.start;
      const cv::Rect r = best.windows[k];
      cv::Mat labels;
      const std::vector<Blob> here = blobsOf(foreground[i], &labels);
      const Blob* mine = nullptr;
      for (const Blob& b : here)
        if (!mine || std::hypot(b.centre.x - best.centres[k].x, b.centre.y - best.centres[k].y) <
                         std::hypot(mine->centre.x - best.centres[k].x, mine->centre.y - best.centres[k].y))
          mine = &b;
      cv::Mat keep_half = cv::Mat::zeros(r.size(), CV_8UC1);
      if (mine) keep_half.setTo(255, labels(r) == mine->label);
      const cv::Rect rf(cvRound(r.x * sx), cvRound(r.y * sy), window.width, window.height);
      const cv::Rect inside = rf & cv::Rect(0, 0, full.width, full.height);
      cv::Mat colour(window, CV_8UC3, cv::Scalar::all(0));
      frame(inside).copyTo(colour(cv::Rect(inside.tl() - rf.tl(), inside.size())));
      cv::Mat keep;
      cv::resize(keep_half, keep, window, 0, 0, cv::INTER_LINEAR);
      cv::threshold(keep, keep, 127, 255, cv::THRESH_BINARY);
      clip.colour.push_back(colour);
      clip.keep.push_back(keep);
    }
    if (static_cast<int>(clip.colour.size()) < options.min_frames)
      return Error{"video '" + path + "' ended early on the third reading"};
    return clip;
  } catch (const cv::Exception& e) {
    return Error{"video '" + path + "': " + e.what()};
  }
}

}  // namespace stillpoint::synth
