#pragma once
// Adds the lifetime of a scope to a stage's milliseconds (StageTimes).
#include <chrono>

namespace stillpoint::slam {

class ScopedStageTimer {
 public:
  explicit ScopedStageTimer(double* ms) : ms_(ms), start_(std::chrono::steady_clock::now()) {}
  ~ScopedStageTimer() {
    *ms_ += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start_).count();
  }
  ScopedStageTimer(const ScopedStageTimer&) = delete;
  ScopedStageTimer& operator=(const ScopedStageTimer&) = delete;

 private:
  double* ms_;
  std::chrono::steady_clock::time_point start_;
};

}  // namespace stillpoint::slam
