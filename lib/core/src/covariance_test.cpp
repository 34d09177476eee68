#include "stillpoint/core/covariance.hpp"

#include <gtest/gtest.h>

#include "stillpoint/core/geometry.hpp"

namespace stillpoint {
namespace {

TEST(Covariance, TheUpperTriangleRowByRowAndBack) {
  Eigen::Matrix<double, 6, 6> A;
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c) A(r, c) = 0.25 * (r + 1) + 0.125 * c;
  const Eigen::Matrix<double, 6, 6> covariance = A * A.transpose();
  const auto upper = upperTriangle<double>(covariance);
  EXPECT_EQ(upper[0], covariance(0, 0));
  EXPECT_EQ(upper[5], covariance(0, 5));
  EXPECT_EQ(upper[6], covariance(1, 1));  // the second row starts on the diagonal
  EXPECT_EQ(upper[20], covariance(5, 5));
  EXPECT_EQ(fromUpperTriangle(upper), covariance);
  // As floats, the way the wire formats carry it.
  EXPECT_TRUE(fromUpperTriangle(upperTriangle<float>(covariance)).isApprox(covariance, 1e-6));
}

TEST(Geometry, SkewIsTheCrossProduct) {
  const Vec3 a(0.3, -1.2, 2.5), b(-0.7, 0.4, 1.1);
  EXPECT_TRUE((skew(a) * b).isApprox(a.cross(b), 1e-15));
  EXPECT_TRUE((skew(a) + skew(a).transpose()).isZero());
}

}  // namespace
}  // namespace stillpoint
