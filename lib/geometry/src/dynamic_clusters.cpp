#include "stillpoint/geometry/dynamic_clusters.hpp"

#include <algorithm>
#include <cmath>

namespace stillpoint::geometry {

Status DynamicClusterOptions::validate() const {
  if (!(rho_cap > 0)) return Error{"geometry.rho_cap must be > 0"};
  if (min_features < 1) return Error{"geometry.min_features must be >= 1"};
  if (!(reference_quantile >= 0 && reference_quantile <= 1))
    return Error{"geometry.reference_quantile must be in [0, 1]"};
  if (!(relative_factor >= 1)) return Error{"geometry.relative_factor must be >= 1"};
  if (!(absolute_floor >= 0)) return Error{"geometry.absolute_floor must be >= 0"};
  if (!(ceiling_fraction > 0 && ceiling_fraction <= 1)) return Error{"geometry.ceiling_fraction must be in (0, 1]"};
  if (!(hold_fraction > 0 && hold_fraction <= 1)) return Error{"geometry.hold_fraction must be in (0, 1] (1: all)"};
  if (!(hold_factor >= 1)) return Error{"geometry.hold_factor must be >= 1"};
  if (!(hold_floor >= 0)) return Error{"geometry.hold_floor must be >= 0"};
  return Status::success();
}

double truncatedRho(double chi2, double cap) { return std::min(chi2, cap); }

ClusterVerdict classifyClusters(const std::vector<FeatureResidual>& residuals, int clusters,
                                const DynamicClusterOptions& options) {
  ClusterVerdict verdict;
  verdict.clusters.assign(std::max(0, clusters), {});
  // The sums run in the order of `residuals`, as the mean is defined.
  std::vector<double> sums(verdict.clusters.size(), 0.0);
  for (const FeatureResidual& r : residuals) {
    if (r.cluster < 0 || r.cluster >= clusters) continue;
    ClusterScore& c = verdict.clusters[r.cluster];
    ++c.features;
    c.inherited += r.inherited;
    sums[r.cluster] += truncatedRho(r.chi2, options.rho_cap);
  }
  std::vector<double> judged;
  for (std::size_t k = 0; k < verdict.clusters.size(); ++k) {
    ClusterScore& c = verdict.clusters[k];
    c.mean_rho = c.features > 0 ? sums[k] / c.features : 0.0;
    c.judged = c.features >= options.min_features;
    if (c.judged) judged.push_back(c.mean_rho);
  }
  if (judged.empty()) return verdict;
  std::sort(judged.begin(), judged.end());
  const auto q = static_cast<std::size_t>(std::floor(options.reference_quantile * (judged.size() - 1) + 0.5));
  verdict.reference = judged[q];
  verdict.threshold = std::min(std::max(options.absolute_floor, options.relative_factor * verdict.reference),
                               std::max(options.absolute_floor, options.ceiling_fraction * options.rho_cap));
  verdict.hold_threshold =
      std::min(verdict.threshold, std::max(options.hold_floor, options.hold_factor * verdict.reference));
  for (ClusterScore& c : verdict.clusters) {
    const bool held = c.inherited >= options.hold_fraction * c.features && c.mean_rho > verdict.hold_threshold;
    c.dynamic = c.judged && (c.mean_rho > verdict.threshold || held);
    verdict.dynamic_clusters += c.dynamic;
  }
  return verdict;
}

ClusterSplit splitCluster(const std::vector<SplitFeature>& features, const ClusterVerdict& verdict,
                          const DynamicClusterOptions& options, double protect_chi2) {
  ClusterSplit out;
  const std::size_t n = features.size();
  out.released.assign(n, 0);
  out.half.assign(n, 0);
  if (static_cast<int>(n) < 4 * options.min_features) return out;
  Vec3 mean = Vec3::Zero();
  for (const SplitFeature& f : features) mean += f.position;
  mean /= static_cast<double>(n);
  const auto farthest = [&](const Vec3& from) {
    std::size_t best = 0;
    for (std::size_t k = 1; k < n; ++k)
      if ((features[k].position - from).squaredNorm() > (features[best].position - from).squaredNorm()) best = k;
    return features[best].position;
  };
  Vec3 centre[2];
  centre[0] = farthest(mean);
  centre[1] = farthest(centre[0]);
  std::vector<std::uint8_t>& half = out.half;
  for (int iteration = 0; iteration < 10; ++iteration) {
    Vec3 sum[2] = {Vec3::Zero(), Vec3::Zero()};
    int count[2] = {0, 0};
    for (std::size_t k = 0; k < n; ++k) {
      const Vec3& p = features[k].position;
      half[k] = (p - centre[1]).squaredNorm() < (p - centre[0]).squaredNorm();
      sum[half[k]] += p;
      ++count[half[k]];
    }
    if (count[0] == 0 || count[1] == 0) return out;
    centre[0] = sum[0] / count[0];
    centre[1] = sum[1] / count[1];
  }
  double rho[2] = {0, 0};
  int judged[2] = {0, 0}, moving[2] = {0, 0};
  for (std::size_t k = 0; k < n; ++k) {
    const SplitFeature& f = features[k];
    moving[half[k]] += f.moving;
    if (f.chi2 < 0) continue;
    const double r = truncatedRho(f.chi2, options.rho_cap);
    rho[half[k]] += r;
    ++judged[half[k]];
  }
  for (int h = 0; h < 2; ++h) {
    const int o = 1 - h;
    if (judged[h] < options.min_features || judged[o] < options.min_features) continue;
    const double mean_h = rho[h] / judged[h], mean_o = rho[o] / judged[o];
    if (mean_h > std::min(verdict.hold_threshold, options.absolute_floor) || mean_o <= verdict.threshold) continue;
    if (moving[h] >= options.hold_fraction * judged[h]) continue;
    out.static_half = h;
    out.static_rho = mean_h;
    out.moving_rho = mean_o;
    for (std::size_t k = 0; k < n; ++k)
      out.released[k] = half[k] == h && !features[k].moving && features[k].chi2 >= 0 && features[k].chi2 <= protect_chi2;
    break;
  }
  return out;
}

}  // namespace stillpoint::geometry
