// S2xR: R^3 minus the origin with the metric |dx|^2 / |x|^2 (x = e^w u, u on the unit sphere).
// Geodesics in closed form: with b = <v, x> / |x|^2 (the speed of w) and p = v - b x (|p| = a |x|,
// a the speed on the sphere), x(t) = e^{b t} (cos(a t) x + sin(a t) / a . p), log-spirals in a
// plane through the origin. The chart is the model (AffineChart); face maps are e^c R (R in O(3)),
// faces the spheres w = log|x| = w0, given as covectors (0, 0, c2, c3) of (0, 0, w, 1)
// (geometries/s2xr.py): w is linear in arclength, so exits are exact.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "affine_chart.hpp"
#include "closed_form.hpp"
#include "kernel.hpp"
#include "vec.hpp"

namespace thurston {

struct S2xRFlow : AffineChart, ClosedForm<S2xRFlow> {
  static void geodesic(const Vec3& x, const Vec3& v, double t, Vec3& xt, Vec3& vt) {
    const double r2 = dot3(x, x), b = dot3(v, x) / r2;
    const Vec3 p = sub3(v, scaled3(b, x));
    const double a = std::sqrt(dot3(p, p) / r2), at = a * t;
    const double grow = std::exp(b * t), c = std::cos(at),
                 sin_over = a > 0.0 ? std::sin(at) / a : t;
    for (int i = 0; i < 3; ++i) {
      const double spiral = c * x[i] + sin_over * p[i];
      const double turning = -a * a * sin_over * x[i] + c * p[i];
      xt[i] = grow * spiral;
      vt[i] = grow * (b * spiral + turning);
    }
  }
  // What the closed form's roundings may add: a few ulps of |x(t)| per unit length.
  static double rounding(const Vec3& x, double t) {
    const double r = std::sqrt(dot3(x, x));
    return 4e-16 * r * std::exp(t) * (1.0 + t);
  }

  // |x''| = |x| (a^2 + b^2) = |x| along a unit-speed log-spiral (its chart velocity has length
  // |x|, turning at rate a and growing at rate b); over a step of length h, |x| <= |x0| e^h.
  double acceleration_bound(const Vec3& x, const Vec3&, double h) const {
    return std::sqrt(dot3(x, x)) * std::exp(h);
  }
  // Sectional curvatures lie in [0, 1]: nearby geodesics separate at most linearly (rate 1 bounds
  // it).
  double growth_rate() const { return 1.0; }
  double max_step() const { return 1.0; }

  double dot(const Vec3& x, const Vec3& a, const Vec3& b) const { return dot3(a, b) / dot3(x, x); }
  Vec3 raise(const Vec3& x, const Vec3& n) const { return scaled3(dot3(x, x), n); }

  // Light along every geodesic: from h to the light's copy l (chart points) the cover holds one
  // geodesic per great-circle arc between their directions, the sphere angle alpha going either
  // way round and winding (theta + 2 pi n, 2 pi (n + 1) - theta), times the straight w part, so
  // that r^2 = alpha^2 + dw^2; those no longer than reach. The wavefront is the sphere's circle
  // times the flat direction: area density r^2 |sin alpha| / alpha. Directions that coincide or
  // are antipodal (where whole cones of arcs focus) keep only the straight w path.
  static void connections(const Vec3& h, const Vec3& l, double reach,
                          std::vector<LightPath>& paths) {
    const double rh = norm3(h), rl = norm3(l), dw = std::log(rl / rh);
    const Vec3 u = scaled3(1.0 / rh, h), ul = scaled3(1.0 / rl, l);
    const double cos_theta = dot3(u, ul);
    Vec3 e = sub3(ul, scaled3(cos_theta, u));
    const double sin_theta = norm3(e);
    const auto add = [&](double alpha, const Vec3& towards) {
      const double r = std::hypot(alpha, dw);
      if (!(r > 0.0)) return;
      const Vec3 v = scaled3(rh / r, add3(scaled3(dw, u), scaled3(alpha, towards)));
      const double stretch = alpha > 0.0 ? std::abs(std::sin(alpha)) / alpha : 1.0;
      paths.push_back({vector4(v), r, floored_falloff(r * r * stretch)});
    };
    constexpr double kAligned = 1e-12;
    if (!(sin_theta > kAligned)) {
      if (cos_theta > 0.0 && std::abs(dw) <= reach) add(0.0, e);
      return;
    }
    e = scaled3(1.0 / sin_theta, e);
    const double theta = std::atan2(sin_theta, cos_theta);
    const double longest = std::sqrt(std::max(reach * reach - dw * dw, 0.0));  // of alpha
    if (!(std::abs(dw) <= reach)) return;
    for (double turns = 0.0; theta + turns <= longest; turns += 2.0 * kPi) {
      add(theta + turns, e);
      if (turns + 2.0 * kPi - theta <= longest) add(turns + 2.0 * kPi - theta, scaled3(-1.0, e));
    }
  }

  // Faces: the spheres c2 w + c3 = 0 (c[0] = c[1] = 0), w = log|x|, linear along every geodesic.
  static double side(const Vec4& c, const Vec3& x) {
    return c[2] * 0.5 * std::log(dot3(x, x)) + c[3];
  }
  static Vec3 side_gradient(const Vec4& c, const Vec3& x) { return scaled3(c[2] / dot3(x, x), x); }
  static double side_acceleration_bound(const Vec4&, double) { return 0.0; }
  // The tolerance is metric: a unit of it is |x| of chart length at x, at least |x| / e over a step
  // (max_step 1), so chords are the same wherever the shell is (its chart spans a factor e^L).
  static double chart_scale(const Vec3& x) { return std::sqrt(dot3(x, x)) * 0.36787944117144233; }
};

}  // namespace thurston
