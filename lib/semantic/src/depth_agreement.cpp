#include "stillpoint/semantic/depth_agreement.hpp"

#include <algorithm>
#include <cmath>

namespace stillpoint::semantic {

Result<std::vector<InstanceDepth>> applyDepthAgreement(const cv::Mat& depth, const DepthAgreementOptions& options,
                                                       Segmentation* seg) {
  if (depth.empty() || (depth.type() != CV_16U && depth.type() != CV_32F))
    return Error{"depth agreement: depth must be a CV_16U or CV_32F image"};
  if (depth.size() != seg->movable_mask.size())
    return Error{"depth agreement: depth is " + std::to_string(depth.cols) + "x" + std::to_string(depth.rows) +
                 ", the segmentation " + std::to_string(seg->movable_mask.cols) + "x" +
                 std::to_string(seg->movable_mask.rows)};
  if (!(options.depth_scale > 0) || options.abs_tolerance_m < 0 || options.rel_tolerance < 0)
    return Error{"depth agreement: depth_scale must be positive and tolerances non-negative"};
  cv::Mat metres;
  if (depth.type() == CV_16U)
    depth.convertTo(metres, CV_32F, options.depth_scale);
  else
    metres = depth;

  std::vector<InstanceDepth> out(seg->instances.size());
  std::vector<float> values;
  for (std::size_t k = 0; k < seg->instances.size(); ++k) {
    Instance& inst = seg->instances[k];
    if (!inst.movable || !inst.kept || inst.area == 0) continue;
    const cv::Mat z = metres(inst.box);
    values.clear();
    for (int y = 0; y < z.rows; ++y) {
      const float* zr = z.ptr<float>(y);
      const uchar* m = inst.mask.ptr<uchar>(y);
      for (int x = 0; x < z.cols; ++x)
        if (m[x] && zr[x] > 0 && std::isfinite(zr[x])) values.push_back(zr[x]);
    }
    out[k].depth_pixels = int(values.size());
    if (values.empty() || out[k].depth_pixels < options.min_depth_pixels) continue;
    std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
    const float median = values[values.size() / 2];
    out[k].median_m = median;
    const float tolerance = float(options.abs_tolerance_m + options.rel_tolerance * median);
    for (int y = 0; y < z.rows; ++y) {
      const float* zr = z.ptr<float>(y);
      uchar* m = inst.mask.ptr<uchar>(y);
      for (int x = 0; x < z.cols; ++x) {
        if (m[x] && zr[x] > 0 && std::isfinite(zr[x]) && std::abs(zr[x] - median) > tolerance) {
          m[x] = 0;
          ++out[k].removed_pixels;
        }
      }
    }
    inst.area -= out[k].removed_pixels;
  }
  seg->movable_mask.setTo(0);
  for (const Instance& inst : seg->instances)
    if (inst.movable && inst.kept && inst.area > 0) seg->movable_mask(inst.box).setTo(255, inst.mask);
  seg->movable_pixels = cv::countNonZero(seg->movable_mask);
  return out;
}

}  // namespace stillpoint::semantic
