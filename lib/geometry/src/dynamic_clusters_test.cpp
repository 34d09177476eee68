#include "stillpoint/geometry/dynamic_clusters.hpp"

#include <gtest/gtest.h>

#include <algorithm>
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

// A cluster for splitCluster(): `n_static` features with static errors on a
// 30 x 30 cm patch centred at x = -0.2 m, 1.2 m away, and `n_moving` displaced
// by `pixels` on one at x = +0.2 m (a teddy bear beside the person who hides
// it, at the same depth).
std::vector<SplitFeature> twoObjects(int n_static, int n_moving, double pixels, std::mt19937* rng) {
  std::vector<SplitFeature> out;
  std::uniform_real_distribution<double> spread(-0.15, 0.15);
  std::vector<FeatureResidual> r;
  addStatic(&r, 0, n_static, rng);
  addMoving(&r, 1, n_moving, pixels, rng);
  for (const FeatureResidual& f : r) {
    const double x = f.cluster == 0 ? -0.2 : 0.2;
    out.push_back({Vec3(x + spread(*rng), spread(*rng), 1.2 + 0.2 * spread(*rng)), f.chi2, false});
  }
  return out;
}

// The verdict of a frame of static clusters (its threshold the ceiling, 5.9).
ClusterVerdict frameVerdict() {
  std::mt19937 rng(1);
  std::vector<FeatureResidual> r;
  for (int j = 0; j < 10; ++j) addStatic(&r, j, 30, &rng);
  return classifyClusters(r, 10, {});
}

TEST(DynamicClusters, SplitGivesBackTheStaticHalf) {
  std::mt19937 rng(3);
  const ClusterVerdict verdict = frameVerdict();
  std::vector<SplitFeature> f = twoObjects(20, 30, 5.0, &rng);
  f[0].chi2 = -1;       // a static feature without evidence
  f[1].moving = true;   // one matched to a feature seen moving
  f[2].chi2 = 30;       // one whose own evidence disagrees
  const ClusterSplit split = splitCluster(f, verdict, {}, 7.815);
  ASSERT_GE(split.static_half, 0);
  EXPECT_LE(split.static_rho, verdict.hold_threshold);
  EXPECT_GT(split.moving_rho, verdict.threshold);
  int released_static = 0, released_moving = 0;
  for (std::size_t k = 0; k < f.size(); ++k) {
    EXPECT_EQ(split.half[k] == split.static_half, k < 20) << "feature " << k;
    (k < 20 ? released_static : released_moving) += split.released[k];
  }
  EXPECT_FALSE(split.released[0]);
  EXPECT_FALSE(split.released[1]);
  EXPECT_FALSE(split.released[2]);
  EXPECT_GE(released_static, 15);
  EXPECT_EQ(released_moving, 0);
}

TEST(DynamicClusters, SplitKeepsAClusterThatMovesAsAWhole) {
  // Both halves move: one object, nothing given back.
  std::mt19937 rng(4);
  const ClusterVerdict verdict = frameVerdict();
  std::vector<SplitFeature> f = twoObjects(0, 50, 5.0, &rng);
  for (std::size_t k = 0; k < f.size(); k += 2) f[k].position.x() -= 0.4;
  const ClusterSplit split = splitCluster(f, verdict, {}, 7.815);
  EXPECT_EQ(split.static_half, -1);
  EXPECT_EQ(std::count(split.released.begin(), split.released.end(), 1), 0);
}

TEST(DynamicClusters, SplitKeepsAHalfKnownToMove) {
  // The still half was seen moving before (a person who stopped beside one
  // who walks on): the cluster's memory holds it, as it holds a cluster.
  std::mt19937 rng(5);
  const ClusterVerdict verdict = frameVerdict();
  std::vector<SplitFeature> f = twoObjects(20, 30, 5.0, &rng);
  for (int k = 0; k < 12; ++k) f[k].moving = true;
  EXPECT_EQ(splitCluster(f, verdict, {}, 7.815).static_half, -1);
  for (int k = 0; k < 8; ++k) f[k].moving = false;  // 4 of 20: a minority
  EXPECT_GE(splitCluster(f, verdict, {}, 7.815).static_half, 0);
}

TEST(DynamicClusters, SplitNeedsEvidenceOnBothHalves) {
  std::mt19937 rng(6);
  const ClusterVerdict verdict = frameVerdict();
  std::vector<SplitFeature> f = twoObjects(20, 30, 5.0, &rng);
  for (int k = 0; k < 17; ++k) f[k].chi2 = -1;  // 3 judged on the static half
  EXPECT_EQ(splitCluster(f, verdict, {}, 7.815).static_half, -1);
  const std::vector<SplitFeature> small = twoObjects(6, 9, 5.0, &rng);  // fewer than 4 x min_features
  const ClusterSplit split = splitCluster(small, verdict, {}, 7.815);
  EXPECT_EQ(split.static_half, -1);
  EXPECT_EQ(split.released.size(), small.size());
  EXPECT_TRUE(splitCluster({}, verdict, {}, 7.815).released.empty());
}

}  // namespace
}  // namespace stillpoint::geometry
