#include "optimizer.hpp"

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <array>
#include <chrono>
#include <functional>
#include <mutex>
#include <random>
#include <set>
#include <unordered_map>
#include <unordered_set>

namespace stillpoint::slam {
namespace {

// Pose block: [angle-axis (3), translation (3)] of T_c_w.
void toParameters(const SE3& T, double* p) {
  Eigen::AngleAxisd aa(T.linear());
  const Vec3 w = aa.angle() * aa.axis();
  for (int i = 0; i < 3; ++i) {
    p[i] = w[i];
    p[3 + i] = T.translation()[i];
  }
}

SE3 fromParameters(const double* p) {
  SE3 T = SE3::Identity();
  T.linear() = expSO3(Vec3(p[0], p[1], p[2]));
  T.translation() = Vec3(p[3], p[4], p[5]);
  return T;
}

// Residual of one observation; depth enters as the virtual right u.
struct ReprojectionError {
  ReprojectionError(const CameraModel& cam, const Observation& o)
      : fx(cam.fx), fy(cam.fy), cx(cam.cx), cy(cam.cy), bf(cam.bf()), obs(o) {}

  template <typename T>
  bool project(const T* pose, const T* point, T* residual) const {
    T p[3];
    ceres::AngleAxisRotatePoint(pose, point, p);
    p[0] += pose[3];
    p[1] += pose[4];
    p[2] += pose[5];
    if (p[2] < T(1e-6)) p[2] = T(1e-6);
    const T inv_z = T(1.0) / p[2];
    const T u = T(fx) * p[0] * inv_z + T(cx);
    residual[0] = (u - T(obs.u)) * T(obs.inv_sigma);
    residual[1] = (T(fy) * p[1] * inv_z + T(cy) - T(obs.v)) * T(obs.inv_sigma);
    if (obs.u_right >= 0) residual[2] = (u - T(bf) * inv_z - T(obs.u_right)) * T(obs.inv_sigma);
    return true;
  }
  double fx, fy, cx, cy, bf;
  Observation obs;
};

struct PoseOnlyError : ReprojectionError {
  PoseOnlyError(const CameraModel& cam, const Observation& o, const Vec3& p) : ReprojectionError(cam, o), p_w(p) {}
  template <typename T>
  bool operator()(const T* pose, T* residual) const {
    const T point[3] = {T(p_w.x()), T(p_w.y()), T(p_w.z())};
    return project(pose, point, residual);
  }
  Vec3 p_w;
};


// Left Jacobian of SO(3): d(exp(w) x)/dw = -[exp(w) x]x J_l(w) when the
// rotation vector itself is the parameter.
Mat3 leftJacobianSO3(const Vec3& w) {
  const double theta2 = w.squaredNorm();
  Mat3 W;
  W << 0, -w.z(), w.y(), w.z(), 0, -w.x(), -w.y(), w.x(), 0;
  if (theta2 < 1e-10) return Mat3::Identity() + 0.5 * W;
  const double theta = std::sqrt(theta2);
  return Mat3::Identity() + (1 - std::cos(theta)) / theta2 * W + (theta - std::sin(theta)) / (theta2 * theta) * W * W;
}

// Bundle-adjustment residual with analytic Jacobians. Always three rows (the
// depth row is zero for keypoints without depth) so that Ceres uses its
// fixed-size Schur eliminator for 3-row residuals, 6-D poses and 3-D points.
// The depth row is the virtual right coordinate's error, or, with a
// `disparity_weight` > 0, the disparity's alone (bf / z), that many times
// the keypoint's weight: the right coordinate carries the keypoint's own
// position error, which dilutes what the depth says.
class BundleAdjustmentCost final : public ceres::SizedCostFunction<3, 6, 3> {
 public:
  BundleAdjustmentCost(const CameraModel& cam, const Observation& o, double disparity_weight)
      : fx_(cam.fx), fy_(cam.fy), cx_(cam.cx), cy_(cam.cy), bf_(cam.bf()), obs_(o), disparity_weight_(disparity_weight) {}

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    const double* pose = parameters[0];
    const Vec3 w(pose[0], pose[1], pose[2]);
    const Mat3 R = expSO3(w);
    const Vec3 point(parameters[1][0], parameters[1][1], parameters[1][2]);
    const Vec3 Rp = R * point;
    const Vec3 p = Rp + Vec3(pose[3], pose[4], pose[5]);
    const bool stereo = obs_.u_right >= 0;
    const double z = std::max(p.z(), 1e-6);
    const double inv_z = 1.0 / z;
    const double u = fx_ * p.x() * inv_z + cx_;
    const double s = obs_.inv_sigma;
    residuals[0] = (u - obs_.u) * s;
    residuals[1] = (fy_ * p.y() * inv_z + cy_ - obs_.v) * s;
    const bool disparity = disparity_weight_ > 0;
    if (!stereo)
      residuals[2] = 0.0;
    else if (disparity)
      residuals[2] = (bf_ * inv_z - (obs_.u - obs_.u_right)) * s * disparity_weight_;
    else
      residuals[2] = (u - bf_ * inv_z - obs_.u_right) * s;
    if (!jacobians) return true;
    const double inv_z2 = inv_z * inv_z;
    Eigen::Matrix3d J_p;
    J_p << fx_ * inv_z, 0, -fx_ * p.x() * inv_z2,  //
        0, fy_ * inv_z, -fy_ * p.y() * inv_z2,     //
        fx_ * inv_z, 0, -(fx_ * p.x() - bf_) * inv_z2;
    if (!stereo)
      J_p.row(2).setZero();
    else if (disparity)
      J_p.row(2) << 0, 0, -bf_ * inv_z2 * disparity_weight_;
    J_p *= s;
    if (jacobians[0]) {
      Eigen::Map<Eigen::Matrix<double, 3, 6, Eigen::RowMajor>> J(jacobians[0]);
      J.leftCols<3>() = -J_p * skew(Rp) * leftJacobianSO3(w);
      J.rightCols<3>() = J_p;
    }
    if (jacobians[1]) {
      Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> J(jacobians[1]);
      J = J_p * R;
    }
    return true;
  }

 private:
  double fx_, fy_, cx_, cy_, bf_;
  Observation obs_;
  double disparity_weight_;
};

}  // namespace

Observation observationOf(const Frame& f, int i) {
  Observation o;
  o.u = f.un[i].x;
  o.v = f.un[i].y;
  o.u_right = f.u_right[i];
  o.inv_sigma = 1.0 / f.levels->scales[f.keys[i].octave];
  return o;
}

double reprojectionChi2(const CameraModel& cam, const SE3& T_c_w, const Vec3& p_w, const Observation& obs,
                        bool* behind) {
  const Vec3 p = T_c_w * p_w;
  if (behind) *behind = p.z() <= 0;
  if (p.z() <= 1e-6) return 1e9;
  const double u = cam.fx * p.x() / p.z() + cam.cx, v = cam.fy * p.y() / p.z() + cam.cy;
  double e2 = (u - obs.u) * (u - obs.u) + (v - obs.v) * (v - obs.v);
  if (obs.u_right >= 0) {
    const double ur = u - cam.bf() / p.z();
    e2 += (ur - obs.u_right) * (ur - obs.u_right);
  }
  return e2 * obs.inv_sigma * obs.inv_sigma;
}

// Pose-only residual whose observation can be switched off between rounds
// without rebuilding the problem (an inactive residual is zero).
struct SwitchablePoseError : PoseOnlyError {
  SwitchablePoseError(const CameraModel& cam, const Observation& o, const Vec3& p, const char* active)
      : PoseOnlyError(cam, o, p), active(active) {}
  template <typename T>
  bool operator()(const T* pose, T* residual) const {
    if (!*active) {
      for (int i = 0; i < (obs.u_right >= 0 ? 3 : 2); ++i) residual[i] = T(0.0);
      return true;
    }
    return PoseOnlyError::operator()(pose, residual);
  }
  const char* active;
};

namespace {

// All observations start as inliers; fewer than 3 cannot fix a pose.
PoseResult initialPoseResult(std::size_t n, const SE3& initial) {
  PoseResult result;
  result.T_c_w = initial;
  result.inlier.assign(n, n >= 3 ? 1 : 0);
  return result;
}

// Chi-square test of every observation at T; returns the inlier count.
int classifyInliers(const PoseProblem& problem, const SE3& T, std::vector<char>* inlier) {
  int inliers = 0;
  for (std::size_t i = 0; i < problem.points_w.size(); ++i) {
    const Observation& o = problem.observations[i];
    const double chi2 = reprojectionChi2(*problem.camera, T, problem.points_w[i], o);
    (*inlier)[i] = chi2 <= (o.u_right >= 0 ? kChi2Stereo : kChi2Mono);
    inliers += (*inlier)[i];
  }
  return inliers;
}

}  // namespace

PoseResult optimizePoseCeres(const PoseProblem& problem, const SE3& initial, int rounds) {
  const std::size_t n = problem.points_w.size();
  PoseResult result = initialPoseResult(n, initial);
  if (n < 3) return result;
  double pose[6];
  toParameters(initial, pose);
  // One problem for all rounds; between rounds observations failing the
  // chi-square test are switched off (and may come back in a later round).
  // The robust kernel matters while outliers may still be in; the last rounds
  // refine on the accepted set, where Huber and quadratic agree.
  std::vector<char> active(n, 1);
  ceres::Problem::Options problem_options;
  problem_options.enable_fast_removal = false;
  ceres::Problem ceres_problem(problem_options);
  ceres_problem.AddParameterBlock(pose, 6);
  for (std::size_t i = 0; i < n; ++i) {
    const Observation& o = problem.observations[i];
    const double delta = std::sqrt(o.u_right >= 0 ? kChi2Stereo : kChi2Mono);
    auto* functor = new SwitchablePoseError(*problem.camera, o, problem.points_w[i], &active[i]);
    ceres::CostFunction* cost =
        o.u_right >= 0
            ? static_cast<ceres::CostFunction*>(new ceres::AutoDiffCostFunction<SwitchablePoseError, 3, 6>(functor))
            : new ceres::AutoDiffCostFunction<SwitchablePoseError, 2, 6>(functor);
    ceres_problem.AddResidualBlock(cost, new ceres::HuberLoss(delta), pose);
  }
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
  options.max_num_iterations = 10;
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  options.function_tolerance = 1e-7;
  options.parameter_tolerance = 1e-9;
  for (int round = 0; round < rounds; ++round) {
    ceres::Solver::Summary summary;
    ceres::Solve(options, &ceres_problem, &summary);
    const SE3 T = fromParameters(pose);
    result.inliers = classifyInliers(problem, T, &result.inlier);
    // Copy in place: the residuals hold pointers into `active`.
    std::copy(result.inlier.begin(), result.inlier.end(), active.begin());
    if (result.inliers < 10) break;
  }
  result.T_c_w = fromParameters(pose);
  return result;
}

namespace {

// Robust cost of one observation at pose T and, optionally, its weighted
// normal-equation contribution for a left perturbation exp([w, v]) * T.
struct PoseLinearisation {
  Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
  Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
  double cost = 0;
};

double huberCost(double chi2, double delta) {
  const double e = std::sqrt(chi2);
  return e <= delta ? chi2 : 2 * delta * e - delta * delta;
}

void linearisePose(const PoseProblem& problem, const std::vector<char>& active, const SE3& T, bool robust,
                   bool with_jacobians, PoseLinearisation* out) {
  const CameraModel& cam = *problem.camera;
  *out = PoseLinearisation{};
  for (std::size_t i = 0; i < problem.points_w.size(); ++i) {
    if (!active[i]) continue;
    const Observation& o = problem.observations[i];
    const Vec3 p = T * problem.points_w[i];
    const bool stereo = o.u_right >= 0;
    if (p.z() <= 1e-3) {
      // Behind the camera: a large constant cost, so a step can never gain
      // by moving points out of view.
      out->cost += robust ? huberCost(1e6, std::sqrt(stereo ? kChi2Stereo : kChi2Mono)) : 1e6;
      continue;
    }
    const double inv_z = 1.0 / p.z();
    const double u = cam.fx * p.x() * inv_z + cam.cx, v = cam.fy * p.y() * inv_z + cam.cy;
    Eigen::Vector3d r(u - o.u, v - o.v, stereo ? u - cam.bf() * inv_z - o.u_right : 0.0);
    r *= o.inv_sigma;
    const double chi2 = r.squaredNorm();
    const double delta = std::sqrt(stereo ? kChi2Stereo : kChi2Mono);
    const double e = std::sqrt(chi2);
    const double weight = (!robust || e <= delta) ? 1.0 : delta / e;  // IRLS weight of Huber
    out->cost += robust ? huberCost(chi2, delta) : chi2;
    if (!with_jacobians) continue;
    // d(residual)/d(p_c), then d(p_c)/d([w, v]) = [-[p]x, I].
    Eigen::Matrix<double, 3, 3> J_p = Eigen::Matrix<double, 3, 3>::Zero();
    const double inv_z2 = inv_z * inv_z;
    J_p.row(0) << cam.fx * inv_z, 0, -cam.fx * p.x() * inv_z2;
    J_p.row(1) << 0, cam.fy * inv_z, -cam.fy * p.y() * inv_z2;
    if (stereo) J_p.row(2) << cam.fx * inv_z, 0, -(cam.fx * p.x() - cam.bf()) * inv_z2;
    J_p *= o.inv_sigma;
    Eigen::Matrix<double, 3, 6> J;
    J.leftCols<3>() = -J_p * skew(p);
    J.rightCols<3>() = J_p;
    const int rows = stereo ? 3 : 2;
    out->H.noalias() += weight * J.topRows(rows).transpose() * J.topRows(rows);
    out->b.noalias() += weight * J.topRows(rows).transpose() * r.head(rows);
  }
  if (problem.prior_sqrt_information.any()) {
    // Left-perturbation residual of T against the prior; its Jacobian is
    // close to the identity near the prior (the step is checked on the exact cost).
    const Mat3 dR = T.linear() * problem.prior.linear().transpose();
    Eigen::Matrix<double, 6, 1> r;
    r.head<3>() = logSO3(dR);
    r.tail<3>() = T.translation() - dR * problem.prior.translation();
    const Eigen::Matrix<double, 6, 1>& s = problem.prior_sqrt_information;
    r.array() *= s.array();
    out->cost += r.squaredNorm();
    if (with_jacobians) {
      out->H.diagonal().array() += s.array().square();
      out->b.array() += s.array() * r.array();
    }
  }
}

SE3 retract(const Eigen::Matrix<double, 6, 1>& dx, const SE3& T) {
  SE3 update = SE3::Identity();
  update.linear() = expSO3(dx.head<3>());
  update.translation() = dx.tail<3>();
  return renormalized(update * T);
}

// Levenberg-Marquardt on the 6-DoF pose with Huber IRLS weights.
SE3 minimisePose(const PoseProblem& problem, const std::vector<char>& active, const SE3& initial, bool robust,
                 int max_iterations) {
  SE3 T = initial;
  PoseLinearisation lin;
  linearisePose(problem, active, T, robust, true, &lin);
  double lambda = 1e-4;
  for (int it = 0; it < max_iterations; ++it) {
    Eigen::Matrix<double, 6, 6> H = lin.H;
    H.diagonal() *= 1.0 + lambda;
    const Eigen::Matrix<double, 6, 1> dx = H.ldlt().solve(-lin.b);
    if (!dx.allFinite()) break;
    const SE3 candidate = retract(dx, T);
    PoseLinearisation next;
    linearisePose(problem, active, candidate, robust, false, &next);
    if (next.cost <= lin.cost) {
      T = candidate;
      lambda = std::max(1e-7, lambda * 0.1);
      const bool converged = dx.squaredNorm() < 1e-14 || lin.cost - next.cost < 1e-9 * lin.cost;
      if (converged) break;
      linearisePose(problem, active, T, robust, true, &lin);
    } else {
      lambda *= 10;
      if (lambda > 1e6) break;
    }
  }
  return T;
}

}  // namespace

Eigen::Matrix<double, 6, 6> poseInformation(const PoseProblem& problem, const SE3& T_c_w) {
  PoseLinearisation lin;
  linearisePose(problem, std::vector<char>(problem.points_w.size(), 1), T_c_w, false, true, &lin);
  return lin.H;
}

Eigen::Matrix<double, 6, 6> poseCovarianceInMap(const Eigen::Matrix<double, 6, 6>& information, const SE3& T_c_w,
                                                double pixel_sigma) {
  // T_c_w's left perturbation exp([w, v]) moves the centre by -R_wc v and
  // turns R_wc by exp(-R_wc w).
  Eigen::Matrix<double, 6, 6> H = information / (pixel_sigma * pixel_sigma);
  H.diagonal() += (Eigen::Matrix<double, 6, 1>() << 1, 1, 1, 0.01, 0.01, 0.01).finished();
  const Eigen::Matrix<double, 6, 6> cov_wv = H.ldlt().solve(Eigen::Matrix<double, 6, 6>::Identity());
  const Mat3 R_wc = T_c_w.linear().transpose();
  Eigen::Matrix<double, 6, 6> G = Eigen::Matrix<double, 6, 6>::Zero();
  G.block<3, 3>(0, 3) = -R_wc;
  G.block<3, 3>(3, 0) = -R_wc;
  const Eigen::Matrix<double, 6, 6> cov = G * cov_wv * G.transpose();
  return 0.5 * (cov + cov.transpose());
}

double truncatedPoseCost(const PoseProblem& problem, const SE3& T_c_w, double cap, int* inliers, double stop_at) {
  double sum = 0;
  int under = 0;
  for (std::size_t k = 0; k < problem.points_w.size() && sum < stop_at; ++k) {
    const double chi2 = reprojectionChi2(*problem.camera, T_c_w, problem.points_w[k], problem.observations[k]);
    sum += std::min(chi2, cap);
    under += chi2 < cap;
  }
  if (inliers) *inliers = under;
  return sum;
}

ConsensusResult consensusPose(const ConsensusProblem& problem, const SE3& initial) {
  const PoseProblem& matches = problem.pose;
  ConsensusResult result{initial, 0, 0, 0};
  result.initial_cost = truncatedPoseCost(matches, initial, problem.cap, &result.initial_inliers);
  result.cost = result.initial_cost;
  if (result.initial_inliers < problem.min_initial_inliers) return result;
  std::vector<int> sampleable;
  for (std::size_t k = 0; k < problem.sampleable.size(); ++k)
    if (problem.sampleable[k]) sampleable.push_back(static_cast<int>(k));
  if (sampleable.size() < 3) return result;
  std::mt19937 rng(problem.seed);
  std::uniform_int_distribution<std::size_t> pick(0, sampleable.size() - 1);
  SE3 best = initial;
  for (int s = 0; s < problem.samples; ++s) {
    std::array<int, 3> k{};
    bool distinct = false;
    for (int attempt = 0; attempt < 10 && !distinct; ++attempt) {
      for (int& x : k) x = sampleable[pick(rng)];
      const auto g = [&](int i) { return problem.group[k[i]]; };
      distinct = g(0) != g(1) && g(0) != g(2) && g(1) != g(2);
    }
    if (!distinct) continue;
    Eigen::Matrix3d from, to;
    for (int c = 0; c < 3; ++c) from.col(c) = matches.points_w[k[c]], to.col(c) = problem.seen[k[c]];
    if ((from.col(1) - from.col(0)).cross(from.col(2) - from.col(0)).norm() < 1e-4) continue;  // collinear
    SE3 T;
    T.matrix() = Eigen::umeyama(from, to, false);
    // Scored only until it cannot beat the best so far.
    const double cost = truncatedPoseCost(matches, T, problem.cap, nullptr, result.cost);
    if (cost < result.cost) result.cost = cost, best = T;
  }
  // Refitted on the inliers of the best hypothesis, or of the initial pose
  // when none beat it, while that lowers the cost. The refit of the initial
  // pose is the local search: the anchor frame's own pose is a few
  // millimetres off, which near surfaces show as a coherent shift of several
  // sigma, and a hypothesis from three noisy depth samples rarely beats it.
  result.T_c_w = best;
  for (int round = 0; round < 2; ++round) {
    PoseProblem inliers;
    inliers.camera = matches.camera;
    for (std::size_t k = 0; k < matches.points_w.size(); ++k)
      if (reprojectionChi2(*matches.camera, result.T_c_w, matches.points_w[k], matches.observations[k]) < problem.cap) {
        inliers.points_w.push_back(matches.points_w[k]);
        inliers.observations.push_back(matches.observations[k]);
      }
    if (inliers.points_w.size() < 6) break;
    const SE3 T = optimizePose(inliers, result.T_c_w).T_c_w;
    const double cost = truncatedPoseCost(matches, T, problem.cap);
    if (cost >= result.cost) break;
    result.cost = cost;
    result.T_c_w = T;
  }
  return result;
}

PoseResult optimizePose(const PoseProblem& problem, const SE3& initial, int rounds) {
  const std::size_t n = problem.points_w.size();
  PoseResult result = initialPoseResult(n, initial);
  if (n < 3) return result;
  std::vector<char> active(n, 1);
  SE3 T = initial;
  for (int round = 0; round < rounds; ++round) {
    // Huber while outliers may still be in; the last rounds refine the
    // accepted set with the plain quadratic cost.
    T = minimisePose(problem, active, T, round < 2, 30);
    result.inliers = classifyInliers(problem, T, &result.inlier);
    active = result.inlier;
    if (result.inliers < 10) break;
  }
  result.T_c_w = T;
  return result;
}

int optimizeFramePose(Frame* frame, const SE3* prior, const Eigen::Matrix<double, 6, 1>* prior_sqrt_information) {
  PoseProblem problem;
  problem.camera = frame->camera;
  if (prior && prior_sqrt_information) {
    problem.prior = *prior;
    problem.prior_sqrt_information = *prior_sqrt_information;
  }
  std::vector<int> index;
  for (int i = 0; i < frame->size(); ++i) {
    const auto& p = frame->points[i];
    if (!p || p->bad) continue;
    problem.points_w.push_back(p->position);
    problem.observations.push_back(observationOf(*frame, i));
    index.push_back(i);
  }
  const PoseResult r = optimizePose(problem, frame->T_c_w);
  if (r.inliers < 10) {
    // No trustworthy pose: every match counts as an outlier, the pose stays.
    for (int i : index) frame->outlier[i] = 1;
    return r.inliers;
  }
  frame->T_c_w = r.T_c_w;
  for (std::size_t k = 0; k < index.size(); ++k) frame->outlier[index[k]] = !r.inlier[k];
  return r.inliers;
}

namespace {
// Whether a keyframe that sees `p` has it in front within the sensor's depth
// range (with a margin for the refinement of a point measured near its end).
bool withinDepthRange(const CameraModel& camera, const MapPoint& p) {
  constexpr double kMargin = 1.25;
  for (const auto& [kf, idx] : p.observations) {
    if (kf->bad) continue;
    const double z = (kf->T_c_w() * p.position).z();
    if (z > 0 && z <= kMargin * camera.max_depth) return true;
  }
  return false;
}

// A keyframe's pose held near where tracking put it: rotation error (angle
// axis of R R_prior^T) over sigma_rad, camera centre error over sigma_m.
struct PosePriorCost {
  PosePriorCost(const SE3& prior, double sigma_rad, double sigma_m) : sigma_rad(sigma_rad), sigma_m(sigma_m) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) R_prior[3 * c + r] = prior.linear()(r, c);  // column major
    const Vec3 centre = -prior.linear().transpose() * prior.translation();
    for (int k = 0; k < 3; ++k) centre_prior[k] = centre[k];
  }
  template <typename T>
  bool operator()(const T* pose, T* residual) const {
    T R[9];
    ceres::AngleAxisToRotationMatrix(pose, R);  // column major
    T E[9];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        E[3 * c + r] = T(0);
        for (int k = 0; k < 3; ++k) E[3 * c + r] += R[3 * k + r] * T(R_prior[3 * k + c]);
      }
    ceres::RotationMatrixToAngleAxis(E, residual);
    for (int k = 0; k < 3; ++k) {
      residual[k] /= T(sigma_rad);
      T centre = T(0);  // -R^T t
      for (int j = 0; j < 3; ++j) centre -= R[3 * k + j] * pose[3 + j];
      residual[3 + k] = (centre - T(centre_prior[k])) / T(sigma_m);
    }
    return true;
  }
  double R_prior[9], centre_prior[3], sigma_rad, sigma_m;
};

// The newest keyframe's pose is tracking's, which the motion model held
// where the frame's own evidence leaves a direction nearly free (far points
// only: a sideways slide with a turn reprojects them alike). A two-view BA
// (a map's second keyframe, the first fixed) keeps it near that pose with
// these sigmas; where its points pin it, they outweigh the prior by far. In
// larger windows the other views pin the points.
constexpr double kHeldSigmaM = 0.01;
constexpr double kHeldSigmaDeg = 0.5;

// The global BA's depth row: the disparity, three times a keypoint's weight
// (a third of a pixel at the finest level, where an RGB-D sensor's
// disparity is good to a fraction of one). With every keyframe free, the
// map's scale rests on the depth alone; weighed as the virtual right
// coordinate, whose error holds the keypoint's too, it let the scale slide
// 0.6 % on the real excerpt (docs/place-recognition.md). Local windows keep
// the right coordinate: their fixed neighbours hold the scale.
constexpr double kGlobalDisparityWeight = 3.0;

// A keyframe that sees fewer map points than this stays out of the global BA
// and keeps its pose relative to its parent. Where a poster held near the
// camera left a keyframe 9 points, the whole map's solve slid it 0.43 m
// (docs/place-recognition.md); local BA, which holds the map around it,
// places such keyframes.
constexpr int kGlobalMinPoints = 50;

struct BaRun {
  int iterations = 10;
  const std::atomic<bool>* abort = nullptr;
  // One of the free keyframes that keeps a prior at its pose as it was.
  const KeyFrame* held = nullptr;
  double disparity_weight = 0;  // 0: the depth row is the virtual right coordinate
  double max_seconds = 0;       // 0: no limit
  // Keyframes of this map made during the solve follow their parents.
  bool carry_newcomers = false;
  // Keyframes (not an origin) that see fewer map points than this are left
  // out of the solve and follow their parents too (0: none).
  int min_points = 0;
  std::uint32_t map_id = 0;
  const std::function<void()>* after_solve = nullptr;
};

// Keyframes of `map_id` made while a bundle adjustment ran (ids from
// `first_new` on), and those it left out (`held_out`), keep their pose
// relative to their parent in the spanning tree, which moved from
// `moved[parent].first` to `.second`; the points they made follow their
// reference keyframe, or the keyframe carried that sees them. Exclusive lock
// held.
void carryNewcomers(Map* map, std::uint32_t map_id, std::int64_t first_new,
                    const std::unordered_set<std::int64_t>& held_out, const std::vector<KeyFrame*>& solved,
                    const std::vector<std::shared_ptr<MapPoint>>& solved_points,
                    std::unordered_map<const KeyFrame*, std::pair<SE3, SE3>>* moved, LocalBaStats* stats) {
  const std::unordered_set<const KeyFrame*> in_solve(solved.begin(), solved.end());
  std::vector<KeyFrame*> newcomers;
  for (const auto& k : map->keyframes())
    if (!k->bad && k->map_id == map_id && (k->id >= first_new || held_out.count(k->id)) && !in_solve.count(k.get()))
      newcomers.push_back(k.get());
  std::vector<KeyFrame*> carried;
  // Parents first; a culled keyframe's children may have been handed to a
  // newer keyframe, hence the passes.
  for (bool progress = true; progress;) {
    progress = false;
    for (KeyFrame*& k : newcomers) {
      if (!k || !k->parent) continue;
      const auto it = moved->find(k->parent);
      if (it == moved->end()) continue;
      const SE3 before = k->T_c_w();
      k->T_c_w() = renormalized(before * it->second.first.inverse() * it->second.second);
      moved->emplace(k, std::make_pair(before, k->T_c_w()));
      carried.push_back(k);
      k = nullptr;
      progress = true;
    }
  }
  stats->keyframes_carried = static_cast<int>(carried.size());
  std::unordered_set<const MapPoint*> done;
  for (const auto& p : solved_points) done.insert(p.get());
  for (KeyFrame* k : carried) {
    for (const auto& p : k->frame.points) {
      if (!p || p->bad || p->isTemporary() || !done.insert(p.get()).second) continue;
      auto it = p->reference ? moved->find(p->reference) : moved->end();
      if (it == moved->end()) it = moved->find(k);
      p->position = it->second.second.inverse() * (it->second.first * p->position);
      p->updateFromObservations();
      ++stats->points_carried;
    }
  }
}

// The bundle adjustment of the keyframes `select` picks (shared lock held)
// and every point they see; other keyframes that see those points are held
// fixed, and so are map origins. Snapshot, solve without the lock, write
// back unless the world moved meanwhile (Map::epoch).
LocalBaStats bundleAdjust(Map* map, const CameraModel* camera,
                          const std::function<std::vector<KeyFrame*>()>& select, const BaRun& run) {
  const KeyFrame* held = run.held;
  const std::atomic<bool>* abort = run.abort;
  const int iterations = run.iterations;
  const auto start = std::chrono::steady_clock::now();
  LocalBaStats stats;
  struct Obs {
    int camera;  // index into poses
    int point;   // index into points
    Observation o;
    int feature;
  };
  std::vector<KeyFrame*> cameras;
  // A keyframe culled meanwhile may be freed (by tracking) before the
  // write-back, which finds each one again by id.
  std::vector<std::int64_t> camera_ids;
  std::vector<std::array<double, 6>> poses;
  std::vector<char> fixed;
  std::vector<std::shared_ptr<MapPoint>> points;
  std::vector<std::array<double, 3>> positions;
  std::vector<Obs> observations;
  std::uint64_t epoch = 0;
  std::int64_t first_new = 0;  // keyframes from this id on were made after the snapshot
  std::unordered_set<std::int64_t> held_out;
  int held_camera = -1;
  SE3 held_prior = SE3::Identity();

  {  // Snapshot under a shared lock.
    std::shared_lock lock(map->mutex());
    std::vector<KeyFrame*> local = select();
    // Keyframes their points cannot place (a mover filled the view) stay
    // out: free among hundreds, a handful of points lets one slide far.
    if (run.min_points > 0)
      std::erase_if(local, [&](KeyFrame* k) {
        const bool out = !k->origin && k->trackedPoints(1) < run.min_points;
        if (out) held_out.insert(k->id);
        return out;
      });
    stats.keyframes_held_out = static_cast<int>(held_out.size());
    if (local.empty()) return stats;
    epoch = map->epoch();
    first_new = map->nextKeyFrameId();
    std::unordered_map<KeyFrame*, int> camera_index;
    for (KeyFrame* k : local) {
      camera_index[k] = static_cast<int>(cameras.size());
      cameras.push_back(k);
      fixed.push_back(k->origin);
    }
    std::unordered_map<MapPoint*, int> point_index;
    for (KeyFrame* k : local) {
      for (const auto& p : k->frame.points) {
        if (!p || p->bad || point_index.count(p.get())) continue;
        point_index[p.get()] = static_cast<int>(points.size());
        points.push_back(p);
        positions.push_back({p->position.x(), p->position.y(), p->position.z()});
      }
    }
    for (std::size_t pi = 0; pi < points.size(); ++pi) {
      for (const auto& [obs_kf, idx] : points[pi]->observations) {
        if (obs_kf->bad || held_out.count(obs_kf->id)) continue;
        auto it = camera_index.find(obs_kf);
        if (it == camera_index.end()) {
          it = camera_index.emplace(obs_kf, static_cast<int>(cameras.size())).first;
          cameras.push_back(obs_kf);
          fixed.push_back(1);
        }
        observations.push_back({it->second, static_cast<int>(pi), observationOf(obs_kf->frame, idx), idx});
      }
    }
    poses.resize(cameras.size());
    for (std::size_t c = 0; c < cameras.size(); ++c) {
      toParameters(cameras[c]->T_c_w(), poses[c].data());
      camera_ids.push_back(cameras[c]->id);
    }
    // Two views only (a map's second keyframe): the points have no third view
    // to pin them.
    if (cameras.size() == 2)
      for (std::size_t c = 0; c < cameras.size(); ++c)
        if (cameras[c] == held && !fixed[c]) held_camera = static_cast<int>(c), held_prior = held->T_c_w();
  }
  stats.points = static_cast<int>(points.size());
  stats.observations = static_cast<int>(observations.size());
  for (char f : fixed) (f ? stats.fixed_keyframes : stats.keyframes)++;
  if (stats.keyframes == 0 || points.empty()) return stats;
  // With only keyframe 0 free-less windows, hold at least one camera fixed.
  if (stats.fixed_keyframes == 0) {
    fixed[cameras.size() - 1] = 1;
    stats.fixed_keyframes = 1;
    stats.keyframes--;
  }

  std::vector<char> is_outlier(observations.size(), 0);
  for (int pass = 0; pass < 2; ++pass) {
    if (abort && abort->load()) break;
    ceres::Problem problem;
    for (std::size_t i = 0; i < observations.size(); ++i) {
      if (is_outlier[i]) continue;
      const Obs& ob = observations[i];
      const double delta = std::sqrt(ob.o.u_right >= 0 ? kChi2Stereo : kChi2Mono);
      problem.AddResidualBlock(new BundleAdjustmentCost(*camera, ob.o, run.disparity_weight), new ceres::HuberLoss(delta),
                               poses[ob.camera].data(), positions[ob.point].data());
    }
    for (std::size_t c = 0; c < cameras.size(); ++c)
      if (fixed[c] && problem.HasParameterBlock(poses[c].data())) problem.SetParameterBlockConstant(poses[c].data());
    if (held_camera >= 0 && problem.HasParameterBlock(poses[held_camera].data()))
      problem.AddResidualBlock(new ceres::AutoDiffCostFunction<PosePriorCost, 6, 6>(
                                   new PosePriorCost(held_prior, kHeldSigmaDeg * M_PI / 180.0, kHeldSigmaM)),
                               nullptr, poses[held_camera].data());
    ceres::Solver::Options options;
    // Local windows have few cameras: a dense reduced camera system is the
    // fastest (Debian's Ceres has no fixed-size Schur specialisations). A
    // whole map's needs a sparse one.
    options.linear_solver_type = ceres::DENSE_SCHUR;
    if (cameras.size() > 60) {
      options.linear_solver_type = ceres::SPARSE_SCHUR;
      if (!ceres::IsSparseLinearAlgebraLibraryTypeAvailable(options.sparse_linear_algebra_library_type)) {
        options.linear_solver_type = ceres::ITERATIVE_SCHUR;
        options.preconditioner_type = ceres::SCHUR_JACOBI;
      }
    }
    options.max_num_iterations = pass == 0 ? std::max(1, iterations / 2) : iterations;
    if (run.max_seconds > 0) {
      // The first pass gets half of the time, the second what is left.
      const double left =
          run.max_seconds - std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      if (pass > 0 && left <= 0) {
        stats.out_of_time = true;
        break;
      }
      options.max_solver_time_in_seconds = std::max(0.0, pass == 0 ? left / 2 : left);
    }
    options.num_threads = 1;
    options.logging_type = ceres::SILENT;
    ceres::Solver::Summary summary;
    ceres::Solve(options, &problem, &summary);
    if (run.max_seconds > 0 && summary.termination_type == ceres::NO_CONVERGENCE &&
        summary.num_successful_steps + summary.num_unsuccessful_steps < options.max_num_iterations)
      stats.out_of_time = true;
    if (pass == 0) stats.initial_cost = summary.initial_cost;
    stats.final_cost = summary.final_cost;
    // Set aside observations that fail the chi-square test, then refine.
    for (std::size_t i = 0; i < observations.size(); ++i) {
      const Obs& ob = observations[i];
      const Vec3 pw(positions[ob.point][0], positions[ob.point][1], positions[ob.point][2]);
      bool behind = false;
      const double chi2 = reprojectionChi2(*camera, fromParameters(poses[ob.camera].data()), pw, ob.o, &behind);
      is_outlier[i] = behind || chi2 > (ob.o.u_right >= 0 ? kChi2Stereo : kChi2Mono);
    }
  }

  if (run.after_solve && *run.after_solve) (*run.after_solve)();
  {  // Write back under the exclusive lock.
    std::unique_lock lock(map->mutex());
    // Maps merged meanwhile: the poses read are in a frame the map left.
    if (map->epoch() != epoch) {
      stats.world_moved = true;
      return stats;
    }
    stats.applied = true;
    for (std::size_t c = 0; c < cameras.size(); ++c) {
      KeyFrame* k = map->keyFrame(camera_ids[c]);
      cameras[c] = k && !k->bad ? k : nullptr;
    }
    for (std::size_t i = 0; i < observations.size(); ++i) {
      if (!is_outlier[i]) continue;
      const Obs& ob = observations[i];
      const auto& p = points[ob.point];
      KeyFrame* k = cameras[static_cast<std::size_t>(ob.camera)];
      if (p->bad || !k || k->frame.points[ob.feature] != p) continue;
      k->eraseObservation(ob.feature);
      ++stats.outliers_removed;
      if (p->observations.empty())
        map->erasePoint(p);
    }
    // Each solved keyframe's pose now (local BA may have moved it since the
    // snapshot) and after: newcomers keep theirs relative to it.
    std::unordered_map<const KeyFrame*, std::pair<SE3, SE3>> moved;
    for (std::size_t c = 0; c < cameras.size(); ++c) {
      if (!cameras[c]) continue;
      const SE3 before = cameras[c]->T_c_w();
      if (!fixed[c]) cameras[c]->T_c_w() = fromParameters(poses[c].data());
      if (run.carry_newcomers) moved.emplace(cameras[c], std::make_pair(before, cameras[c]->T_c_w()));
    }
    for (std::size_t pi = 0; pi < points.size(); ++pi) {
      const auto& p = points[pi];
      if (p->bad) continue;
      p->position = Vec3(positions[pi][0], positions[pi][1], positions[pi][2]);
      // Every point was made from a depth measurement. One whose measured
      // observations were all set aside is held by its image positions alone,
      // and with little parallax those slide it along its ray, metres beyond
      // what the sensor can see: such a point is no part of the scene.
      if (!withinDepthRange(*camera, *p)) {
        map->erasePoint(p);
        ++stats.out_of_range_removed;
        continue;
      }
      p->updateFromObservations();
    }
    if (run.carry_newcomers) {
      carryNewcomers(map, run.map_id, first_new, held_out, cameras, points, &moved, &stats);
      // Under the same lock: tracking re-expresses its last pose in the
      // moved world before it tracks another frame.
      map->worldMoved();
    }
  }
  return stats;
}
}  // namespace

LocalBaStats localBundleAdjustment(Map* map, KeyFrame* kf, int max_keyframes, int iterations,
                                   const std::atomic<bool>* abort) {
  BaRun run;
  run.iterations = iterations;
  run.abort = abort;
  run.held = kf;
  return bundleAdjust(
      map, kf->frame.camera,
      [&]() -> std::vector<KeyFrame*> {
        if (kf->bad) return {};
        std::vector<KeyFrame*> local{kf};
        for (KeyFrame* n : kf->bestNeighbours(max_keyframes - 1)) local.push_back(n);
        return local;
      },
      run);
}

LocalBaStats globalBundleAdjustment(Map* map, const CameraModel* camera, std::uint32_t map_id,
                                    const GlobalBaOptions& options) {
  BaRun run;
  run.iterations = options.iterations;
  run.abort = options.abort;
  run.disparity_weight = kGlobalDisparityWeight;
  run.max_seconds = options.max_seconds;
  run.carry_newcomers = true;
  run.min_points = kGlobalMinPoints;
  run.map_id = map_id;
  run.after_solve = &options.after_solve;
  auto select = [&] {
    std::vector<KeyFrame*> all;
    for (const auto& kf : map->keyframes())
      if (!kf->bad && kf->map_id == map_id) all.push_back(kf.get());
    if (options.max_keyframes <= 0 || all.size() <= static_cast<std::size_t>(options.max_keyframes)) return all;
    // The loop's part: outward from its two sides by covisibility,
    // nearest first, until the cap.
    std::vector<KeyFrame*> region;
    std::unordered_set<const KeyFrame*> in;
    for (std::int64_t id : options.seeds) {
      KeyFrame* s = map->keyFrame(id);
      if (s && !s->bad && s->map_id == map_id && in.insert(s).second) region.push_back(s);
    }
    for (std::size_t next = 0; next < region.size() && region.size() < static_cast<std::size_t>(options.max_keyframes);
         ++next)
      for (KeyFrame* n : region[next]->ordered_neighbours) {
        if (region.size() >= static_cast<std::size_t>(options.max_keyframes)) break;
        if (!n->bad && n->map_id == map_id && in.insert(n).second) region.push_back(n);
      }
    return region;
  };
  LocalBaStats stats;
  for (int dropped = 0;; ++dropped) {
    stats = bundleAdjust(map, camera, select, run);
    stats.dropped = dropped;
    if (!stats.world_moved || dropped >= options.retries || (options.abort && options.abort->load())) break;
  }
  return stats;
}

namespace {
// Error of a relative pose: log(T_ij_measured^-1 * T_i * T_j^-1), rotation
// as an angle-axis, then translation; T_* are world-to-camera poses.
struct RelativePoseError {
  explicit RelativePoseError(const SE3& T_i_j) {
    const SE3 inv = T_i_j.inverse();
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) R_inv[3 * c + r] = inv.linear()(r, c);  // column major
      t_inv[r] = inv.translation()[r];
    }
  }
  template <typename T>
  bool operator()(const T* pose_i, const T* pose_j, T* residual) const {
    T Ri[9], Rj[9];
    ceres::AngleAxisToRotationMatrix(pose_i, Ri);  // column major
    ceres::AngleAxisToRotationMatrix(pose_j, Rj);
    auto at = [](const T* R, int r, int c) { return R[3 * c + r]; };
    // T_i * T_j^-1: rotation Ri Rj^T, translation t_i - Ri Rj^T t_j.
    T R[9], t[3];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        R[3 * c + r] = T(0);
        for (int k = 0; k < 3; ++k) R[3 * c + r] += at(Ri, r, k) * at(Rj, c, k);
      }
    for (int r = 0; r < 3; ++r) {
      t[r] = pose_i[3 + r];
      for (int k = 0; k < 3; ++k) t[r] -= at(R, r, k) * pose_j[3 + k];
    }
    // The measured inverse in front.
    T E[9], e[3];
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        E[3 * c + r] = T(0);
        for (int k = 0; k < 3; ++k) E[3 * c + r] += T(R_inv[3 * k + r]) * at(R, k, c);
      }
      e[r] = T(t_inv[r]);
      for (int k = 0; k < 3; ++k) e[r] += T(R_inv[3 * k + r]) * t[k];
    }
    ceres::RotationMatrixToAngleAxis(E, residual);
    for (int r = 0; r < 3; ++r) residual[3 + r] = e[r];
    return true;
  }
  double R_inv[9], t_inv[3];
};
}  // namespace

std::vector<SE3> optimizePoseGraph(const std::vector<SE3>& initial, const std::vector<char>& fixed,
                                   const std::vector<PoseGraphEdge>& edges, int iterations) {
  std::vector<std::array<double, 6>> poses(initial.size());
  for (std::size_t i = 0; i < initial.size(); ++i) toParameters(initial[i], poses[i].data());
  ceres::Problem problem;
  for (const PoseGraphEdge& e : edges) {
    if (e.i == e.j || e.i >= initial.size() || e.j >= initial.size()) continue;
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<RelativePoseError, 6, 6, 6>(new RelativePoseError(e.T_i_j)),
                             nullptr, poses[e.i].data(), poses[e.j].data());
  }
  for (std::size_t i = 0; i < initial.size(); ++i)
    if (fixed[i] && problem.HasParameterBlock(poses[i].data())) problem.SetParameterBlockConstant(poses[i].data());
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  if (!ceres::IsSparseLinearAlgebraLibraryTypeAvailable(options.sparse_linear_algebra_library_type))
    options.linear_solver_type = ceres::DENSE_QR;
  options.max_num_iterations = iterations;
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  std::vector<SE3> out(initial.size());
  for (std::size_t i = 0; i < initial.size(); ++i) out[i] = renormalized(fromParameters(poses[i].data()));
  return out;
}

}  // namespace stillpoint::slam
