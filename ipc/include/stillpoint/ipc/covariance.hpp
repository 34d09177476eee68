#pragma once
// PoseMessage::covariance (the upper triangle, row by row, as float) and the
// 6 x 6 matrix it holds.
#include <array>

#include <Eigen/Core>

namespace stillpoint::ipc {

inline std::array<float, 21> packCovariance(const Eigen::Matrix<double, 6, 6>& covariance) {
  std::array<float, 21> upper{};
  for (int r = 0, k = 0; r < 6; ++r)
    for (int c = r; c < 6; ++c, ++k) upper[static_cast<std::size_t>(k)] = static_cast<float>(covariance(r, c));
  return upper;
}

inline Eigen::Matrix<double, 6, 6> unpackCovariance(const std::array<float, 21>& upper) {
  Eigen::Matrix<double, 6, 6> covariance;
  for (int r = 0, k = 0; r < 6; ++r)
    for (int c = r; c < 6; ++c, ++k) covariance(r, c) = covariance(c, r) = upper[static_cast<std::size_t>(k)];
  return covariance;
}

}  // namespace stillpoint::ipc
