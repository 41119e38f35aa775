// What a hit point's surface looks like: materials (base colour and emission, each optionally
// times an image texture through the triangle's UVs, and how they scatter: bsdf.hpp) and the
// shading normal interpolated from the triangle's corner normals. Kept apart from the walk so that
// direct light and path tracing share one lookup.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include "bsdf.hpp"
#include "vec.hpp"

namespace thurston {

using Rgb = std::array<float, 3>;
inline double mean_rgb(const Rgb& c) { return (double(c[0]) + c[1] + c[2]) / 3.0; }

// A linear RGB image, rows top-down; sampled bilinearly at texel centres with repeat wrap, v up
// (v = 0 is the bottom row, as in Blender and OBJ).
struct Texture {
  int width = 0, height = 0, channels = 0;  // channels 3 or 4 (alpha unused)
  std::vector<float> texels;                // height * width * channels

  Rgb sample(double u, double v) const {
    const double x = (u - std::floor(u)) * width - 0.5;
    const double y = (1.0 - (v - std::floor(v))) * height - 0.5;
    const double fx = std::floor(x), fy = std::floor(y);
    const float ax = float(x - fx), ay = float(y - fy);
    const auto wrap = [](int i, int n) { return i < 0 ? i + n : i >= n ? i - n : i; };
    const int x0 = wrap(int(fx), width), x1 = wrap(int(fx) + 1, width);
    const int y0 = wrap(int(fy), height), y1 = wrap(int(fy) + 1, height);
    const auto at = [&](int row, int col, int a) {
      return texels[(std::size_t(row) * width + col) * channels + a];
    };
    Rgb out;
    for (int a = 0; a < 3; ++a)
      out[a] = (1 - ay) * ((1 - ax) * at(y0, x0, a) + ax * at(y0, x1, a)) +
               ay * ((1 - ax) * at(y1, x0, a) + ax * at(y1, x1, a));
    return out;
  }
};

// Base colour and emission, each a constant times its texture (index into the textures, -1: none),
// and the scattering (Lambert unless glossy).
struct Material {
  Rgb color{}, emission{};
  std::int32_t color_texture = -1, emission_texture = -1;
  bool one_sided = false;  // emits from the front only (the side of the triangle's winding normal)
  Principled scattering{};

  bool emits() const { return emission[0] > 0.0f || emission[1] > 0.0f || emission[2] > 0.0f; }
};

using CornerVectors = std::array<std::array<float, 3>, 3>;  // per triangle corner
using CornerUvs = std::array<std::array<float, 2>, 3>;

// The triangles' surface attributes; the per-corner arrays are empty where the scene has none.
struct Surfaces {
  std::vector<std::int32_t> triangle_material;
  std::vector<Material> materials;
  std::vector<Texture> textures;
  std::vector<CornerVectors> corner_normals;  // chart covectors (the surface's chart conormal)
  std::vector<CornerUvs> corner_uvs;

  // Barycentric coordinates of the chart point x in the plane of the triangle p0 p1 p2.
  static Vec3 barycentric(const Vec3& p0, const Vec3& p1, const Vec3& p2, const Vec3& x) {
    const Vec3 e1 = sub3(p1, p0), e2 = sub3(p2, p0), d = sub3(x, p0);
    const double a = dot3(e1, e1), b = dot3(e1, e2), c = dot3(e2, e2);
    const double p = dot3(d, e1), q = dot3(d, e2);
    const double det = a * c - b * b;
    if (!(det > 0.0)) return {1.0, 0.0, 0.0};  // degenerate: the first corner's attributes
    const double l1 = (c * p - b * q) / det, l2 = (a * q - b * p) / det;
    return {1.0 - l1 - l2, l1, l2};
  }

  // Interpolated chart covector of the shading normal (false: the triangle has none).
  bool normal_covector(std::size_t triangle, const Vec3& weights, Vec3& n) const {
    if (corner_normals.empty()) return false;
    const CornerVectors& c = corner_normals[triangle];
    for (int a = 0; a < 3; ++a)
      n[a] = weights[0] * c[0][a] + weights[1] * c[1][a] + weights[2] * c[2][a];
    return dot3(n, n) > 0.0;
  }

  // Base colour and emission of the triangle's material at the barycentric weights.
  void look_up(std::size_t triangle, const Vec3& weights, Rgb& color, Rgb& emission) const {
    const Material& m = materials[triangle_material[triangle]];
    color = m.color;
    emission = m.emission;
    if (m.color_texture < 0 && m.emission_texture < 0) return;
    const CornerUvs& uv = corner_uvs[triangle];
    const double u = weights[0] * uv[0][0] + weights[1] * uv[1][0] + weights[2] * uv[2][0];
    const double v = weights[0] * uv[0][1] + weights[1] * uv[1][1] + weights[2] * uv[2][1];
    const auto times = [&](Rgb& value, std::int32_t texture) {
      if (texture < 0) return;
      const Rgb t = textures[texture].sample(u, v);
      for (int a = 0; a < 3; ++a) value[a] *= t[a];
    };
    times(color, m.color_texture);
    times(emission, m.emission_texture);
  }
};

}  // namespace thurston
