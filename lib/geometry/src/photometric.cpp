#include "stillpoint/geometry/photometric.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

namespace stillpoint::geometry {

bool photoAgreement(const PatchSite& site, const cv::Mat& gray, const cv::Mat& depth, const SeenView& view,
                    const CameraModel& camera, const PatchTest& test, PhotoAgreement* out) {
  if (!view.gray || !view.depth) return false;
  const cv::Mat& seen_gray = *view.gray;
  const cv::Mat& seen_depth = *view.depth;
  if (seen_gray.empty() || seen_depth.empty() || gray.empty()) return false;
  const int r = test.radius;
  const int x0 = static_cast<int>(std::lround(site.keypoint.x));
  const int y0 = static_cast<int>(std::lround(site.keypoint.y));
  if (x0 - r < 0 || y0 - r < 0 || x0 + r >= gray.cols || y0 + r >= gray.rows) return false;
  const Mat3 R = view.T_seen_current.linear();
  const Vec3 t = view.T_seen_current.translation();
  const bool distorted = camera.hasDistortion();
  const int n = (2 * r + 1) * (2 * r + 1);
  const auto sample = [&](double qx, double qy) {  // bilinear, in the image (first pass)
    const int ix = static_cast<int>(qx), iy = static_cast<int>(qy);
    const double fx = qx - ix, fy = qy - iy;
    const std::uint8_t* row0 = seen_gray.ptr<std::uint8_t>(iy);
    const std::uint8_t* row1 = seen_gray.ptr<std::uint8_t>(iy + 1);
    return (1 - fy) * ((1 - fx) * row0[ix] + fx * row0[ix + 1]) + fy * ((1 - fx) * row1[ix] + fx * row1[ix + 1]);
  };
  // Two passes. The first warps the patch and checks its depth: most dropped
  // features are movers whose depth disagrees there, and once more pixels
  // disagree than the depth share allows, the patch has failed
  // whatever its intensities; only whether it stays in the image is still
  // needed (a patch that leaves it is untestable, and tested nearer). The
  // second pass samples the intensities of a patch whose depth agrees.
  constexpr int kMaxPatch = 31 * 31;  // the radius is at most 15
  std::array<double, kMaxPatch> qx, qy;
  const int may_disagree = n - static_cast<int>(std::ceil(test.depth_share * n - 1e-9));
  // The patch's rows lie on as many cache lines, mostly cold: all are
  // fetched at once (the seen frame's below, once the warp places them).
  for (int y = y0 - r; y <= y0 + r; ++y) {
    if (!depth.empty()) {
      __builtin_prefetch(depth.ptr<float>(y) + x0 - r);
      __builtin_prefetch(depth.ptr<float>(y) + x0 + r);
    }
    __builtin_prefetch(gray.ptr<std::uint8_t>(y) + x0);
  }
  // The patch's depths, read once. A pixel without depth takes the
  // keypoint's: the patch is small.
  std::array<float, kMaxPatch> patch_z;
  float z_near = site.depth, z_far = site.depth;
  for (int y = y0 - r, k = 0; y <= y0 + r; ++y) {
    const float* depth_row = depth.empty() ? nullptr : depth.ptr<float>(y);
    for (int x = x0 - r; x <= x0 + r; ++x, ++k) {
      const float z = depth_row ? depth_row[x] : 0.0f;
      patch_z[k] = z > camera.min_depth && z < camera.max_depth ? z : site.depth;
      z_near = std::min(z_near, patch_z[k]), z_far = std::max(z_far, patch_z[k]);
    }
  }
  // In the image with a bilinear neighbourhood (the second pass samples it).
  const auto inImage = [&](const Vec2& q, double margin) {
    return q.x() >= margin && q.y() >= margin && q.x() < seen_gray.cols - 1 - margin &&
           q.y() < seen_gray.rows - 1 - margin;
  };
  // Whether the whole patch provably stays in front of the seen camera and
  // in its image, without warping each pixel: the patch's rays between its
  // nearest and farthest depth fill a truncated pyramid, whose image under a
  // pinhole camera lies inside the hull of its 8 corners' images. Then the
  // first pass may stop as soon as the depth has failed (the result is the
  // same as warping every pixel); a camera with distortion warps them all.
  bool stays_in = !distorted;
  for (int corner = 0; corner < 8 && stays_in; ++corner) {
    const Vec2 uv(corner & 1 ? x0 + r : x0 - r, corner & 2 ? y0 + r : y0 - r);
    const Vec3 p = R * camera.unproject(uv, corner & 4 ? z_far : z_near) + t;
    stays_in = p.z() > camera.min_depth && inImage(camera.project(p), 0.01);
  }
  // Without distortion the warp is linear in the pixel before the division:
  // p = z * (a + x * b + y * c) + t, one reciprocal per pixel.
  const Vec3 b = R.col(0) / camera.fx, c = R.col(1) / camera.fy;
  const Vec3 a = R.col(2) - camera.cx * b - camera.cy * c;
  // Pixel (x, y) at depth z in the seen camera (p) and image (q); false
  // when behind it.
  const auto warp = [&](int x, int y, double z, Vec3* p, Vec2* q) {
    if (distorted) {
      *p = R * camera.unproject(camera.undistortPixel(Vec2(x, y)), z) + t;
      if (p->z() <= camera.min_depth) return false;
      *q = camera.distortPixel(camera.project(*p));
      return true;
    }
    *p = z * (a + x * b + y * c) + t;
    if (p->z() <= camera.min_depth) return false;
    const double inv_z = 1.0 / p->z();
    *q = Vec2(camera.fx * p->x() * inv_z + camera.cx, camera.fy * p->y() * inv_z + camera.cy);
    return true;
  };
  // The seen frame's images are cold (several frames back), and each patch
  // row lands on other cache lines: their loads are issued together first
  // rather than one row's miss after another's.
  for (int y = y0 - r, k = r; y <= y0 + r; ++y, k += 2 * r + 1) {
    Vec3 p;
    Vec2 q;
    if (!warp(x0, y, patch_z[k], &p, &q) || !inImage(q, r + 1.0)) continue;
    const int qx = static_cast<int>(q.x()), qy = static_cast<int>(q.y());
    __builtin_prefetch(seen_depth.ptr<float>(qy) + qx - r);
    __builtin_prefetch(seen_depth.ptr<float>(qy) + qx + r);
    __builtin_prefetch(seen_gray.ptr<std::uint8_t>(qy) + qx);
    __builtin_prefetch(seen_gray.ptr<std::uint8_t>(qy + 1) + qx);
  }
  int agree = 0, k = 0;
  for (int y = y0 - r; y <= y0 + r; ++y) {
    for (int x = x0 - r; x <= x0 + r; ++x, ++k) {
      const float z = patch_z[k];
      Vec3 p;
      Vec2 q;
      if (!warp(x, y, z, &p, &q) || !inImage(q, 0.0)) return false;
      qx[k] = q.x(), qy[k] = q.y();
      const float zs = seen_depth.at<float>(static_cast<int>(q.y() + 0.5), static_cast<int>(q.x() + 0.5));
      agree += zs > camera.min_depth && std::abs(zs - p.z()) < test.tolerance.at(p.z());
      if (stays_in && k + 1 - agree > may_disagree) {
        // Failed on depth; the share reported is at least the final one,
        // and already below the depth share.
        out->depth_share = static_cast<double>(n - (k + 1 - agree)) / n;
        out->ncc = -1;
        return true;
      }
    }
  }
  out->depth_share = static_cast<double>(agree) / n;
  out->ncc = -1;
  if (n - agree > may_disagree) return true;
  double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
  k = 0;
  for (int y = y0 - r; y <= y0 + r; ++y) {
    const std::uint8_t* gray_row = gray.ptr<std::uint8_t>(y);
    for (int x = x0 - r; x <= x0 + r; ++x, ++k) {
      const double a = gray_row[x], b = sample(qx[k], qy[k]);
      sa += a, sb += b, saa += a * a, sbb += b * b, sab += a * b;
    }
  }
  const double va = saa - sa * sa / n, vb = sbb - sb * sb / n;
  if (va > 1e-6 && vb > 1e-6) out->ncc = (sab - sa * sb / n) / std::sqrt(va * vb);
  return true;
}

void PhotoVote::add(double ncc) {
  if (ncc < worst_) {
    second_ = worst_;
    worst_ = ncc;
  } else if (ncc < second_) {
    second_ = ncc;
  }
  ++frames_;
}

}  // namespace stillpoint::geometry
