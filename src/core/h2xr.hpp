// H2xR: the Klein disk x R with the product metric
//   (dx^2 + dy^2) / (1 - r^2) + (x dx + y dy)^2 / (1 - r^2)^2 + dz^2.
// Geodesics in closed form: over the disk the hyperboloid point cosh(a t) P + sinh(a t) / a P'
// (a the horizontal speed), z linear in arclength: straight in the disk, curved in the vertical
// plane of their line. Model vectors (geometries/h2xr.py) are (X1, X2, e^z, X0) with (X1, X2, X0)
// on the hyperboloid, face maps A (+) e^c: projective on the disk, a translation of z.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "chart_planes.hpp"
#include "closed_form.hpp"
#include "kernel.hpp"
#include "vec.hpp"

namespace thurston {

struct H2xRFlow : ChartPlanes, ClosedForm<H2xRFlow> {
  // The geodesic from p with unit chart velocity v at arclength t, through the hyperboloid point
  // P = s (x, y, 1), s = 1 / sqrt(1 - r^2), and its velocity P' = s (u, 0) + s^3 (x . u) (x, y, 1).
  static void geodesic(const Vec3& p, const Vec3& v, double t, Vec3& xt, Vec3& vt) {
    const double q = 1.0 - p[0] * p[0] - p[1] * p[1];
    const double s = 1.0 / std::sqrt(q), xu = p[0] * v[0] + p[1] * v[1], k = xu / q;
    const double P[3] = {s * p[0], s * p[1], s};
    const double dP[3] = {s * (v[0] + k * p[0]), s * (v[1] + k * p[1]), s * k};
    const double a2 = horizontal_speed2(q, v, xu), a = std::sqrt(a2), at = a * t;
    const double ch = std::cosh(at), sh_over = a > 0.0 ? std::sinh(at) / a : t;  // sinh(a t) / a
    double Q[3], dQ[3];
    for (int i = 0; i < 3; ++i) {
      Q[i] = ch * P[i] + sh_over * dP[i];
      dQ[i] = a2 * sh_over * P[i] + ch * dP[i];
    }
    xt = {Q[0] / Q[2], Q[1] / Q[2], p[2] + v[2] * t};
    vt = {(dQ[0] - xt[0] * dQ[2]) / Q[2], (dQ[1] - xt[1] * dQ[2]) / Q[2], v[2]};
  }
  // What the closed form's roundings may add (a few ulps of the coordinates' size, per unit
  // length).
  static double rounding(const Vec3& p, double t) {
    return 4e-16 * (1.0 + std::abs(p[2]) + t) * (1.0 + t);
  }

  // x'' = -2 (x . x') x' / (1 - r^2) in the disk (from the Christoffel symbols), z'' = 0; with
  // a^2 = |x'|^2 / (1 - r^2) + (x . x')^2 / (1 - r^2)^2 (conserved) this is at most
  // 2 a^2 sqrt(1 - r^2) <= 2 a^2 everywhere along the geodesic.
  double acceleration_bound(const Vec3& p, const Vec3& v, double) const {
    const double q = 1.0 - p[0] * p[0] - p[1] * p[1];
    return 2.0 * horizontal_speed2(q, v, p[0] * v[0] + p[1] * v[1]);
  }
  // Sectional curvatures lie in [-1, 0], so nearby geodesics separate at most like e^t.
  double growth_rate() const { return 1.0; }
  double max_step() const { return 1.0; }

  double dot(const Vec3& p, const Vec3& a, const Vec3& b) const {
    const double q = 1.0 - p[0] * p[0] - p[1] * p[1];
    const double xa = p[0] * a[0] + p[1] * a[1], xb = p[0] * b[0] + p[1] * b[1];
    return (a[0] * b[0] + a[1] * b[1]) / q + xa * xb / (q * q) + a[2] * b[2];
  }
  // g^-1 on the disk is (1 - r^2) (I - x x^T).
  Vec3 raise(const Vec3& p, const Vec3& n) const {
    const double q = 1.0 - p[0] * p[0] - p[1] * p[1], xn = p[0] * n[0] + p[1] * n[1];
    return {q * (n[0] - p[0] * xn), q * (n[1] - p[1] * xn), n[2]};
  }

  // Light along every geodesic: the cover's one geodesic from h to the light's copy l (chart
  // points), if no longer than reach: the H^2 geodesic of the disk parts (length d) times the
  // straight z part. The wavefront is H^2's circle of radius d times the flat direction:
  // area density r^2 sinh(d) / d.
  static void connections(const Vec3& h, const Vec3& l, double reach,
                          std::vector<LightPath>& paths) {
    const double sh = 1.0 / std::sqrt(1.0 - h[0] * h[0] - h[1] * h[1]);
    const double sl = 1.0 / std::sqrt(1.0 - l[0] * l[0] - l[1] * l[1]);
    const double P[3] = {sh * h[0], sh * h[1], sh}, Q[3] = {sl * l[0], sl * l[1], sl};
    const double cosh_d = sh * sl * (1.0 - h[0] * l[0] - h[1] * l[1]);
    // W = Q - cosh(d) P, the tangent at P towards Q, of Lorentz length sinh d
    const double W[3] = {Q[0] - cosh_d * P[0], Q[1] - cosh_d * P[1], Q[2] - cosh_d * P[2]};
    const double sinh_d = std::sqrt(std::max(W[0] * W[0] + W[1] * W[1] - W[2] * W[2], 0.0));
    const double d = std::asinh(sinh_d), dz = l[2] - h[2], r = std::hypot(d, dz);
    if (!(r <= reach) || !(r > 0.0)) return;
    // the chart image of W / sinh d (unit in H^2) scaled by d / r, and z at speed dz / r
    const double horizontal = sinh_d > 0.0 ? d / (r * sinh_d * P[2]) : 0.0;
    const Vec3 v{horizontal * (W[0] - h[0] * W[2]), horizontal * (W[1] - h[1] * W[2]), dz / r};
    paths.push_back({vector4(v), r, floored_falloff(r * r * (d > 0.0 ? sinh_d / d : 1.0))});
  }

  // A model point (X1, X2, e^z, X0) and tangent vector as chart (x, 1) and (v, 0).
  static bool to_chart(Vec4& P, Vec4& V) {
    if (!(P[3] > 0.0) || !(P[2] > 0.0)) return false;
    const Vec4 X = P, U = V;
    P = {X[0] / X[3], X[1] / X[3], std::log(X[2]), 1.0};
    V = {(U[0] - P[0] * U[3]) / X[3], (U[1] - P[1] * U[3]) / X[3], U[2] / X[2], 0.0};
    return finite4(P) && finite4(V) && P[0] * P[0] + P[1] * P[1] < 1.0;
  }
  // Light lifts (model points) as chart points (x, 1), for the registry.
  static bool normalise_lift(int, Vec4& X) {
    Vec4 V{};
    return to_chart(X, V);
  }
  // The face map A (+) e^c: A projective on (x, y, 1) (its rows and columns 0, 1, 3), the
  // differential by the quotient rule; z translated by c.
  static void map(const Mat4& M, Vec3& x, Vec3& v) {
    double X[3], dX[3];
    for (int i = 0; i < 3; ++i) {
      const int r = 4 * (i < 2 ? i : 3);
      X[i] = M[r] * x[0] + M[r + 1] * x[1] + M[r + 3];
      dX[i] = M[r] * v[0] + M[r + 1] * v[1];
    }
    const double x0 = X[0] / X[2], x1 = X[1] / X[2];
    v = {(dX[0] - x0 * dX[2]) / X[2], (dX[1] - x1 * dX[2]) / X[2], v[2]};
    x = {x0, x1, x[2] + std::log(M[10])};
  }

 private:
  // a^2, the squared length of the disk part of v at a point with q = 1 - r^2, xu = x . v.
  static double horizontal_speed2(double q, const Vec3& v, double xu) {
    return (v[0] * v[0] + v[1] * v[1]) / q + xu * xu / (q * q);
  }
};

}  // namespace thurston
