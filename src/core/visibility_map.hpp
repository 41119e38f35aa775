// A point light's visibility map: for each direction leaving the light (a cube map of texels over
// the unit directions of an orthonormal frame at the light), how far the geodesic from the light in
// that direction runs before it meets an occluder. A geodesic from a shaded point H to a copy g L
// of the light is g applied to one from L to g^-1 H, which leaves L in the direction g^-1 of its
// arrival tangent at g L: H is lit along it where the map's distance in that direction reaches H.
// One map serves every copy and every geodesic to it, so a shaded point's hundreds of shadow walks
// become lookups. The texels are traced lazily, on first use, by whichever thread asks (they are
// deterministic, so a race only traces one twice). integrator.hpp uses the map as a control
// variate: its answer, corrected by exact walks drawn at random (docs/lighting.md).
#pragma once

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <memory>

#include "vec.hpp"

namespace thurston {

class VisibilityMap {
 public:
  // A map of 6 * texels^2 texels, none traced yet.
  explicit VisibilityMap(int texels)
      : texels_(texels), reach_(new std::atomic<float>[6 * std::size_t(texels) * texels]) {
    for (std::size_t i = 0; i < size(); ++i) reach_[i].store(kUntraced, std::memory_order_relaxed);
  }

  int texels() const { return texels_; }
  std::size_t size() const { return 6 * std::size_t(texels_) * texels_; }
  // The angle between neighbouring texels' directions at a face's centre (the widest).
  double spacing() const { return 2.0 / texels_; }

  // The unit direction (in the light's frame) of texel i's centre.
  Vec3 direction(std::size_t i) const {
    const std::size_t n = std::size_t(texels_), face = i / (n * n), rest = i % (n * n);
    const double s = 2.0 * (double(rest % n) + 0.5) / n - 1.0;
    const double t = 2.0 * (double(rest / n) + 0.5) / n - 1.0;
    const int axis = int(face / 2), a = (axis + 1) % 3, b = (axis + 2) % 3;
    Vec3 u{0.0, 0.0, 0.0};
    u[axis] = face % 2 ? -1.0 : 1.0;
    u[a] = s;
    u[b] = t;
    return scaled3(1.0 / norm3(u), u);
  }

  // The four texels about direction u (any length) and their bilinear weights, within u's face.
  struct Footprint {
    std::size_t texel[4];
    double weight[4];
  };
  Footprint footprint(const Vec3& u) const {
    int axis = 0;
    for (int k = 1; k < 3; ++k)
      if (std::abs(u[k]) > std::abs(u[axis])) axis = k;
    const int a = (axis + 1) % 3, b = (axis + 2) % 3;
    const std::size_t face = 2 * std::size_t(axis) + (u[axis] < 0.0 ? 1 : 0);
    const double n = texels_, half = 0.5 * n / std::abs(u[axis]);
    // texel coordinates of u, texel centres at whole numbers, kept on the face
    const double x = std::clamp(u[a] * half + 0.5 * n - 0.5, 0.0, n - 1.0);
    const double y = std::clamp(u[b] * half + 0.5 * n - 0.5, 0.0, n - 1.0);
    const std::size_t row = std::size_t(texels_), last = row - 1;
    const std::size_t i0 = std::min(std::size_t(x), last), j0 = std::min(std::size_t(y), last);
    const std::size_t i1 = std::min(i0 + 1, last), j1 = std::min(j0 + 1, last);
    const double fx = x - double(i0), fy = y - double(j0);
    const std::size_t base = face * row * row;
    return {
        {base + j0 * row + i0, base + j0 * row + i1, base + j1 * row + i0, base + j1 * row + i1},
        {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy}};
  }

  // Texel i's distance to the first occluder (inf: none within the reach), tracing it with
  // `trace(direction)` where it is not known yet; NaN where the trace was cut short (cancelled).
  template <class Trace>
  double reach(std::size_t i, Trace&& trace, bool& traced) const {
    float r = reach_[i].load(std::memory_order_relaxed);
    traced = false;
    if (std::isnan(r)) {
      const double found = trace(direction(i));
      if (std::isnan(found)) return found;
      r = float(found);
      reach_[i].store(r, std::memory_order_relaxed);
      traced = true;
    }
    return r;
  }

 private:
  static constexpr float kUntraced = std::numeric_limits<float>::quiet_NaN();
  int texels_;
  std::unique_ptr<std::atomic<float>[]> reach_;
};

}  // namespace thurston
