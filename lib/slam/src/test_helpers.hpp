#pragma once
// Small GoogleTest helpers shared by the slam module's tests.
#include <gtest/gtest.h>

#include <string>

namespace stillpoint::slam::testing {

// Passes when `text` contains `part`; the failure message shows both.
inline ::testing::AssertionResult contains(const std::string& text, const std::string& part) {
  if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "\"" << text << "\" does not contain \"" << part << "\"";
}

}  // namespace stillpoint::slam::testing
