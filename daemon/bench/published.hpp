#pragma once
// Published ATE figures of other systems on the TUM RGB-D dynamic sequences,
// shown beside stillpoint-bench's own results and labelled as published
// figures on other hardware. Each names where it was read.
#include <string>
#include <vector>

namespace stillpoint::bench {

struct PublishedFigure {
  std::string sequence_key;  // matched against the sequence folder's name
  std::string system;
  double ate_m = 0;  // ATE RMSE, metres
  std::string source;
};

const std::vector<PublishedFigure>& publishedFigures();

}  // namespace stillpoint::bench
