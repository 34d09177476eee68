#pragma once
// Small GoogleTest helpers shared by the slam module's tests.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "frame.hpp"

namespace stillpoint::slam::testing {

// Passes when `text` contains `part`; the failure message shows both.
inline ::testing::AssertionResult contains(const std::string& text, const std::string& part) {
  if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "\"" << text << "\" does not contain \"" << part << "\"";
}

// Pyramid constants of a single level (scale 1, sigma 1), for hand-made frames.
inline const LevelInfo& oneLevel() {
  static const LevelInfo lv = [] {
    LevelInfo l;
    l.levels = 1;
    l.scale_factor = 1.2;
    l.log_scale_factor = std::log(1.2);
    l.scales = l.sigma2 = l.inv_sigma2 = {1.0};
    return l;
  }();
  return lv;
}

}  // namespace stillpoint::slam::testing
