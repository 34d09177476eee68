#pragma once
// Decides which depth clusters move: each cluster's matched features are
// scored by a robust penalty of their reprojection error under the frame's
// initial pose; clusters scoring well above the frame's typical cluster are
// dynamic.
#include <vector>

#include "stillpoint/core/result.hpp"

namespace stillpoint::geometry {

struct DynamicClusterOptions {
  // rho(s) = min(s, rho_cap) (truncated quadratic) of the squared,
  // sigma-normalised reprojection error s. A cluster's mean rho is then about
  // rho_cap x (share of its features that disagree with the pose) plus the
  // static noise (s follows a chi-square law with 3 DoF, mean 3): a mover
  // scores near rho_cap, while mismatches (7-10 % of stage-1 matches on
  // repetitive texture) cannot lift a static cluster. Measured against a
  // Cauchy rho on three generated sequences it gives higher precision at
  // every recall (docs/dynamic-objects.md).
  double rho_cap = 7.815;  // chi-square 95 % at 3 DoF (u, v, depth)
  // Clusters with fewer matched features are not judged (stay static).
  int min_features = 4;
  // Dynamic when mean rho > clamp(relative_factor * reference, absolute_floor,
  // ceiling_fraction * rho_cap),
  // reference = this quantile of the judged clusters' mean rho. A low
  // quantile keeps the reference static even when movers fill half the view.
  double reference_quantile = 0.3;
  double relative_factor = 2.5;
  double absolute_floor = 4.5;
  // ...and the relative rule never asks more than this share of rho_cap (a
  // noisy frame would otherwise push the threshold above what any cluster
  // can score).
  double ceiling_fraction = 0.75;
  // Memory: a cluster most of whose judged features were on a moving surface
  // in an earlier frame (inherited) stays dynamic while its mean rho is above
  // max(hold_floor, hold_factor * reference). A mover slowing down, turning
  // or seen edge-on still shows some error, but less than a fresh one.
  double hold_fraction = 0.5;
  double hold_factor = 1.5;
  double hold_floor = 3.0;
  Status validate() const;
};

struct FeatureResidual {
  int cluster = -1;  // < 0: no cluster (not counted)
  double chi2 = 0;   // squared reprojection error / sigma^2 of the keypoint's level
  bool inherited = false;  // the feature it was matched to lay in a dynamic cluster
};

struct ClusterScore {
  int features = 0;
  int inherited = 0;
  double mean_rho = 0;
  bool judged = false;   // enough features to decide
  bool dynamic = false;
};

struct ClusterVerdict {
  std::vector<ClusterScore> clusters;
  double reference = 0;  // the reference mean rho of this frame
  double threshold = 0;  // mean rho above which a judged cluster is dynamic
  double hold_threshold = 0;  // ... or, for a mostly inherited cluster, above this
  int dynamic_clusters = 0;
};

double truncatedRho(double chi2, double cap);

ClusterVerdict classifyClusters(const std::vector<FeatureResidual>& residuals, int clusters,
                                const DynamicClusterOptions& options);

}  // namespace stillpoint::geometry
