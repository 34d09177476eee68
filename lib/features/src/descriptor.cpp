#include "stillpoint/features/descriptor.hpp"

#include <algorithm>
#include <limits>
#include <vector>

namespace stillpoint::features {

int medianDescriptorIndex(const std::uint8_t* const* descriptors, int count) {
  if (count <= 0) return -1;
  std::vector<int> dist(static_cast<std::size_t>(count) * count, 0);
  for (int i = 0; i < count; ++i)
    for (int j = i + 1; j < count; ++j)
      dist[i * count + j] = dist[j * count + i] = hammingDistance(descriptors[i], descriptors[j]);
  int best = 0;
  int best_median = std::numeric_limits<int>::max();
  std::vector<int> row(count);
  for (int i = 0; i < count; ++i) {
    std::copy(dist.begin() + i * count, dist.begin() + (i + 1) * count, row.begin());
    std::nth_element(row.begin(), row.begin() + (count - 1) / 2, row.end());
    const int median = row[(count - 1) / 2];
    if (median < best_median) {
      best_median = median;
      best = i;
    }
  }
  return best;
}

}  // namespace stillpoint::features
