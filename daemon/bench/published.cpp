#include "bench/published.hpp"

namespace stillpoint::bench {

const std::vector<PublishedFigure>& publishedFigures() {
  // Ji, Wang and Xie (ICRA 2021) as two later papers quote its Table II (both
  // agree); ORB-SLAM2 as run by CFP-SLAM; ORB-SLAM3 as run by RLD-SLAM
  // (median of ten runs).
  static const std::string kJi = "Ji et al. 2021, as quoted in CFP-SLAM (Hu et al. 2022) Table I and RLD-SLAM "
                                 "(Zheng et al. 2024) Table I";
  static const std::string kCfp = "CFP-SLAM (Hu et al. 2022) Table I, their run";
  static const std::string kRld = "RLD-SLAM (Zheng et al. 2024) Table I, their run, median of 10";
  static const std::vector<PublishedFigure> figures = {
      {"walking_xyz", "Ji et al. (the seed paper)", 0.0194, kJi},
      {"walking_static", "Ji et al. (the seed paper)", 0.0111, kJi},
      {"walking_rpy", "Ji et al. (the seed paper)", 0.0371, kJi},
      {"walking_halfsphere", "Ji et al. (the seed paper)", 0.0290, kJi},
      {"sitting_xyz", "Ji et al. (the seed paper)", 0.0117, kJi},
      {"sitting_halfsphere", "Ji et al. (the seed paper)", 0.0172, kJi},
      {"walking_xyz", "ORB-SLAM2", 0.7214, kCfp},
      {"walking_static", "ORB-SLAM2", 0.3872, kCfp},
      {"walking_halfsphere", "ORB-SLAM2", 0.4667, kCfp},
      {"walking_rpy", "ORB-SLAM2", 0.7842, kCfp},
      {"sitting_static", "ORB-SLAM2", 0.0087, kCfp},
      {"sitting_xyz", "ORB-SLAM2", 0.0092, kCfp},
      {"sitting_halfsphere", "ORB-SLAM2", 0.0192, kCfp},
      {"sitting_rpy", "ORB-SLAM2", 0.0195, kCfp},
      {"walking_xyz", "ORB-SLAM3", 0.5212, kRld},
      {"walking_static", "ORB-SLAM3", 0.0277, kRld},
      {"walking_rpy", "ORB-SLAM3", 0.9902, kRld},
      {"walking_halfsphere", "ORB-SLAM3", 0.6418, kRld},
  };
  return figures;
}

}  // namespace stillpoint::bench
