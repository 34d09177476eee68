#pragma once
// Rigid transforms. T_a_b maps points from frame b into frame a.
#include <Eigen/Core>
#include <Eigen/Geometry>

namespace stillpoint {

using SE3 = Eigen::Isometry3d;
using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;

inline SE3 makeSE3(const Eigen::Quaterniond& q, const Vec3& t) {
  SE3 T = SE3::Identity();
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() = t;
  return T;
}

// Projects the rotation back onto SO(3). Chains of products (motion models:
// v = T_k T_{k-1}^-1, T_{k+1} = v T_k) otherwise amplify rounding errors
// exponentially, because Isometry::inverse() assumes an exact rotation.
inline SE3 renormalized(const SE3& T) {
  SE3 out = SE3::Identity();
  out.linear() = Eigen::Quaterniond(T.linear()).normalized().toRotationMatrix();
  out.translation() = T.translation();
  return out;
}

// The cross-product matrix: skew(a) * b == a.cross(b).
inline Mat3 skew(const Vec3& a) {
  Mat3 S;
  S << 0, -a.z(), a.y(), a.z(), 0, -a.x(), -a.y(), a.x(), 0;
  return S;
}

// Exponential map of so(3): rotation vector -> rotation matrix.
inline Mat3 expSO3(const Vec3& w) {
  const double theta = w.norm();
  if (theta < 1e-12) return Mat3::Identity();
  return Eigen::AngleAxisd(theta, w / theta).toRotationMatrix();
}

// Logarithm map of SO(3): rotation matrix -> rotation vector.
inline Vec3 logSO3(const Mat3& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

// Rotation angle of R in radians.
inline double rotationAngle(const Mat3& R) {
  return Eigen::AngleAxisd(R).angle();
}

}  // namespace stillpoint
