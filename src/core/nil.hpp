// Nil: R^3 with the paper's metric dx^2 + dy^2 + (dz - x dy)^2, the Heisenberg group
// (x, y, z) . (x', y', z') = (x + x', y + y', z + z' + x y') acting by left multiplication.
// Geodesics in closed form: from the origin in the form that stays accurate for small w t
// (GEOMETRIES.md), from any point by left translation.
#pragma once

#include <algorithm>
#include <cmath>

#include "affine_chart.hpp"
#include "closed_form.hpp"
#include "vec.hpp"

namespace thurston {

struct NilFlow : AffineChart, ClosedForm<NilFlow> {
  // The geodesic from p with unit chart velocity v at arclength t. At the origin the velocity is
  // (c cos a, c sin a, w); the horizontal part turns at the rate w (theta = w t) and w is constant.
  static void geodesic(const Vec3& p, const Vec3& v, double t, Vec3& xt, Vec3& vt) {
    // to the origin by the left translation p^-1, whose differential is dz -> dz - p_x dy
    const double ux = v[0], uy = v[1], w = v[2] - p[0] * v[1];
    const double c2 = ux * ux + uy * uy;
    const double theta = w * t, half = 0.5 * theta;
    const double ch = std::cos(half), sh = std::sin(half), sinc = sin_over(half);
    const double cos_t = ch * ch - sh * sh, sin_t = 2.0 * sh * ch;
    const double X = t * sinc * (ux * ch - uy * sh);
    const double Y = t * sinc * (uy * ch + ux * sh);
    // c^2 sin(theta + 2a) with (cos a, sin a) = (ux, uy) / c
    const double twist = (ux * ux - uy * uy) * sin_t + 2.0 * ux * uy * cos_t;
    const double Z = w * t + 0.5 * t * t * (c2 * excess(theta) + 0.5 * sinc * sinc * twist);
    const double vx = ux * cos_t - uy * sin_t, vy = uy * cos_t + ux * sin_t;
    const double vz = w + X * vy;
    // back by the left translation p
    xt = {X + p[0], Y + p[1], Z + p[2] + p[0] * Y};
    vt = {vx, vy, vz + p[0] * vy};
  }
  // What the closed form's roundings may add (a few ulps of the coordinates' size, per unit length).
  static double rounding(const Vec3& p, double t) {
    const double size = 1.0 + std::max({std::abs(p[0]), std::abs(p[1]), std::abs(p[2])}) + t;
    return 4e-16 * size * (1.0 + t);
  }

  // x'' = -w y', y'' = w x', z'' = x' y' + x x' w (from the Christoffel symbols), with
  // x'^2 + y'^2 = c^2 and |x| growing at most by c h over the step.
  double acceleration_bound(const Vec3& p, const Vec3& v, double h) const {
    const double w = std::abs(v[2] - p[0] * v[1]);
    const double c = std::sqrt(v[0] * v[0] + v[1] * v[1]);
    const double horizontal = c * w;
    const double vertical = 0.5 * c * c + (std::abs(p[0]) + c * h) * c * w;
    return std::sqrt(horizontal * horizontal + vertical * vertical);
  }
  // Sectional curvatures lie in [-3/4, 1/4], so nearby geodesics separate slower than e^t.
  double growth_rate() const { return 1.0; }
  double max_step() const { return 1.0; }

  double dot(const Vec3& p, const Vec3& a, const Vec3& b) const {
    return a[0] * b[0] + a[1] * b[1] + (a[2] - p[0] * a[1]) * (b[2] - p[0] * b[1]);
  }
  Vec3 raise(const Vec3& p, const Vec3& n) const {
    const double x = p[0];
    return {n[0], n[1] + x * n[2], x * n[1] + (1.0 + x * x) * n[2]};
  }
  double volume_density(const Vec3&) const { return 1.0; }
  // The chart length of q^-1 p: the left translation of q to the origin, where the chart is
  // isometric to first order.
  double separation(const Vec3& q, const Vec3& p) const {
    const Vec3 d{p[0] - q[0], p[1] - q[1], p[2] - q[2] - q[0] * (p[1] - q[1])};
    return norm3(d);
  }

 private:
  // sin(u) / u, and (theta - sin theta) / theta^2, by their series where they would cancel
  static double sin_over(double u) {
    if (std::abs(u) < 1e-3) {
      const double u2 = u * u;
      return 1.0 - u2 / 6.0 + u2 * u2 / 120.0;
    }
    return std::sin(u) / u;
  }
  static double excess(double theta) {
    if (std::abs(theta) < 0.1) {
      const double q = theta * theta;
      return theta * (1.0 / 6.0 - q * (1.0 / 120.0 - q * (1.0 / 5040.0 - q * (1.0 / 362880.0 -
                                                                              q / 39916800.0))));
    }
    return (theta - std::sin(theta)) / (theta * theta);
  }
};

}  // namespace thurston
