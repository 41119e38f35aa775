// Nil: R^3 with the paper's metric dx^2 + dy^2 + (dz - x dy)^2, the Heisenberg group
// (x, y, z) . (x', y', z') = (x + x', y + y', z + z' + x y') acting by left multiplication.
// Geodesics in closed form: from the origin in the form that stays accurate for small w t
// (docs/mathematics.md#nil), from any point by left translation. Connecting geodesics in closed
// form too, up to a one-dimensional root search per branch (connections).
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "affine_chart.hpp"
#include "closed_form.hpp"
#include "kernel.hpp"
#include "roots.hpp"
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
  // What the closed form's roundings may add (a few ulps of the coordinates' size, per unit
  // length).
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

  // Light along every geodesic: every geodesic from h to the light's copy l no longer than reach.
  // Seen from h (left translation to the origin), with the symmetric height Z_s = Z - X Y / 2 of
  // the target (X, Y, Z) and rho = |(X, Y)|, the geodesic of turning angle theta = w t has
  //   rho = c t |S(theta / 2)|,   Z_s = theta + c^2 t^2 F(theta) / 2,   c^2 + w^2 = 1
  // (the closed form: its x y / 2 cancels the twist term of z), so theta solves
  //   height(theta) = theta + rho^2 F(theta) / (2 S(theta / 2)^2) = Z_s
  // and t^2 = theta^2 + rho^2 / S(theta / 2)^2. height is odd; for theta > 0 it increases from 0 to
  // infinity on (0, 2 pi) (the one geodesic of branch 0, the shortest) and falls from and returns
  // to infinity on each (2 pi k, 2 pi (k + 1)) (two geodesics of branch k where its minimum is
  // below |Z_s|, none elsewhere), where t >= |theta| > 2 pi k: within a reach below 2 pi, one
  // geodesic per copy. On the axis (rho = 0) the geodesics of every branch k >= 1 form cones that
  // focus there: only the vertical one is kept. Area density: rotations about the axis are
  // isometries of the symmetric model, so in cylinder coordinates (rho, psi, Z_s) of the end, psi =
  // a + theta / 2,
  //   r^2 |det d exp| = |d(rho, psi, Z_s) / d(t, a, w)| rho = rho |rho_t Z_w - rho_w Z_t|
  // (the sphere of directions has area da dw).
  static void connections(const Vec3& h, const Vec3& l, double reach,
                          std::vector<LightPath>& paths) {
    const double X = l[0] - h[0], Y = l[1] - h[1], Z = l[2] - h[2] - h[0] * Y;
    const double rho = std::hypot(X, Y), symmetric = Z - 0.5 * X * Y,
                 up = symmetric < 0.0 ? -1.0 : 1.0;
    const double lift = std::abs(symmetric);
    if (!(rho <= reach) || !(shortest_for_height(lift) <= reach)) return;
    const bool axis =
        !(rho > kAxis * (1.0 + lift));  // the cones focus there: the vertical geodesic
    // one geodesic of turning angle up * theta (theta >= 0), if no longer than reach
    const auto add = [&](double theta) {
      theta *= up;
      const double half = 0.5 * theta, S = sin_over(half), lateral = axis ? 0.0 : rho / S;
      const double t = std::sqrt(theta * theta + lateral * lateral);
      if (!(t <= reach) || !(t > 0.0)) return;
      // at the origin: (c cos a, c sin a) = (X + iY) e^{-i theta/2} / (t S), w = theta / t
      const double ch = std::cos(half), sh = std::sin(half), w = theta / t, c2 = sq(lateral / t);
      const double vx = axis ? 0.0 : (X * ch + Y * sh) / (t * S);
      const double vy = axis ? 0.0 : (Y * ch - X * sh) / (t * S);
      const double F = excess(theta), dF = excess_derivative(theta), dS = sin_over_derivative(half);
      const double rho_t = c2 * t * S * ch,
                   rho_w = t * t * S * (0.5 * c2 * t * dS - w * S);  // times rho
      const double z_t = w + c2 * t * (F + 0.5 * theta * dF);
      const double z_w = t - w * t * t * F + 0.5 * c2 * t * t * t * dF;
      paths.push_back({vector4({vx, vy, w + h[0] * vy}), t,
                       floored_falloff(std::abs(rho_t * z_w - rho_w * z_t))});
    };
    if (axis) {
      add(lift);
      return;
    }
    const double tolerance = 1e-15 * (1.0 + lift);
    const auto f = [&](double theta) { return height(theta, rho) - lift; };
    // branch 0: from the guess theta (1 + rho^2 / 12) = |Z_s| (height's slope at 0) towards 2 pi
    double hi = std::min(lift / (1.0 + rho * rho / 12.0), kPi), f_hi = f(hi);
    for (int i = 0; i < 64 && f_hi < 0.0; ++i) f_hi = f(hi = 0.5 * (hi + 2.0 * kPi));
    if (f_hi >= 0.0) add(bracketed_root(f, 0.0, hi, -lift, f_hi, tolerance));
    // branch k >= 1: the geodesics there are longer than 2 pi k
    for (int k = 1; 2.0 * kPi * k <= reach; ++k)
      roots_about_minimum(f, 2.0 * kPi * k, 2.0 * kPi * (k + 1), tolerance, add);
  }

 private:
  // Targets closer than this to the axis (relative to 1 + |Z_s|) count as on it.
  static constexpr double kAxis = 1e-12;
  static double sq(double x) { return x * x; }
  // Z_s of the geodesic of turning angle theta that ends at rho from the axis (connections).
  static double height(double theta, double rho) {
    return theta + 0.5 * sq(rho / sin_over(0.5 * theta)) * excess(theta);
  }
  // A lower bound of the length of any curve that rises by |Z_s| = lift: its vertical part is at
  // most its length L and the area its shadow encloses with the chord (what it adds to Z_s) at
  // most L^2 / pi (isoperimetric), so lift <= L + L^2 / pi.
  static double shortest_for_height(double lift) {
    return 0.5 * kPi * (std::sqrt(1.0 + 4.0 * lift / kPi) - 1.0);
  }
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
      return theta * (1.0 / 6.0 - q * (1.0 / 120.0 -
                                       q * (1.0 / 5040.0 - q * (1.0 / 362880.0 - q / 39916800.0))));
    }
    return (theta - std::sin(theta)) / (theta * theta);
  }
  // d/du sin(u) / u and d/dtheta (theta - sin theta) / theta^2, by their series where they cancel.
  static double sin_over_derivative(double u) {
    if (std::abs(u) < 0.1) {
      const double q = u * u;
      return u * (-1.0 / 3.0 + q * (1.0 / 30.0 - q * (1.0 / 840.0 - q / 45360.0)));
    }
    return (u * std::cos(u) - std::sin(u)) / (u * u);
  }
  static double excess_derivative(double theta) {
    if (std::abs(theta) < 0.1) {
      const double q = theta * theta;
      return 1.0 / 6.0 -
             q * (1.0 / 40.0 - q * (1.0 / 1008.0 - q * (1.0 / 51840.0 - q / 4435200.0)));
    }
    return (theta * (1.0 - std::cos(theta)) - 2.0 * (theta - std::sin(theta))) /
           (theta * theta * theta);
  }
};

}  // namespace thurston
