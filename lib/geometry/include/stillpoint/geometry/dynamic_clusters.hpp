#pragma once
// Decides which depth clusters move: each cluster's matched features are
// scored by a robust penalty of their reprojection error under the frame's
// initial pose; clusters scoring well above the frame's typical cluster are
// dynamic.
#include <vector>

#include "stillpoint/core/result.hpp"

namespace stillpoint::geometry {

struct DynamicClusterOptions {
  // rho(s) = c^2 log(1 + s / c^2) (Cauchy) of the squared, sigma-normalised
  // reprojection error s. Bounded growth: one gross mismatch cannot make a
  // static cluster dynamic, yet a cluster whose every feature is off by a few
  // sigma scores clearly above static ones (whose s follows a chi-square law).
  double cauchy_c2 = 7.815;  // chi-square 95 % at 3 DoF (u, v, depth)
  // Clusters with fewer matched features are not judged (stay static).
  int min_features = 4;
  // Dynamic when mean rho > max(absolute_floor, relative_factor * reference),
  // reference = this quantile of the judged clusters' mean rho. A low
  // quantile keeps the reference static even when movers fill half the view.
  double reference_quantile = 0.3;
  double relative_factor = 2.5;
  double absolute_floor = 4.0;
  Status validate() const;
};

struct FeatureResidual {
  int cluster = -1;  // < 0: no cluster (not counted)
  double chi2 = 0;   // squared reprojection error / sigma^2 of the keypoint's level
};

struct ClusterScore {
  int features = 0;
  double mean_rho = 0;
  bool judged = false;   // enough features to decide
  bool dynamic = false;
};

struct ClusterVerdict {
  std::vector<ClusterScore> clusters;
  double reference = 0;  // the reference mean rho of this frame
  double threshold = 0;  // mean rho above which a judged cluster is dynamic
  int dynamic_clusters = 0;
};

double cauchyRho(double chi2, double c2);

ClusterVerdict classifyClusters(const std::vector<FeatureResidual>& residuals, int clusters,
                                const DynamicClusterOptions& options);

}  // namespace stillpoint::geometry
