#pragma once
// Pose-only optimisation and local bundle adjustment with Ceres.
#include <atomic>
#include <cstdint>
#include <functional>
#include <limits>
#include <vector>

#include "map.hpp"

namespace stillpoint::slam {

// Observation of a 3D point by a camera: undistorted pixel, virtual right u
// (< 0 when the keypoint has no depth), and its pyramid-level information.
struct Observation {
  double u = 0, v = 0, u_right = -1;
  double inv_sigma = 1;  // 1 / (scale^level)
};

// Thresholds of the chi-square test at 95 %, 2 and 3 degrees of freedom.
constexpr double kChi2Mono = 5.991;
constexpr double kChi2Stereo = 7.815;

struct PoseProblem {
  const CameraModel* camera = nullptr;
  std::vector<Vec3> points_w;
  std::vector<Observation> observations;
  // Optional prior on the pose (e.g. the motion model's prediction): adds
  // r^T r with r = sqrt_information * [log(R R_p^T); t - R R_p^T t_p].
  // Zero sqrt_information (the default) = no prior.
  SE3 prior = SE3::Identity();
  Eigen::Matrix<double, 6, 1> prior_sqrt_information = Eigen::Matrix<double, 6, 1>::Zero();
};

struct PoseResult {
  SE3 T_c_w;
  std::vector<char> inlier;
  int inliers = 0;
};

// Robust (Huber) pose-only optimisation in rounds; after each round matches
// failing the chi-square test are set aside (and may return in a later
// round). Recovers from `initial`. A dedicated 6-DoF Levenberg-Marquardt with
// analytic Jacobians: it runs on every frame, where a general solver's set-up
// cost dominates (see optimizePoseCeres, the reference it is tested against).
PoseResult optimizePose(const PoseProblem& problem, const SE3& initial, int rounds = 4);

// The pose that explains the most of a set of matches, where a minority may
// share another motion: MSAC. Each hypothesis is the rigid motion of three
// matches measured in 3D in the camera (`seen`, from depth), taken from three
// different `group`s (depth clusters: three points of one surface are a poor
// sample and likely share its motion); it is scored by the truncated cost
// sum min(chi2, cap) over all matches. The best is refitted on its inliers
// (a fit over all the matches would be pulled back by the ones it rejects).
// A redescending search, unlike optimizePose: it can leave the basin of a
// pose that a moving minority has pulled into a compromise, where both the
// minority and the rest stay under the chi-square gate.
struct ConsensusProblem {
  PoseProblem pose;
  std::vector<Vec3> seen;         // per match: its point in the camera frame
  std::vector<char> sampleable;   // per match: `seen` can be sampled (good depth)
  std::vector<int> group;         // per match
  double cap = kChi2Stereo;
  int samples = 48;
  std::uint32_t seed = 0;         // deterministic per frame
  // No search when fewer matches pass the initial pose: it is not a
  // compromise to correct but wrong (the caller's fallback decides).
  int min_initial_inliers = 0;
};

struct ConsensusResult {
  SE3 T_c_w;
  double cost = 0;          // truncated cost of T_c_w
  double initial_cost = 0;  // of the initial pose
  int initial_inliers = 0;  // matches under the cap at the initial pose
};

// The best hypothesis, or the initial pose when none beats it, refitted on
// its inliers. Returns the initial pose (cost == initial_cost) when neither
// beats it or the search did not run (min_initial_inliers, fewer than three
// sampleable matches).
ConsensusResult consensusPose(const ConsensusProblem& problem, const SE3& initial);

// sum min(chi2, cap) over the problem's matches under T_c_w; `inliers`
// (optional): how many are under the cap. Stops adding once the sum reaches
// `stop_at` (then the sum and count are partial).
double truncatedPoseCost(const PoseProblem& problem, const SE3& T_c_w, double cap, int* inliers = nullptr,
                         double stop_at = std::numeric_limits<double>::infinity());

// The same optimisation through Ceres (auto-diff, Huber loss); slower, kept
// as the reference implementation for tests and benchmarks.
PoseResult optimizePoseCeres(const PoseProblem& problem, const SE3& initial, int rounds = 4);

// Convenience: optimises frame->T_c_w against its matched points, sets
// frame->outlier; returns the number of inliers.
// `prior` (optional): PoseProblem::prior and its sqrt information.
int optimizeFramePose(Frame* frame, const SE3* prior = nullptr,
                      const Eigen::Matrix<double, 6, 1>* prior_sqrt_information = nullptr);

// The observation of keypoint i of a frame (undistorted position, virtual
// right coordinate, level sigma).
Observation observationOf(const Frame& f, int i);

// The Gauss-Newton information J^T J of T_c_w over every observation of the
// problem and its prior (no robust weights), for a left perturbation
// exp([w, v]) * T_c_w, rotation first: the inverse of the pose's covariance
// when an observation's level-0 pixel error has a sigma of one pixel.
Eigen::Matrix<double, 6, 6> poseInformation(const PoseProblem& problem, const SE3& T_c_w);

// The covariance of the camera's pose in the map from poseInformation's
// information of T_c_w, for observations whose level-0 pixel error has the
// sigma `pixel_sigma`: the camera's centre [m], then its rotation about the
// map's axes [rad] (a small rotation r turns R_w_c into exp(r) R_w_c). A weak
// prior (1 rad, 10 m) keeps a direction the information leaves free finite.
Eigen::Matrix<double, 6, 6> poseCovarianceInMap(const Eigen::Matrix<double, 6, 6>& information, const SE3& T_c_w,
                                                double pixel_sigma);

// Squared, sigma-normalised reprojection error of a point seen in a camera.
double reprojectionChi2(const CameraModel& camera, const SE3& T_c_w, const Vec3& p_w, const Observation& obs,
                        bool* behind = nullptr);

struct LocalBaStats {
  int keyframes = 0, fixed_keyframes = 0, points = 0, observations = 0, outliers_removed = 0;
  int out_of_range_removed = 0;  // points moved beyond every observer's depth range
  double initial_cost = 0, final_cost = 0;
  // Global BA: whether it was written back (not when the world moved
  // meanwhile), whether its time ran out before its iterations, the
  // keyframes too weakly observed to be in the solve, and the keyframes
  // (those, and those made during the solve) and points it carried along.
  bool applied = false;
  bool world_moved = false;  // not applied: the world moved during the solve
  int dropped = 0;           // global BA: solves dropped for that and done again
  bool out_of_time = false;
  int keyframes_held_out = 0;
  int keyframes_carried = 0, points_carried = 0;
};

// Local BA around `kf`: it and its best covisible keyframes are optimised
// together with every point they see; other keyframes seeing those points are
// held fixed. In a window of two views (a map's second keyframe) `kf` keeps a
// prior at its tracked pose: far points leave a slide with a turn nearly free
// there. Runs without the map lock between a snapshot and a write-back.
LocalBaStats localBundleAdjustment(Map* map, KeyFrame* kf, int max_keyframes, int iterations,
                                   const std::atomic<bool>* abort = nullptr);

struct GlobalBaOptions {
  int iterations = 10;
  // The solve stops at this many seconds (0: at its iterations), keeping the
  // best solution found: each accepted step lowers the cost, so a cut-short
  // solve still improves on the map it read.
  double max_seconds = 0;
  const std::atomic<bool>* abort = nullptr;
  // A map of more keyframes than this optimises the loop's part of it: the
  // keyframes nearest `seeds` (the loop's two sides) by covisibility, the
  // rest held where they are (0: every keyframe).
  int max_keyframes = 0;
  std::vector<std::int64_t> seeds;
  // A solve the world moved under (a merge, another loop) is done again
  // from the moved map, up to this many times.
  int retries = 0;
  // Called between the solve and the write-back, with no lock held: the map
  // changes there as under a running system (tests).
  std::function<void()> after_solve;
};

// The same over every keyframe of one map (its origin fixed), or the loop's
// part of a large one: the global BA after a loop closure. Results are
// dropped when the world moved meanwhile; written back, they move it
// (Map::worldMoved, under the same lock).
// Keyframes made during the solve (not in it) keep their pose relative to
// their parent in the spanning tree, and the points they made follow them: a
// map that went on growing while the BA ran stays one piece. So do keyframes
// that see fewer than 50 map points, left out of the solve.
LocalBaStats globalBundleAdjustment(Map* map, const CameraModel* camera, std::uint32_t map_id,
                                    const GlobalBaOptions& options);

// A pose graph: poses (world to camera) tied by measured relative poses
// T_i_j = T_i_w * T_j_w^-1; the fixed ones do not move. Returns the poses
// that best agree with every measurement (least squares over the SE3 error
// of each edge): the essential-graph optimisation of a loop closure.
struct PoseGraphEdge {
  std::size_t i = 0, j = 0;
  SE3 T_i_j;
};
std::vector<SE3> optimizePoseGraph(const std::vector<SE3>& initial, const std::vector<char>& fixed,
                                   const std::vector<PoseGraphEdge>& edges, int iterations = 20);

}  // namespace stillpoint::slam
