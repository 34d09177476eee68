#include "stillpoint/synth/raster.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <opencv2/imgproc.hpp>

namespace stillpoint::synth {
namespace {

struct ClipVertex {
  Vec3 c;   // camera coordinates
  Vec2 uv;
};

// Sutherland-Hodgman against z >= near: a triangle becomes at most a quad.
int clipNear(const std::array<ClipVertex, 3>& in, double near_m, std::array<ClipVertex, 4>* out) {
  int n = 0;
  for (int i = 0; i < 3; ++i) {
    const ClipVertex& a = in[static_cast<std::size_t>(i)];
    const ClipVertex& b = in[static_cast<std::size_t>((i + 1) % 3)];
    const bool a_in = a.c.z() >= near_m;
    const bool b_in = b.c.z() >= near_m;
    if (a_in) (*out)[static_cast<std::size_t>(n++)] = a;
    if (a_in != b_in) {
      const double s = (near_m - a.c.z()) / (b.c.z() - a.c.z());
      (*out)[static_cast<std::size_t>(n++)] = {a.c + s * (b.c - a.c), a.uv + s * (b.uv - a.uv)};
    }
  }
  return n;
}

inline float wrapOrClamp(float x, int size, bool repeat, int* i0, int* i1) {
  float fl = std::floor(x);
  const float frac = x - fl;
  int i = static_cast<int>(fl);
  if (repeat) {
    i %= size;
    if (i < 0) i += size;
    *i0 = i;
    *i1 = i + 1 == size ? 0 : i + 1;
  } else {
    *i0 = std::clamp(i, 0, size - 1);
    *i1 = std::clamp(i + 1, 0, size - 1);
  }
  return frac;
}

inline int wrapIndex(int i, int size, bool repeat) {
  if (repeat) {
    i %= size;
    return i < 0 ? i + size : i;
  }
  return i < 0 ? 0 : (i >= size ? size - 1 : i);
}

struct Rasteriser {
  const CameraModel& cam;
  RenderTarget* target;
  RasterStats stats;

  void drawClipped(const std::array<ClipVertex, 3>& v, const Triangle& tri) {
    const int width = target->colour.cols;
    const int height = target->colour.rows;
    std::array<Vec2, 3> s;
    for (std::size_t i = 0; i < 3; ++i) s[i] = cam.project(v[i].c);
    const double area = (s[1].x() - s[0].x()) * (s[2].y() - s[0].y()) -
                        (s[2].x() - s[0].x()) * (s[1].y() - s[0].y());
    if (!(std::abs(area) > 1e-9)) return;
    const double xmin_d = std::min({s[0].x(), s[1].x(), s[2].x()});
    const double xmax_d = std::max({s[0].x(), s[1].x(), s[2].x()});
    const double ymin_d = std::min({s[0].y(), s[1].y(), s[2].y()});
    const double ymax_d = std::max({s[0].y(), s[1].y(), s[2].y()});
    const int y0 = std::max(0, static_cast<int>(std::ceil(ymin_d)));
    const int y1 = std::min(height - 1, static_cast<int>(std::floor(ymax_d)));
    const int xlo = std::max(0, static_cast<int>(std::ceil(xmin_d)));
    const int xhi = std::min(width - 1, static_cast<int>(std::floor(xmax_d)));
    if (y0 > y1 || xlo > xhi) return;

    // Attributes that are affine in screen space: 1/z, u/z, v/z.
    std::array<Eigen::Vector3d, 3> f;
    for (std::size_t i = 0; i < 3; ++i) {
      const double w = 1.0 / v[i].c.z();
      f[i] = {w, v[i].uv.x() * w, v[i].uv.y() * w};
    }
    const Eigen::Vector3d dfdx = ((f[1] - f[0]) * (s[2].y() - s[0].y()) -
                                  (f[2] - f[0]) * (s[1].y() - s[0].y())) / area;
    const Eigen::Vector3d dfdy = ((f[2] - f[0]) * (s[1].x() - s[0].x()) -
                                  (f[1] - f[0]) * (s[2].x() - s[0].x())) / area;

    // Mip level from the texel footprint of the whole triangle.
    int lod = 0;
    if (tri.texture->levels() > 1) {
      const cv::Mat& t0 = tri.texture->level(0);
      const Vec2 a = v[1].uv - v[0].uv, b = v[2].uv - v[0].uv;
      const double texel_area = std::abs(a.x() * b.y() - a.y() * b.x()) * t0.cols * t0.rows;
      const double ratio = texel_area / std::abs(area);
      if (ratio > 1.0) {
        lod = std::min(tri.texture->levels() - 1, static_cast<int>(0.5 * std::log2(ratio)));
      }
    }
    const cv::Mat& tex = tri.texture->level(lod);
    const bool repeat = tri.texture->repeat();
    const int tw = tex.cols, th = tex.rows;
    const int shade256 = static_cast<int>(tri.shade * 256.0f + 0.5f);
    const float ftw = static_cast<float>(tw), fth = static_cast<float>(th);
    const std::uint8_t* tex_data = tex.data;
    const std::size_t tex_step = tex.step[0];
    const std::uint8_t* keep_data = tri.texture->cutout() ? tri.texture->keepLevel(lod).data : nullptr;
    const std::size_t keep_step = tri.texture->cutout() ? tri.texture->keepLevel(lod).step[0] : 0;
    const std::uint16_t id = tri.id;
    const double sign = area > 0 ? 1.0 : -1.0;

    for (int y = y0; y <= y1; ++y) {
      // Span of x where all three edge functions are >= 0.
      double left = xlo, right = xhi;
      bool empty = false;
      for (int e = 0; e < 3 && !empty; ++e) {
        const Vec2& a = s[static_cast<std::size_t>(e)];
        const Vec2& b = s[static_cast<std::size_t>((e + 1) % 3)];
        // E(x) = (b.x - a.x)(y - a.y) - (b.y - a.y)(x - a.x), times sign.
        const double k = -(b.y() - a.y()) * sign;
        const double c = (b.x() - a.x()) * (y - a.y()) * sign + (b.y() - a.y()) * a.x() * sign;
        if (std::abs(k) < 1e-12) {
          if (c < 0) empty = true;
        } else if (k > 0) {
          left = std::max(left, -c / k);
        } else {
          right = std::min(right, -c / k);
        }
      }
      if (empty) continue;
      const int xa = std::max(xlo, static_cast<int>(std::ceil(left - 1e-9)));
      const int xb = std::min(xhi, static_cast<int>(std::floor(right + 1e-9)));
      if (xa > xb) continue;
      const Eigen::Vector3d row = f[0] + dfdx * (xa - s[0].x()) + dfdy * (y - s[0].y());
      // Float from the row start on: over one row the relative error stays ~1e-6.
      const float w0 = static_cast<float>(row.x()), dw = static_cast<float>(dfdx.x());
      const float a0 = static_cast<float>(row.y()), da = static_cast<float>(dfdx.y());
      const float b0 = static_cast<float>(row.z()), db = static_cast<float>(dfdx.z());
      float* zrow = target->depth.ptr<float>(y);
      cv::Vec3b* crow = target->colour.ptr<cv::Vec3b>(y);
      std::uint16_t* irow = target->id.ptr<std::uint16_t>(y);
      for (int x = xa; x <= xb; ++x) {
        const float dx = static_cast<float>(x - xa);
        const float w = w0 + dw * dx;
        if (!(w > 0)) continue;
        const float z = 1.0f / w;
        if (!(z < zrow[x])) continue;
        const float tu = (a0 + da * dx) * z * ftw - 0.5f;
        const float tv = (b0 + db * dx) * z * fth - 0.5f;
        int u0 = static_cast<int>(tu), v0 = static_cast<int>(tv);
        if (tu < static_cast<float>(u0)) --u0;
        if (tv < static_cast<float>(v0)) --v0;
        const int fu = static_cast<int>((tu - static_cast<float>(u0)) * 256.0f);
        const int fv = static_cast<int>((tv - static_cast<float>(v0)) * 256.0f);
        int u1 = u0 + 1, v1 = v0 + 1;
        if (static_cast<unsigned>(u0) >= static_cast<unsigned>(tw - 1) ||
            static_cast<unsigned>(v0) >= static_cast<unsigned>(th - 1)) {
          u0 = wrapIndex(u0, tw, repeat);
          u1 = wrapIndex(u1, tw, repeat);
          v0 = wrapIndex(v0, th, repeat);
          v1 = wrapIndex(v1, th, repeat);
        }
        if (keep_data) {  // cut-out: transparent where the bilinear mask is below half
          const std::uint8_t* k0 = keep_data + static_cast<std::ptrdiff_t>(v0) * keep_step;
          const std::uint8_t* k1 = keep_data + static_cast<std::ptrdiff_t>(v1) * keep_step;
          const int top = (k0[u0] << 8) + (k0[u1] - k0[u0]) * fu;
          const int bottom = (k1[u0] << 8) + (k1[u1] - k1[u0]) * fu;
          if ((((top << 8) + (bottom - top) * fv) >> 16) < 128) continue;
        }
        const std::uint8_t* r0 = tex_data + static_cast<std::ptrdiff_t>(v0) * tex_step;
        const std::uint8_t* r1 = tex_data + static_cast<std::ptrdiff_t>(v1) * tex_step;
        const std::uint8_t* p00 = r0 + 3 * u0;
        const std::uint8_t* p01 = r0 + 3 * u1;
        const std::uint8_t* p10 = r1 + 3 * u0;
        const std::uint8_t* p11 = r1 + 3 * u1;
        cv::Vec3b out;
        for (int ch = 0; ch < 3; ++ch) {
          const int top = (p00[ch] << 8) + (p01[ch] - p00[ch]) * fu;
          const int bottom = (p10[ch] << 8) + (p11[ch] - p10[ch]) * fu;
          const int value = ((top << 8) + (bottom - top) * fv) >> 16;  // 0..255
          const int shaded = (value * shade256) >> 8;
          out[ch] = static_cast<std::uint8_t>(shaded > 255 ? 255 : shaded);
        }
        zrow[x] = z;
        crow[x] = out;
        irow[x] = id;
        ++stats.pixels_written;
      }
    }
    ++stats.triangles_drawn;
  }
};

}  // namespace

Texture::Texture(const cv::Mat& bgr, bool repeat, const cv::Mat& keep) : repeat_(repeat) {
  cv::Mat level0;
  if (bgr.type() == CV_8UC3) {
    level0 = bgr.clone();
  } else if (bgr.type() == CV_8UC1) {
    cv::cvtColor(bgr, level0, cv::COLOR_GRAY2BGR);
  } else if (bgr.type() == CV_8UC4) {
    cv::cvtColor(bgr, level0, cv::COLOR_BGRA2BGR);
  } else {
    level0 = cv::Mat(8, 8, CV_8UC3, cv::Scalar(128, 128, 128));
  }
  levels_.push_back(level0);
  while (levels_.back().cols >= 8 && levels_.back().rows >= 8) {
    cv::Mat next;
    cv::resize(levels_.back(), next, cv::Size(levels_.back().cols / 2, levels_.back().rows / 2), 0,
               0, cv::INTER_AREA);
    levels_.push_back(next);
  }
  if (!keep.empty() && keep.type() == CV_8UC1) {
    for (const cv::Mat& level : levels_) {
      cv::Mat k;
      cv::resize(keep, k, level.size(), 0, 0, level.cols < keep.cols ? cv::INTER_AREA : cv::INTER_LINEAR);
      keep_.push_back(k);
    }
  }
}

cv::Vec3f Texture::sample(float u, float v, int lod) const {
  const cv::Mat& tex = level(std::clamp(lod, 0, levels() - 1));
  int u0, u1, v0, v1;
  const float fu = wrapOrClamp(u * tex.cols - 0.5f, tex.cols, repeat_, &u0, &u1);
  const float fv = wrapOrClamp(v * tex.rows - 0.5f, tex.rows, repeat_, &v0, &v1);
  cv::Vec3f out;
  for (int ch = 0; ch < 3; ++ch) {
    const float top = tex.at<cv::Vec3b>(v0, u0)[ch] * (1 - fu) + tex.at<cv::Vec3b>(v0, u1)[ch] * fu;
    const float bot = tex.at<cv::Vec3b>(v1, u0)[ch] * (1 - fu) + tex.at<cv::Vec3b>(v1, u1)[ch] * fu;
    out[ch] = top * (1 - fv) + bot * fv;
  }
  return out;
}

float faceShade(const Vec3& n) {
  static const Vec3 light = Vec3(0.4, -0.3, 0.87).normalized();
  const double len = n.norm();
  if (!(len > 0)) return 1.0f;
  return static_cast<float>(0.6 + 0.45 * std::abs(n.dot(light)) / len);
}

void addQuad(Mesh* mesh, const std::array<Vec3, 4>& c, const Texture* texture, std::uint16_t id,
             double u1, double v1, int tiles_u, int tiles_v) {
  const float shade = faceShade((c[1] - c[0]).cross(c[3] - c[0]));
  tiles_u = std::max(1, tiles_u);
  tiles_v = std::max(1, tiles_v);
  // Bilinear corner interpolation; exact for planar parallelograms.
  auto point = [&](double a, double b) {
    return Vec3((1 - a) * (1 - b) * c[0] + a * (1 - b) * c[1] + a * b * c[2] + (1 - a) * b * c[3]);
  };
  for (int j = 0; j < tiles_v; ++j) {
    for (int i = 0; i < tiles_u; ++i) {
      const double a0 = double(i) / tiles_u, a1 = double(i + 1) / tiles_u;
      const double b0 = double(j) / tiles_v, b1 = double(j + 1) / tiles_v;
      const Vec3 p00 = point(a0, b0), p10 = point(a1, b0), p11 = point(a1, b1), p01 = point(a0, b1);
      const Vec2 t00(a0 * u1, b0 * v1), t10(a1 * u1, b0 * v1), t11(a1 * u1, b1 * v1),
          t01(a0 * u1, b1 * v1);
      mesh->triangles.push_back({{p00, p10, p11}, {t00, t10, t11}, texture, shade, id});
      mesh->triangles.push_back({{p00, p11, p01}, {t00, t11, t01}, texture, shade, id});
    }
  }
}

void addBox(Mesh* mesh, const SE3& T_w_b, const Vec3& h, const Texture* texture, std::uint16_t id) {
  auto P = [&](double x, double y, double z) { return Vec3(T_w_b * Vec3(x * h.x(), y * h.y(), z * h.z())); };
  // Each face listed counter-clockwise seen from outside, starting top-left.
  addQuad(mesh, {P(-1, -1, -1), P(1, -1, -1), P(1, 1, -1), P(-1, 1, -1)}, texture, id);  // -z
  addQuad(mesh, {P(1, -1, 1), P(-1, -1, 1), P(-1, 1, 1), P(1, 1, 1)}, texture, id);      // +z
  addQuad(mesh, {P(-1, -1, 1), P(-1, -1, -1), P(-1, 1, -1), P(-1, 1, 1)}, texture, id);  // -x
  addQuad(mesh, {P(1, -1, -1), P(1, -1, 1), P(1, 1, 1), P(1, 1, -1)}, texture, id);      // +x
  addQuad(mesh, {P(-1, -1, 1), P(1, -1, 1), P(1, -1, -1), P(-1, -1, -1)}, texture, id);  // -y
  addQuad(mesh, {P(-1, 1, -1), P(1, 1, -1), P(1, 1, 1), P(-1, 1, 1)}, texture, id);      // +y
}

RenderTarget RenderTarget::blank(int width, int height, const cv::Vec3b& background) {
  RenderTarget t;
  t.colour = cv::Mat(height, width, CV_8UC3, cv::Scalar(background[0], background[1], background[2]));
  t.depth = cv::Mat(height, width, CV_32FC1, cv::Scalar(std::numeric_limits<float>::infinity()));
  t.id = cv::Mat(height, width, CV_16UC1, cv::Scalar(0));
  return t;
}

RasterStats render(const Mesh& mesh, const SE3& T_w_c, const CameraModel& cam, RenderTarget* target,
                   double near_m) {
  Rasteriser r{cam, target, {}};
  const SE3 T_c_w = T_w_c.inverse();
  const Mat3 R = T_c_w.linear();
  const Vec3 t = T_c_w.translation();
  for (const Triangle& tri : mesh.triangles) {
    if (tri.texture == nullptr) continue;
    std::array<ClipVertex, 3> v;
    int behind = 0;
    for (std::size_t i = 0; i < 3; ++i) {
      v[i] = {R * tri.p[i] + t, tri.uv[i]};
      behind += v[i].c.z() < near_m;
    }
    if (behind == 3) continue;
    if (behind == 0) {
      r.drawClipped(v, tri);
      continue;
    }
    std::array<ClipVertex, 4> poly;
    const int n = clipNear(v, near_m, &poly);
    for (int k = 1; k + 1 < n; ++k) {
      r.drawClipped({poly[0], poly[static_cast<std::size_t>(k)], poly[static_cast<std::size_t>(k + 1)]}, tri);
    }
  }
  return r.stats;
}

}  // namespace stillpoint::synth
