#include "stillpoint/features/descriptor.hpp"

#include <gtest/gtest.h>

#include <random>
#include <vector>

namespace stillpoint::features {
namespace {

// The vector path takes eight descriptors at a time and the rest one by
// one: every count up to a few blocks, from every alignment of a cache line
// (descriptors are compared where they lie in `storage`; each count is also
// run on an exact copy), must give hammingDistance's numbers, the extremes
// (0 and 256) included.
TEST(HammingDistances, EqualTheOneByOneDistanceAtAnyCountAndAlignment) {
  RecordProperty("path", hammingDistancesPath());
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> byte(0, 255);
  constexpr int kMax = 41;
  std::vector<std::uint8_t> storage((kMax + 2) * kDescriptorBytes + 64);
  std::vector<std::uint8_t> query(kDescriptorBytes);
  for (auto& b : storage) b = static_cast<std::uint8_t>(byte(rng));
  for (auto& b : query) b = static_cast<std::uint8_t>(byte(rng));
  std::vector<int> out(kMax), scalar(kMax), copied(kMax);
  for (int offset = 0; offset < 64; ++offset) {
    std::uint8_t* descriptors = storage.data() + offset;
    // The same descriptor as the query and its complement, at varying places.
    const int same = offset % kMax, opposite = (same + 1 + offset % 5) % kMax;
    for (int b = 0; b < kDescriptorBytes; ++b) {
      descriptors[same * kDescriptorBytes + b] = query[b];
      descriptors[opposite * kDescriptorBytes + b] = static_cast<std::uint8_t>(~query[b]);
    }
    for (int count = 0; count <= kMax; ++count) {
      // In a buffer that ends with the last descriptor, so that a read past
      // it meets AddressSanitizer's red zone in the asan build.
      std::vector<std::uint8_t> exact(descriptors, descriptors + count * kDescriptorBytes);
      hammingDistances(query.data(), exact.data(), count, copied.data());
      out.assign(kMax, -1);
      hammingDistances(query.data(), descriptors, count, out.data());
      for (int k = 0; k < count; ++k) {
        ASSERT_EQ(out[k], hammingDistance(query.data(), descriptors + k * kDescriptorBytes))
            << "offset " << offset << " count " << count << " k " << k;
        ASSERT_EQ(copied[k], out[k]) << "count " << count << " k " << k;
      }
      for (int k = count; k < kMax; ++k) ASSERT_EQ(out[k], -1) << "wrote past count " << count;
      hammingDistancesScalar(query.data(), descriptors, count, scalar.data());
      for (int k = 0; k < count; ++k) ASSERT_EQ(out[k], scalar[k]);
    }
    EXPECT_EQ(out[same], 0);
    EXPECT_EQ(out[opposite], 256);
  }
}

}  // namespace
}  // namespace stillpoint::features
