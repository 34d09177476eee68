#include "stillpoint/eval/metrics.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <numbers>
#include <numeric>
#include <sstream>
#include <tuple>
#include <utility>

#include <Eigen/Cholesky>
#include <Eigen/SVD>

#include "stillpoint/core/health_causes.hpp"

namespace stillpoint::eval {
namespace {

constexpr double kRadToDeg = 180.0 / std::numbers::pi;

std::int64_t secondsToNs(double s) { return static_cast<std::int64_t>(std::llround(s * 1e9)); }

bool strictlyIncreasing(const Trajectory& trajectory) {
  for (std::size_t k = 1; k < trajectory.size(); ++k) {
    if (!(trajectory[k - 1].stamp < trajectory[k].stamp)) return false;
  }
  return true;
}

double rms(const std::vector<double>& values) {
  double sum_sq = 0.0;
  for (double v : values) sum_sq += v * v;
  return std::sqrt(sum_sq / static_cast<double>(values.size()));
}

// Index among the first n poses whose stamp is closest to target (the earlier
// one on a tie).
std::size_t closestIndex(const Trajectory& trajectory, std::size_t n, Timestamp target) {
  const auto end = trajectory.begin() + static_cast<std::ptrdiff_t>(n);
  const auto it = std::lower_bound(
      trajectory.begin(), end, target,
      [](const StampedPose& pose, Timestamp t) { return pose.stamp < t; });
  if (it == trajectory.begin()) return 0;
  if (it == end) return n - 1;
  const auto after = static_cast<std::size_t>(it - trajectory.begin());
  const std::int64_t d_after = it->stamp.nanoseconds() - target.nanoseconds();
  const std::int64_t d_before = target.nanoseconds() - (it - 1)->stamp.nanoseconds();
  return d_before <= d_after ? after - 1 : after;
}

}  // namespace

// Time spans in seconds are compared in nanoseconds (int64): 10^6 s keeps
// every sum and difference with a stamp far inside its range.
constexpr double kMaxSpanS = 1e6;

Status EvalOptions::validate() const {
  if (!(max_dt_s >= 0.0 && max_dt_s <= kMaxSpanS)) return Error{"EvalOptions.max_dt_s must be in [0, 1e6] s"};
  if (!(rpe_delta_s > 0.0 && rpe_delta_s <= kMaxSpanS)) return Error{"EvalOptions.rpe_delta_s must be in (0, 1e6] s"};
  if (min_matches < 3) return Error{"EvalOptions.min_matches must be >= 3"};
  return Status::success();
}

std::vector<Match> associate(const Trajectory& est, const Trajectory& gt, double max_dt_s) {
  const std::int64_t max_dt_ns = secondsToNs(max_dt_s);
  // (|dt| ns, est index, gt index): sorting the tuples gives associate.py's order.
  std::vector<std::tuple<std::int64_t, std::size_t, std::size_t>> candidates;
  for (std::size_t i = 0; i < est.size(); ++i) {
    const std::int64_t t = est[i].stamp.nanoseconds();
    const auto first = std::lower_bound(
        gt.begin(), gt.end(), t - max_dt_ns,
        [](const StampedPose& pose, std::int64_t ns) { return pose.stamp.nanoseconds() < ns; });
    for (auto it = first; it != gt.end() && it->stamp.nanoseconds() <= t + max_dt_ns; ++it) {
      const std::int64_t diff = std::abs(it->stamp.nanoseconds() - t);
      candidates.emplace_back(diff, i, static_cast<std::size_t>(it - gt.begin()));
    }
  }
  std::sort(candidates.begin(), candidates.end());

  std::vector<bool> est_used(est.size(), false);
  std::vector<bool> gt_used(gt.size(), false);
  std::vector<Match> matches;
  for (const auto& [diff, i, j] : candidates) {
    if (est_used[i] || gt_used[j]) continue;
    est_used[i] = true;
    gt_used[j] = true;
    matches.push_back({i, j});
  }
  std::sort(matches.begin(), matches.end(),
            [](const Match& a, const Match& b) { return a.est_index < b.est_index; });
  return matches;
}

Vec3 Alignment::apply(const Vec3& p_est) const {
  return scale * (T_gt_est.linear() * p_est) + T_gt_est.translation();
}

SE3 Alignment::apply(const SE3& T_w_c) const {
  SE3 out = SE3::Identity();
  out.linear() = T_gt_est.linear() * T_w_c.linear();
  out.translation() = apply(Vec3(T_w_c.translation()));
  return out;
}

Result<Alignment> alignUmeyama(const std::vector<Vec3>& est_positions,
                               const std::vector<Vec3>& gt_positions, bool estimate_scale) {
  const std::size_t n = est_positions.size();
  if (n != gt_positions.size()) return Error{"alignUmeyama: point sets differ in size"};
  if (n < 3) return Error{"alignUmeyama: need at least 3 point pairs"};

  Vec3 mean_est = Vec3::Zero();
  Vec3 mean_gt = Vec3::Zero();
  for (std::size_t k = 0; k < n; ++k) {
    if (!est_positions[k].allFinite() || !gt_positions[k].allFinite()) {
      return Error{"alignUmeyama: non-finite position at index " + std::to_string(k)};
    }
    mean_est += est_positions[k];
    mean_gt += gt_positions[k];
  }
  const double inv_n = 1.0 / static_cast<double>(n);
  mean_est *= inv_n;
  mean_gt *= inv_n;

  // Cross-covariance of the centred sets, Sigma = 1/n sum (gt_c)(est_c)^T.
  Mat3 sigma = Mat3::Zero();
  double var_est = 0.0;
  for (std::size_t k = 0; k < n; ++k) {
    const Vec3 e = est_positions[k] - mean_est;
    const Vec3 g = gt_positions[k] - mean_gt;
    sigma += g * e.transpose();
    var_est += e.squaredNorm();
  }
  sigma *= inv_n;
  var_est *= inv_n;

  const Eigen::JacobiSVD<Mat3> svd(sigma, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Mat3& U = svd.matrixU();
  const Mat3& V = svd.matrixV();
  // Reflection guard: force det(R) = +1 by flipping the weakest direction.
  Vec3 s_diag(1.0, 1.0, 1.0);
  if (U.determinant() * V.determinant() < 0.0) s_diag.z() = -1.0;
  const Mat3 R = U * s_diag.asDiagonal() * V.transpose();

  Alignment alignment;
  if (estimate_scale) {
    if (var_est < 1e-12) return Error{"alignUmeyama: estimate positions have no spread, scale undefined"};
    alignment.scale = svd.singularValues().dot(s_diag) / var_est;
    if (!(alignment.scale > 0.0)) return Error{"alignUmeyama: degenerate scale"};
  }
  alignment.T_gt_est.linear() = R;
  alignment.T_gt_est.translation() = mean_gt - alignment.scale * (R * mean_est);
  return alignment;
}

RpeSummary computeRpe(const Trajectory& est, const Trajectory& gt, double delta_s) {
  RpeSummary summary;
  const std::size_t n = std::min(est.size(), gt.size());
  const std::int64_t delta_ns = secondsToNs(delta_s);
  if (n >= 2) {
    const Timestamp last = est[n - 1].stamp;
    for (std::size_t i = 0; i < n; ++i) {
      const auto target = Timestamp::fromNanoseconds(est[i].stamp.nanoseconds() + delta_ns);
      if (target > last) break;  // stamps increase, so every later i overshoots too
      const std::size_t j = closestIndex(est, n, target);
      if (j <= i) continue;
      const SE3 delta_est = est[i].T_w_c.inverse() * est[j].T_w_c;
      const SE3 delta_gt = gt[i].T_w_c.inverse() * gt[j].T_w_c;
      const SE3 error = delta_gt.inverse() * delta_est;
      RelativeError pair;
      pair.from = est[i].stamp;
      pair.to = est[j].stamp;
      pair.dt_s = secondsBetween(pair.to, pair.from);
      pair.trans_m = error.translation().norm();
      pair.rot_deg = rotationAngle(error.linear()) * kRadToDeg;
      summary.pairs.push_back(pair);
    }
  }
  if (summary.pairs.empty()) {
    summary.trans_m_s = std::numeric_limits<double>::quiet_NaN();
    summary.rot_deg_s = std::numeric_limits<double>::quiet_NaN();
    return summary;
  }
  std::vector<double> trans_rates;
  std::vector<double> rot_rates;
  for (const RelativeError& pair : summary.pairs) {
    trans_rates.push_back(pair.trans_m / pair.dt_s);
    rot_rates.push_back(pair.rot_deg / pair.dt_s);
  }
  summary.trans_m_s = rms(trans_rates);
  summary.rot_deg_s = rms(rot_rates);
  return summary;
}

namespace {
void matchedPositions(const std::vector<Match>& matches, const Trajectory& est, const Trajectory& gt,
                      std::vector<Vec3>* est_positions, std::vector<Vec3>* gt_positions) {
  for (const Match& m : matches) {
    est_positions->push_back(est[m.est_index].T_w_c.translation());
    gt_positions->push_back(gt[m.gt_index].T_w_c.translation());
  }
}
}  // namespace

Result<EvalResult> evaluate(const Trajectory& gt, const Trajectory& est,
                            const EvalOptions& options) {
  if (Status status = options.validate(); !status) return Error{status.error()};
  if (!strictlyIncreasing(gt)) return Error{"ground truth timestamps are not strictly increasing"};
  if (!strictlyIncreasing(est)) return Error{"estimate timestamps are not strictly increasing"};

  const std::vector<Match> matches = associate(est, gt, options.max_dt_s);
  if (matches.size() < options.min_matches) {
    std::ostringstream os;
    os << "only " << matches.size() << " of " << est.size()
       << " estimate poses have a ground-truth pose within " << options.max_dt_s
       << " s (need at least " << options.min_matches << ")";
    return Error{os.str()};
  }

  // Each map of the estimate (StampedPose::map_id: a SLAM system that
  // started a new map after a loss) is in its own frame: it is aligned on its
  // own, and relative errors never span two maps. A map with fewer than
  // min_matches matched poses cannot be aligned and is left out (counted).
  std::map<std::uint32_t, std::vector<Match>> by_map;
  for (const Match& m : matches) by_map[est[m.est_index].map_id].push_back(m);

  EvalResult result;
  result.maps = by_map.size();
  std::vector<double> errors, trans_rates, rot_rates;
  for (const auto& [map_id, map_matches] : by_map) {
    if (by_map.size() > 1 && map_matches.size() < options.min_matches) {
      result.unaligned += map_matches.size();
      continue;
    }
    std::vector<Vec3> est_positions, gt_positions;
    matchedPositions(map_matches, est, gt, &est_positions, &gt_positions);
    Trajectory est_matched, gt_matched;
    for (const Match& m : map_matches) {
      est_matched.push_back(est[m.est_index]);
      gt_matched.push_back(gt[m.gt_index]);
    }
    auto alignment = alignUmeyama(est_positions, gt_positions, options.estimate_scale);
    if (!alignment) return Error{alignment.error()};
    // The alignment reported is the largest map's.
    if (map_matches.size() > result.matched_in_largest_map) {
      result.matched_in_largest_map = map_matches.size();
      result.alignment = *alignment;
    }
    Trajectory aligned_map;
    for (std::size_t k = 0; k < map_matches.size(); ++k) {
      const SE3 aligned = alignment->apply(est_matched[k].T_w_c);
      aligned_map.push_back({est_matched[k].stamp, aligned, map_id});
      const double e = (aligned.translation() - gt_positions[k]).norm();
      errors.push_back(e);
      result.pose_errors.push_back({est_matched[k].stamp, e});
    }
    // Aligned poses: a no-op for a rigid alignment, and with a scale it applies
    // the scale correction to the relative translations too.
    RpeSummary rpe = computeRpe(aligned_map, gt_matched, options.rpe_delta_s);
    for (const RelativeError& pair : rpe.pairs) {
      trans_rates.push_back(pair.trans_m / pair.dt_s);
      rot_rates.push_back(pair.rot_deg / pair.dt_s);
      result.relative_errors.push_back(pair);
    }
    result.est_aligned.insert(result.est_aligned.end(), aligned_map.begin(), aligned_map.end());
    result.gt_matched.insert(result.gt_matched.end(), gt_matched.begin(), gt_matched.end());
  }
  // Maps were visited in id order; the per-pose lists go back to time order.
  std::vector<std::size_t> order(result.est_aligned.size());
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(),
            [&](std::size_t a, std::size_t b) { return result.est_aligned[a].stamp < result.est_aligned[b].stamp; });
  auto permute = [&order](auto& v) {
    auto copy = v;
    for (std::size_t k = 0; k < order.size(); ++k) v[k] = copy[order[k]];
  };
  permute(result.est_aligned);
  permute(result.gt_matched);
  permute(result.pose_errors);
  std::sort(result.relative_errors.begin(), result.relative_errors.end(),
            [](const RelativeError& a, const RelativeError& b) { return a.from < b.from; });
  result.matched = errors.size();
  if (errors.empty()) return Error{"no map of the estimate has enough matched poses to align"};
  result.ate_rmse_m = rms(errors);
  double sum = 0.0;
  for (double e : errors) sum += e;
  result.ate_mean = sum / static_cast<double>(errors.size());
  result.ate_median = quantile(errors, 0.5);
  result.ate_max = *std::max_element(errors.begin(), errors.end());
  result.ate_one_frame_rmse_m = result.ate_rmse_m;
  if (by_map.size() > 1) {
    std::vector<Vec3> est_positions, gt_positions;
    matchedPositions(matches, est, gt, &est_positions, &gt_positions);
    auto alignment = alignUmeyama(est_positions, gt_positions, options.estimate_scale);
    if (!alignment) return Error{alignment.error()};
    std::vector<double> one_frame;
    for (std::size_t k = 0; k < est_positions.size(); ++k)
      one_frame.push_back((alignment->apply(est_positions[k]) - gt_positions[k]).norm());
    result.ate_one_frame_rmse_m = rms(one_frame);
  }
  result.rpe_pairs = trans_rates.size();
  result.rpe_trans_m_s = trans_rates.empty() ? std::numeric_limits<double>::quiet_NaN() : rms(trans_rates);
  result.rpe_rot_deg_s = rot_rates.empty() ? std::numeric_limits<double>::quiet_NaN() : rms(rot_rates);
  return result;
}

double quantile(std::vector<double> values, double q) {
  const std::size_t n = values.size();
  if (n == 0) return std::numeric_limits<double>::quiet_NaN();
  std::sort(values.begin(), values.end());
  if (q == 0.5) return n % 2 == 1 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
  const auto rank = static_cast<std::size_t>(std::ceil(q * static_cast<double>(n)));
  return values[std::min(n - 1, rank == 0 ? 0 : rank - 1)];
}

Status DriftOptions::validate() const {
  if (!(window_s > 0.0 && window_s <= kMaxSpanS)) return Error{"DriftOptions.window_s must be in (0, 1e6] s"};
  if (!std::isfinite(bound_m) || bound_m < 0.0) return Error{"DriftOptions.bound_m must be a finite value >= 0"};
  if (!(max_dt_s >= 0.0 && max_dt_s <= kMaxSpanS)) return Error{"DriftOptions.max_dt_s must be in [0, 1e6] s"};
  return Status::success();
}

DriftOptions poseHealthDriftOptions() {
  DriftOptions options;
  options.order = {"good", "degraded", "unreliable"};
  return options;
}

DriftOptions healthCauseDriftOptions() {
  DriftOptions options;
  options.order = {"none"};
  for (int bit = 0; bit < health_cause::kCount; ++bit)
    options.order.push_back(health_cause::name(static_cast<std::uint16_t>(1u << bit)));
  return options;
}

std::vector<LabelledDrift> splitLabels(const std::vector<LabelledDrift>& poses, char separator) {
  std::vector<LabelledDrift> out;
  out.reserve(poses.size());
  for (const LabelledDrift& p : poses) {
    std::size_t from = 0;
    for (;;) {
      const std::size_t to = p.label.find(separator, from);
      out.push_back({p.label.substr(from, to == std::string::npos ? std::string::npos : to - from), p.drift_m});
      if (to == std::string::npos) break;
      from = to + 1;
    }
  }
  return out;
}

namespace {

template <typename T>
std::vector<T> sortedByStamp(std::vector<T> v) {
  std::sort(v.begin(), v.end(), [](const T& a, const T& b) { return a.stamp < b.stamp; });
  return v;
}

// The element of `sorted` nearest to t within max_dt_ns (the later of two
// as near), or none.
template <typename T>
const T* nearestInTime(const std::vector<T>& sorted, Timestamp t, std::int64_t max_dt_ns) {
  const auto it =
      std::lower_bound(sorted.begin(), sorted.end(), t, [](const T& x, Timestamp s) { return x.stamp < s; });
  const T* best = nullptr;
  std::int64_t best_dt = max_dt_ns + 1;
  for (auto c : {it, it == sorted.begin() ? it : it - 1}) {
    if (c == sorted.end()) continue;
    const std::int64_t d = std::abs(c->stamp.nanoseconds() - t.nanoseconds());
    if (d < best_dt) best_dt = d, best = &*c;
  }
  return best;
}

// Every matched pose j with the pose i it drifted from: the newest pose of
// the same map at least a window back (less the association slack), if
// within two windows (a gap makes no pair).
std::vector<std::pair<std::size_t, std::size_t>> driftPairs(const EvalResult& result, const DriftOptions& options) {
  const Trajectory& est = result.est_aligned;
  const std::int64_t window_ns = secondsToNs(options.window_s), max_dt_ns = secondsToNs(options.max_dt_s);
  std::vector<std::pair<std::size_t, std::size_t>> pairs;
  for (std::size_t j = 0; j < est.size() && j < result.gt_matched.size(); ++j) {
    const std::int64_t latest = est[j].stamp.nanoseconds() - window_ns + max_dt_ns;
    for (std::size_t i = j; i-- > 0 && est[i].stamp.nanoseconds() >= est[j].stamp.nanoseconds() - 2 * window_ns;) {
      if (est[i].map_id != est[j].map_id || est[i].stamp.nanoseconds() > latest) continue;
      pairs.emplace_back(i, j);
      break;
    }
  }
  return pairs;
}

// E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j).
SE3 driftError(const EvalResult& result, std::size_t i, std::size_t j) {
  const Trajectory& est = result.est_aligned;
  const Trajectory& gt = result.gt_matched;
  return (gt[i].T_w_c.inverse() * gt[j].T_w_c).inverse() * (est[i].T_w_c.inverse() * est[j].T_w_c);
}

}  // namespace

Result<std::vector<LabelledDrift>> driftPerPose(const EvalResult& result, const std::vector<StampedLabel>& labels,
                                                const DriftOptions& options) {
  if (Status status = options.validate(); !status) return Error{status.error()};
  const auto sorted = sortedByStamp(labels);
  const std::int64_t max_dt_ns = secondsToNs(options.max_dt_s);
  std::vector<LabelledDrift> poses;
  for (const auto& [from, j] : driftPairs(result, options)) {
    const StampedLabel* label = nearestInTime(sorted, result.est_aligned[j].stamp, max_dt_ns);
    poses.push_back({label ? label->label : "-", driftError(result, from, j).translation().norm()});
  }
  return poses;
}

Result<std::vector<NormalisedDrift>> normalisedDriftPerPose(const EvalResult& result, const Trajectory& estimate,
                                                            const std::vector<StampedCovariance>& covariances,
                                                            const std::vector<StampedLabel>& labels,
                                                            const DriftOptions& options) {
  if (Status status = options.validate(); !status) return Error{status.error()};
  const auto sorted_labels = sortedByStamp(labels);
  const auto sorted = sortedByStamp(covariances);
  const std::int64_t max_dt_ns = secondsToNs(options.max_dt_s);
  const auto covarianceAt = [&](Timestamp t) -> const Eigen::Matrix<double, 6, 6>* {
    const StampedCovariance* c = nearestInTime(sorted, t, max_dt_ns);
    return c && !c->covariance.isZero() ? &c->covariance : nullptr;
  };
  // The estimate's own pose at t (what the covariance describes).
  const auto rawAt = [&](Timestamp t) -> const SE3* {
    const auto it = std::lower_bound(estimate.begin(), estimate.end(), t,
                                     [](const StampedPose& p, Timestamp s) { return p.stamp < s; });
    return it != estimate.end() && it->stamp == t ? &it->T_w_c : nullptr;
  };
  std::vector<NormalisedDrift> poses;
  for (const auto& [from, j] : driftPairs(result, options)) {
    const Timestamp t = result.est_aligned[j].stamp;
    const auto* S_i = covarianceAt(result.est_aligned[from].stamp);
    const auto* S_j = covarianceAt(t);
    const SE3* P_i = rawAt(result.est_aligned[from].stamp);
    const SE3* P_j = rawAt(t);
    if (!S_i || !S_j || !P_i || !P_j) continue;
    const SE3 error = driftError(result, from, j);
    // To first order, in the map's axes: the translation drift is
    // dc_j - dc_i + [c_j - c_i]x dr_i (pose i's turn swings the way to j),
    // the rotation drift dr_j - dr_i; camera j's axes turn both into E's.
    Eigen::Matrix<double, 3, 6> J_i;
    J_i << -Mat3::Identity(), skew(P_j->translation() - P_i->translation());
    const Mat3 R = P_j->linear();
    const Mat3 position =
        R.transpose() * (S_j->topLeftCorner<3, 3>() + J_i * *S_i * J_i.transpose()) * R;
    const Mat3 rotation = R.transpose() * (S_i->bottomRightCorner<3, 3>() + S_j->bottomRightCorner<3, 3>()) * R;
    const Vec3 d = error.translation();
    const Vec3 r = logSO3(error.linear());
    const StampedLabel* label = nearestInTime(sorted_labels, t, max_dt_ns);
    poses.push_back({label ? label->label : "-", d.dot(position.ldlt().solve(d)), r.dot(rotation.ldlt().solve(r))});
  }
  return poses;
}

std::vector<CovarianceCoverage> summariseCoverage(const std::vector<NormalisedDrift>& poses,
                                                  const DriftOptions& options) {
  constexpr double kChi2Three95 = 7.815, kChi2ThreeMedian = 2.366;
  std::map<std::string, std::vector<const NormalisedDrift*>> by_label;
  for (const NormalisedDrift& p : poses) by_label[p.label].push_back(&p);
  std::vector<std::string> names;
  for (const std::string& name : options.order)
    if (by_label.count(name) && std::find(names.begin(), names.end(), name) == names.end()) names.push_back(name);
  for (const auto& [name, members] : by_label)
    if (std::find(names.begin(), names.end(), name) == names.end()) names.push_back(name);
  for (const NormalisedDrift& p : poses) by_label["all"].push_back(&p);
  if (!poses.empty()) names.push_back("all");

  std::vector<CovarianceCoverage> out;
  for (const std::string& name : names) {
    const auto& members = by_label[name];
    CovarianceCoverage c;
    c.label = name;
    c.poses = members.size();
    std::vector<double> position, rotation;
    for (const NormalisedDrift* p : members) position.push_back(p->position), rotation.push_back(p->rotation);
    const auto within = [&](const std::vector<double>& v) {
      return static_cast<double>(std::count_if(v.begin(), v.end(), [&](double x) { return x < kChi2Three95; })) /
             static_cast<double>(v.size());
    };
    c.position_within = within(position);
    c.rotation_within = within(rotation);
    c.position_median = quantile(position, 0.5) / kChi2ThreeMedian;
    c.rotation_median = quantile(rotation, 0.5) / kChi2ThreeMedian;
    out.push_back(c);
  }
  return out;
}

std::vector<LabelDrift> summariseDrift(const std::vector<LabelledDrift>& poses, const DriftOptions& options) {
  std::map<std::string, std::vector<double>> drift;
  for (const LabelledDrift& p : poses) drift[p.label].push_back(p.drift_m);

  std::vector<std::string> names;
  for (const std::string& name : options.order)
    if (drift.count(name) && std::find(names.begin(), names.end(), name) == names.end()) names.push_back(name);
  for (const auto& [name, values] : drift)
    if (std::find(names.begin(), names.end(), name) == names.end()) names.push_back(name);

  std::vector<LabelDrift> out;
  for (const std::string& name : names) {
    const std::vector<double>& v = drift[name];
    LabelDrift d;
    d.label = name;
    d.poses = v.size();
    d.median_m = quantile(v, 0.5);
    d.p90_m = quantile(v, 0.9);
    d.max_m = *std::max_element(v.begin(), v.end());
    d.share_over_bound = static_cast<double>(std::count_if(v.begin(), v.end(), [&](double x) { return x > options.bound_m; })) /
                         static_cast<double>(v.size());
    out.push_back(d);
  }
  return out;
}

Result<std::vector<LabelDrift>> driftByLabel(const EvalResult& result, const std::vector<StampedLabel>& labels,
                                             const DriftOptions& options) {
  auto poses = driftPerPose(result, labels, options);
  if (!poses) return Error{poses.error()};
  return summariseDrift(*poses, options);
}

}  // namespace stillpoint::eval
