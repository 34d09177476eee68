#include "stillpoint/geometry/dynamic_clusters.hpp"

#include <gtest/gtest.h>

#include <random>

namespace stillpoint::geometry {
namespace {

// Static features: sigma-normalised errors of a well-estimated pose follow a
// chi-square law with 3 degrees of freedom.
void addStatic(std::vector<FeatureResidual>* out, int cluster, int n, std::mt19937* rng) {
  std::chi_squared_distribution<double> chi2(3.0);
  for (int i = 0; i < n; ++i) out->push_back({cluster, chi2(*rng)});
}

// Moving features: displaced by `pixels` (sigma 1) plus noise.
void addMoving(std::vector<FeatureResidual>* out, int cluster, int n, double pixels, std::mt19937* rng) {
  std::normal_distribution<double> noise(0.0, 1.0);
  for (int i = 0; i < n; ++i) {
    const double du = pixels + noise(*rng), dv = noise(*rng), dz = noise(*rng);
    out->push_back({cluster, du * du + dv * dv + dz * dz});
  }
}

TEST(DynamicClusters, AllStaticFlagsNothing) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 50; ++trial) {
    std::vector<FeatureResidual> r;
    for (int j = 0; j < 24; ++j) addStatic(&r, j, 5 + (j * 7) % 40, &rng);
    const ClusterVerdict v = classifyClusters(r, 24, {});
    EXPECT_EQ(v.dynamic_clusters, 0) << "trial " << trial << " threshold " << v.threshold;
  }
}

TEST(DynamicClusters, OneMovingClusterIsFlagged) {
  std::mt19937 rng(11);
  std::vector<FeatureResidual> r;
  for (int j = 0; j < 24; ++j) {
    if (j == 5)
      addMoving(&r, j, 20, 6.0, &rng);
    else
      addStatic(&r, j, 30, &rng);
  }
  const ClusterVerdict v = classifyClusters(r, 24, {});
  EXPECT_EQ(v.dynamic_clusters, 1);
  EXPECT_TRUE(v.clusters[5].dynamic);
  EXPECT_GT(v.clusters[5].mean_rho, v.threshold);
}

TEST(DynamicClusters, MemoryHoldsASlowingMoverOnly) {
  // A mover slowing down (1.7 px of error: a mean rho between the static
  // level and the fresh-mover threshold) stays dynamic while its features
  // were dynamic before; the same cluster without that history does not, and
  // a formerly dynamic cluster that now looks static is released.
  std::mt19937 rng(5);
  std::vector<FeatureResidual> r;
  for (int j = 0; j < 24; ++j) {
    if (j == 3 || j == 4)
      addMoving(&r, j, 30, 1.7, &rng);
    else
      addStatic(&r, j, 30, &rng);
  }
  for (FeatureResidual& f : r) f.inherited = f.cluster == 3 || f.cluster == 7;
  const ClusterVerdict v = classifyClusters(r, 24, {});
  EXPECT_LT(v.clusters[3].mean_rho, v.threshold);
  EXPECT_GT(v.clusters[3].mean_rho, v.hold_threshold);
  EXPECT_TRUE(v.clusters[3].dynamic);   // moving a little, and known to move
  EXPECT_FALSE(v.clusters[4].dynamic);  // moving a little, no history
  EXPECT_FALSE(v.clusters[7].dynamic);  // history, but static now
  EXPECT_EQ(v.dynamic_clusters, 1);
}

TEST(DynamicClusters, MoverCoveringHalfTheImage) {
  std::mt19937 rng(3);
  std::vector<FeatureResidual> r;
  for (int j = 0; j < 24; ++j) {
    if (j % 2)
      addMoving(&r, j, 25, 5.0, &rng);
    else
      addStatic(&r, j, 25, &rng);
  }
  const ClusterVerdict v = classifyClusters(r, 24, {});
  EXPECT_EQ(v.dynamic_clusters, 12);
  for (int j = 0; j < 24; ++j) EXPECT_EQ(v.clusters[j].dynamic, j % 2 == 1) << "cluster " << j;
}

TEST(DynamicClusters, ClustersWithTooFewFeaturesAreNotJudged) {
  std::mt19937 rng(5);
  std::vector<FeatureResidual> r;
  for (int j = 0; j < 10; ++j) addStatic(&r, j, 20, &rng);
  addMoving(&r, 10, 3, 20.0, &rng);  // below min_features
  r.push_back({-1, 1e6});            // unclustered: ignored
  r.push_back({99, 1e6});            // out of range: ignored
  const ClusterVerdict v = classifyClusters(r, 12, {});
  EXPECT_FALSE(v.clusters[10].judged);
  EXPECT_FALSE(v.clusters[10].dynamic);
  EXPECT_EQ(v.clusters[11].features, 0);
  EXPECT_EQ(v.dynamic_clusters, 0);
}

TEST(DynamicClusters, NothingToJudge) {
  const ClusterVerdict v = classifyClusters({}, 24, {});
  EXPECT_EQ(v.dynamic_clusters, 0);
  EXPECT_EQ(v.clusters.size(), 24u);
  EXPECT_TRUE(classifyClusters({{0, 1.0}}, 0, {}).clusters.empty());
}

TEST(DynamicClusters, MismatchesDoNotMakeAStaticClusterDynamic) {
  // 10 % gross mismatches in every cluster (repetitive texture): no flags.
  std::mt19937 rng(9);
  std::vector<FeatureResidual> r;
  for (int j = 0; j < 24; ++j) {
    addStatic(&r, j, 18, &rng);
    r.push_back({j, 400.0});
    r.push_back({j, 90.0});
  }
  EXPECT_EQ(classifyClusters(r, 24, {}).dynamic_clusters, 0);
}

TEST(DynamicClusters, RhoIsBoundedAndMonotonic) {
  EXPECT_DOUBLE_EQ(truncatedRho(0, 7.815), 0);
  EXPECT_DOUBLE_EQ(truncatedRho(2.0, 7.815), 2.0);  // the squared error itself below the cap
  EXPECT_LE(truncatedRho(5, 7.815), truncatedRho(50, 7.815));
  EXPECT_DOUBLE_EQ(truncatedRho(1e6, 7.815), 7.815);
  DynamicClusterOptions o;
  o.relative_factor = 0.5;
  EXPECT_FALSE(o.validate());
}

}  // namespace
}  // namespace stillpoint::geometry
