#pragma once
// A pose covariance (6 x 6: position, then rotation) as its upper triangle,
// row by row: the 21 numbers the frame log and every wire format carry.
#include <array>
#include <cstddef>

#include <Eigen/Core>

namespace stillpoint {

template <typename T>
std::array<T, 21> upperTriangle(const Eigen::Matrix<double, 6, 6>& covariance) {
  std::array<T, 21> upper{};
  std::size_t k = 0;
  for (int r = 0; r < 6; ++r)
    for (int c = r; c < 6; ++c) upper[k++] = static_cast<T>(covariance(r, c));
  return upper;
}

template <typename T>
Eigen::Matrix<double, 6, 6> fromUpperTriangle(const std::array<T, 21>& upper) {
  Eigen::Matrix<double, 6, 6> covariance;
  std::size_t k = 0;
  for (int r = 0; r < 6; ++r)
    for (int c = r; c < 6; ++c, ++k) covariance(r, c) = covariance(c, r) = static_cast<double>(upper[k]);
  return covariance;
}

}  // namespace stillpoint
