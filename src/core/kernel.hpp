// What every geometry kernel shares with the tracer: the domain's faces, the walk's protocol and
// the records a kernel hands back.
//
// A kernel K (ProjectiveKernel for E3/S3/H3, the marching kernels for the other geometries) offers
//   WalkEnd walk(const WalkContext&, Vec4 P, Vec4 V, double length, int max_crossings,
//                double first_skip, Query&& query, OnHit&& on_hit)
//       a ray's walk through the domain and its face pairings for `length`: query(chord, tnear)
//       on each chart chord that may meet the scene (context.may_hit) until it reports a hit,
//       then on_hit(hit) with something whose refine(plane, u) puts the hit (Embree's parameter u
//       on that chord) onto the true curve; the first chord skips `first_skip` of chart length.
//       The projective kernel walks one exact chord per cell; the marching kernel steps its Walk.
//   K::Chord    x0, x1 (the chart segment Embree tests) and margin (how far the curve may stray
//               from it);
//   bool start(Vec4& P, Vec4& V)                 P a point and V a unit tangent there (projected);
//   Vec4 plane_normal(const Vec4& X, const Vec4& plane)     the metric normal of a chart plane;
//   double dot(const Vec4& X, const Vec4& a, const Vec4& b) the metric at X;
//   bool normalise(const Vec4& X, Vec4& v)                 unit length at X;
//   Vec3 chart_vector(const Vec4& X, const Vec4& v)         its chart image, unit in the chart;
//   int light_paths(const Vec4& H, const std::vector<Vec4>& lifts, double reach,
//       std::vector<LightPath>&, const Vec4& facing = {})   every geodesic from the surface point
//       H to the lifts (copies of
//       a light) no longer than reach: closed forms (ProjectiveKernel; the marching kernels of H2xR
//       and S2xR), one-dimensional root searches per branch (Nil, SL2) or shooting from a table of
//       the exponential map (Sol, which may miss some near caustics); returns how many it could
//       tell were missed; those leaving H against `facing` (a tangent vector at H, nonzero) may be
//       left out (the projective kernel does, before it takes their distances);
//   void prepare_light_paths(double reach)   what light_paths needs to know of the reach before
//       it is asked (Sol's table of its exponential map; nothing for the others);
//   Vec4 arrival(const Vec4& H, const LightPath&)   the unit tangent at the path's far end that
//       points back along it (towards H): the direction in which the light leaves;
//   Vec4 leaving(const Vec4& H, const Vec4& X, const LightPath&)   the same up to a positive factor
//       as the metric at the lift X sees it (its products with X's tangent vectors), cheaper;
//   Vec4 chart_point(const Vec3& x), Vec4 chart_tangent(const Vec4& X, const Vec3& e)   the point
//       of a chart point, and the tangent vector at it of a chart direction (for emitter samples);
//   void move(const Mat4& M, Vec4& X, Vec4& V)    an isometry (a group element) applied to a point
//       and a tangent vector there.
// Points and tangent vectors are 4-vectors: model vectors in the projective kernel, (x, 1) and
// (v, 0) in chart coordinates in the others; face maps act on them linearly.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <vector>

#include "vec.hpp"

namespace thurston {

// The fundamental domain {X : c_f . X <= 0} and its face pairings (a ray leaving through face f
// continues from maps[f] X).
struct Domain {
  std::size_t faces = 0;
  std::array<std::vector<double>, 4> components;  // covectors by component, padded to a multiple of
                                                  // 4 with zero covectors (never an exit), for SIMD
  std::vector<Mat4> maps;
  std::vector<Mat4> maps_t;  // the same, column-major, for SIMD products

  Vec4 covector(std::size_t f) const {
    return {components[0][f], components[1][f], components[2][f], components[3][f]};
  }
};

// Which cells of a grid over the scene's bounds hold geometry (boxes marked by the tracer: the
// bounding boxes of triangles or of whole instances), with prefix sums so that a box asks in
// constant time.
class Occupancy {
 public:
  // An empty grid of cells^3 over [lo, hi]; mark() boxes, then finish() before asking.
  void start(const Vec3& lo, const Vec3& hi, int cells);
  void mark(const Vec3& lo, const Vec3& hi);
  void finish();
  // How many cells the box [lo, hi] spans.
  std::size_t cells_spanned(const Vec3& lo, const Vec3& hi) const;
  bool empty() const { return cells_ == 0; }
  // Whether any marked cell meets the box [lo, hi] (which must meet the grid's bounds).
  bool touches(const Vec3& lo, const Vec3& hi) const;

 private:
  std::size_t at(int i, int j, int k) const {
    return (std::size_t(i) * (cells_ + 1) + std::size_t(j)) * (cells_ + 1) + std::size_t(k);
  }
  int cell(double x, int axis) const;
  int cells_ = 0;
  Vec3 lo_{}, size_{};
  std::vector<std::uint8_t> marked_;   // cells^3, until finish()
  std::vector<std::uint32_t> prefix_;  // (cells + 1)^3: marked cells below each corner
};

// Everything of the scene a walk may consult besides the domain.
struct WalkContext {
  const Domain& domain;
  Vec3 bounds_lo, bounds_hi;   // the scene's chart bounds, widened a little (lo > hi: no triangles)
  const Occupancy& occupancy;  // empty: only the bounds are asked
  double tolerance;            // chord deviation allowed at distance 0 (chart units) ...
  double tolerance_per_distance;  // ... growing by this per unit of geodesic distance
  bool skip_empty;  // marching kernels: step through empty space without chords (else chords
                    // within the tolerance everywhere, for measuring what the economy saves)
  // Set when the run is cancelled: walks look at it on every step, since one ray with a huge
  // distance or crossing limit may walk for minutes (it then ends as kCancelled).
  const std::atomic<bool>& stop;
  bool stopped() const { return stop.load(std::memory_order_relaxed); }
  double tolerance_at(double distance) const {
    return tolerance + tolerance_per_distance * distance;
  }

  // Whether a chord (a curve within `margin` of it) may meet the scene; also keeps non-finite or
  // float-overflowing chords away from Embree.
  bool may_hit(const Vec3& x0, const Vec3& x1, double margin) const {
    bool ok = true;
    Vec3 lo, hi;
    for (int a = 0; a < 3; ++a) {
      const double u = x0[a], v = x1[a];
      ok &= std::abs(u) < 1e30 && std::abs(v) < 1e30;
      lo[a] = std::min(u, v) - margin;
      hi[a] = std::max(u, v) + margin;
      ok &= !(hi[a] < bounds_lo[a]) && !(lo[a] > bounds_hi[a]);
    }
    return ok && (!skip_empty || occupancy.empty() || occupancy.touches(lo, hi));
  }
};

enum Stop : std::uint8_t { kHit = 0, kDistanceLimit = 1, kCrossingLimit = 2, kCancelled = 3 };

// How a walk ended: the distance travelled (to the start of the hit's chord on a hit), the face
// crossings, the kernel's bound of the hit chord's distance from the true geodesic, and where a
// walk that met nothing stopped (chart).
struct WalkEnd {
  Stop stop;
  double distance;
  int crossings;
  double error;
  Vec3 end{kNaN, kNaN, kNaN};
};

// A hit refined onto the true curve: arclength from the chord's start, the point and the unit
// tangent of the ray there (model 4-vectors) and the chart point.
struct Hit {
  double s;
  Vec4 X, V;
  Vec3 x;
};

// The geodesic from a surface point to a light: unit direction at the surface point, length and
// the light's falloff along it (the inverse area density of the geodesic sphere about the light),
// and the index of the lift (copy of the light) it reaches.
struct LightPath {
  Vec4 direction;
  double distance;
  double falloff;
  std::int32_t lift = -1;
};

// Falloff floored so that lights touching a surface stay finite.
inline double floored_falloff(double area_density) {
  constexpr double kFloor = 1e-4;
  return 1.0 / std::max(area_density, kFloor * kFloor);
}

}  // namespace thurston
