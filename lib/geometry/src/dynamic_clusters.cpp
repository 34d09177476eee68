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

}  // namespace stillpoint::geometry
