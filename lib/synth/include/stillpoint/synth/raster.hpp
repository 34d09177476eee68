#pragma once
// A small CPU rasteriser for the dynamic-sequence generator: textured
// triangles in world coordinates, near-plane clipping, perspective-correct
// texture mapping and a z-buffer holding metric depth (z along the optical
// axis, so it compares directly with a depth image). Pixel centres sit at
// integer coordinates, the convention of CameraModel::project.
#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/geometry.hpp"

namespace stillpoint::synth {

// A BGR texture with a mip pyramid (level 0 = full resolution). Texture
// coordinates are in [0,1] across the image; with `repeat` they wrap.
class Texture {
 public:
  // `keep` (optional, CV_8UC1, any size: resized to the texture's) cuts the
  // texture out: texels where it is < 128 are transparent, nothing is drawn there.
  Texture(const cv::Mat& bgr, bool repeat, const cv::Mat& keep = cv::Mat());
  int levels() const { return static_cast<int>(levels_.size()); }
  const cv::Mat& level(int i) const { return levels_[static_cast<std::size_t>(i)]; }
  bool repeat() const { return repeat_; }
  bool cutout() const { return !keep_.empty(); }
  // The cut-out mask of level i (CV_8UC1, same size as level(i)); only when cutout().
  const cv::Mat& keepLevel(int i) const { return keep_[static_cast<std::size_t>(i)]; }
  // Bilinear lookup at texture coordinates (u, v) of level `lod`.
  cv::Vec3f sample(float u, float v, int lod) const;

 private:
  std::vector<cv::Mat> levels_;  // CV_8UC3, continuous
  std::vector<cv::Mat> keep_;    // CV_8UC1 per level, or empty
  bool repeat_;
};
using TexturePtr = std::shared_ptr<const Texture>;

struct Triangle {
  std::array<Vec3, 3> p;   // world coordinates (m)
  std::array<Vec2, 3> uv;  // texture coordinates
  const Texture* texture = nullptr;  // not owned; must outlive render()
  float shade = 1.0f;      // colour multiplier (flat lighting)
  std::uint16_t id = 0;    // written to RenderTarget::id where this triangle is visible
};

struct Mesh {
  std::vector<Triangle> triangles;
};

// Flat shading for a face with world normal n: ambient plus a fixed light from
// above and to the side, two-sided.
float faceShade(const Vec3& n);

// Quad with corners c[0..3] (in order around the face) mapped to texture
// corners (0,0) (u1,0) (u1,v1) (0,v1). Split into `tiles` x `tiles` sub-quads so
// that per-triangle mip selection stays local on large faces.
void addQuad(Mesh* mesh, const std::array<Vec3, 4>& c, const Texture* texture, std::uint16_t id,
             double u1 = 1.0, double v1 = 1.0, int tiles_u = 1, int tiles_v = 1);

// Box with half-sizes `half` (x, y, z of its own frame) placed by T_w_b; every
// face carries the whole texture.
void addBox(Mesh* mesh, const SE3& T_w_b, const Vec3& half, const Texture* texture,
            std::uint16_t id);

struct RenderTarget {
  cv::Mat colour;  // CV_8UC3
  cv::Mat depth;   // CV_32FC1 z-buffer in metres; +inf where nothing is
  cv::Mat id;      // CV_16UC1, 0 where the background is visible

  // Colour filled with `background`, depth +inf, id 0.
  static RenderTarget blank(int width, int height, const cv::Vec3b& background = {0, 0, 0});
};

struct RasterStats {
  long triangles_drawn = 0;
  long pixels_written = 0;
};

// Draws every triangle seen by camera `cam` at pose T_w_c into `target`
// (z-test against target->depth, which may hold a real depth image).
// Ignores lens distortion: renders the undistorted pinhole image.
RasterStats render(const Mesh& mesh, const SE3& T_w_c, const CameraModel& cam,
                   RenderTarget* target, double near_m = 0.05);

}  // namespace stillpoint::synth
