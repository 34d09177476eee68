#pragma once
// A minimal PNG writer for uncompressed output: filter type 0, stored deflate
// blocks. About 20x faster than zlib level 1 on this project's machine (PNG
// encoding dominated overlay generation); the files are 2-4x larger but any
// PNG reader opens them.
#include <string>

#include <opencv2/core/mat.hpp>

#include "stillpoint/core/result.hpp"

namespace stillpoint::synth {

// CV_8UC1, CV_8UC3 (BGR, written as RGB) or CV_16UC1. Errors name the file.
Status writeStoredPng(const std::string& path, const cv::Mat& image);

}  // namespace stillpoint::synth
