// SL2~: the Poincare disk x R, chart (x, y, phi), w = x + iy, with the metric
//   lam^2 (dx^2 + dy^2) + (dphi + lam (x dy - y dx))^2,   lam = 2 / (1 - |w|^2)
// (geometries/sl2.py). Geodesics in closed form, branch-free: from the origin with unit body velocity
// (a e^{i a0}, c) the element (alpha, beta, phi) of
//   alpha = e^{ict} (C - i c S), beta = S a e^{i(a0 - ct)},  C = cosh sqrt(q), S = (t/2) sinh sqrt(q) / sqrt(q),
//   q = (a^2 - c^2) t^2 / 4 (cos and sin of sqrt(-q) below zero), phi = 2 Arg(alpha) unwrapped;
// from any chart state by composing on the left with the element taking the origin there. Model
// vectors are the first rows (Re alpha, Im alpha, Re beta, Im beta) of SU(1,1) matrices, on which the
// face maps (left multiplications and fibre translations) are linear; the chart's phi is read back in
// (-2 pi, 2 pi]. Faces are planes of (Klein(w), phi, 1): the lids c2 phi + c3 = 0 (c0 = c1 = 0), and
// the octagon's sides c0 kx + c1 ky + c3 = 0 (c2 = 0), evaluated as (1 + |w|^2) times that,
// 2 (c0 x + c1 y) + c3 (1 + |w|^2), a quadric of the chart.
#pragma once

#include <algorithm>
#include <cmath>
#include <complex>

#include "closed_form.hpp"
#include "vec.hpp"

namespace thurston {

struct SL2Flow : ClosedForm<SL2Flow> {
  using Complex = std::complex<double>;

  static void geodesic(const Vec3& p, const Vec3& v, double t, Vec3& xt, Vec3& vt) {
    const Complex w(p[0], p[1]), dw(v[0], v[1]);
    const double q = 1.0 - std::norm(w), lam = 2.0 / q;
    // the body velocity: lam dw horizontally, the connection form's value along the fibre
    const Complex horizontal = lam * dw;
    const double c = v[2] + lam * std::imag(std::conj(w) * dw);
    const double a2 = std::norm(horizontal);
    const double s2 = 0.25 * (a2 - c * c) * t * t;
    double C, S;
    if (s2 >= 0.0) {
      const double s = std::sqrt(s2);
      C = std::cosh(s);
      S = 0.5 * t * (s > 0.0 ? std::sinh(s) / s : 1.0);
    } else {
      const double s = std::sqrt(-s2);
      C = std::cos(s);
      S = 0.5 * t * std::sin(s) / s;
    }
    const Complex turn = std::polar(1.0, c * t);
    const Complex alpha = turn * Complex(C, -c * S), beta = S * horizontal / turn;
    // Arg(alpha) turns without bound where a < |c|; e^{-i sigma} alpha keeps a positive real part
    const double sigma = (c - 0.5 * std::copysign(std::sqrt(std::max(c * c - a2, 0.0)), c)) * t;
    const double phi = 2.0 * sigma + 2.0 * std::arg(alpha * std::polar(1.0, -sigma));
    const Complex out = horizontal / (turn * turn);  // the body velocity at t
    // compose with the element (1, w) / sqrt(q) taking the origin to p
    const Complex wt = beta / std::conj(alpha), along = 1.0 + std::conj(w) * wt;
    const Complex image = (wt + w) / along;
    const double n = std::sqrt(q);
    const Complex ga = (alpha + w * std::conj(beta)) / n, gb = (beta + w * std::conj(alpha)) / n;
    const Complex ca = std::conj(ga), zeta = std::conj(gb) / ca;
    const Complex dimage = 0.5 * out / (ca * ca);
    xt = {image.real(), image.imag(), p[2] + phi - 2.0 * std::arg(along)};
    vt = {dimage.real(), dimage.imag(), c - std::imag(zeta * out)};
  }
  // What the closed form's roundings may add (a few ulps of the coordinates, more near the rim).
  static double rounding(const Vec3& p, double t) {
    const double q = 1.0 - p[0] * p[0] - p[1] * p[1];
    return 8e-16 * (1.0 + std::abs(p[2]) + t) * (1.0 + t) / q;
  }

  // From the geodesic equation (the Christoffel symbols of geometries/sl2.py): with the conserved
  // body speeds a (horizontal) and c (fibre), |w'| = a q / 2 and |phi'| <= |c| + r a, so
  // |w''| <= 4 r |w'|^2 / q + |w'| |phi'| <= (a q / 2)(|c| + 3 r a) and
  // |phi''| <= r^2 a^2 + 2 r |w'| |phi'| / q <= r a (|c| + 2 r a), r = |w| at most tanh((d0 + a h) / 2)
  // over the step (d0 the hyperbolic distance of w from the centre). At least a^2, which bounds
  // 4 |w'|^2 for the faces' own curvature (side_acceleration_bound).
  double acceleration_bound(const Vec3& p, const Vec3& v, double h) const {
    const Complex w(p[0], p[1]), dw(v[0], v[1]);
    const double lam = 2.0 / (1.0 - std::norm(w));
    const double a = lam * std::abs(dw), c = std::abs(v[2] + lam * std::imag(std::conj(w) * dw));
    const double r = std::tanh(std::min(std::atanh(std::min(std::abs(w), 1.0 - 1e-16)) + 0.5 * a * h, 20.0));
    return std::max(a * (0.5 * (c + 3.0 * r * a) + r * (c + 2.0 * r * a)), a * a);
  }
  // Sectional curvatures lie in [-7/4, 1/4]: nearby geodesics separate at most like e^(sqrt(7/4) t).
  double growth_rate() const { return 1.3228756555322954; }
  double max_step() const { return 1.0; }
  static double chart_scale(const Vec3&) { return 1.0; }  // the chart is about isometric over the domain

  double dot(const Vec3& p, const Vec3& a, const Vec3& b) const {
    const double lam = 2.0 / (1.0 - p[0] * p[0] - p[1] * p[1]);
    const double fa = a[2] + lam * (p[0] * a[1] - p[1] * a[0]), fb = b[2] + lam * (p[0] * b[1] - p[1] * b[0]);
    return lam * lam * (a[0] * b[0] + a[1] * b[1]) + fa * fb;
  }
  // g = F^T F with F u = (lam u_x, lam u_y, u_phi + f . u), f = lam (-y, x): g^-1 = F^-1 F^-T.
  Vec3 raise(const Vec3& p, const Vec3& n) const {
    const double lam = 2.0 / (1.0 - p[0] * p[0] - p[1] * p[1]);
    const double fx = -lam * p[1], fy = lam * p[0];
    const double mx = (n[0] - fx * n[2]) / lam, my = (n[1] - fy * n[2]) / lam;
    return {mx / lam, my / lam, n[2] - (fx * mx + fy * my) / lam};
  }
  double volume_density(const Vec3& p) const {
    const double lam = 2.0 / (1.0 - p[0] * p[0] - p[1] * p[1]);
    return lam * lam;
  }
  // Isometry-invariant: where the element taking q to the origin puts p, its hyperbolic distance
  // from the centre and its fibre angle.
  double separation(const Vec3& q, const Vec3& p) const {
    const Complex wq(q[0], q[1]), wp(p[0], p[1]), along = 1.0 - std::conj(wq) * wp;
    const double r = std::abs((wp - wq) / along);
    return std::hypot(2.0 * std::atanh(std::min(r, 1.0 - 1e-16)), p[2] - q[2] - 2.0 * std::arg(along));
  }

  // A model point (Re alpha, Im alpha, Re beta, Im beta) and tangent vector as chart (x, 1), (v, 0).
  static bool to_chart(Vec4& P, Vec4& V) {
    const Complex alpha(P[0], P[1]), beta(P[2], P[3]), da(V[0], V[1]), db(V[2], V[3]);
    if (!(std::norm(alpha) > std::norm(beta))) return false;
    const Complex ca = std::conj(alpha), w = beta / ca, dw = db / ca - beta * std::conj(da) / (ca * ca);
    P = {w.real(), w.imag(), 2.0 * std::arg(alpha), 1.0};
    V = {dw.real(), dw.imag(), 2.0 * std::imag(da / alpha), 0.0};
    return finite4(P) && finite4(V) && std::norm(w) < 1.0;
  }
  // Light lifts (model points) as chart points (x, 1), for the registry.
  static bool normalise_lift(int, Vec4& X) {
    Vec4 V{};
    return to_chart(X, V);
  }
  // The face map M (linear on model vectors) on a chart state, through the model.
  static void map(const Mat4& M, Vec3& x, Vec3& v) {
    Vec4 P, V;
    to_model(x, v, P, V);
    Vec4 Q{}, U{};
    for (int r = 0; r < 4; ++r)
      for (int k = 0; k < 4; ++k) {
        Q[r] += M[4 * r + k] * P[k];
        U[r] += M[4 * r + k] * V[k];
      }
    to_chart(Q, U);
    x = head3(Q);
    v = head3(U);
  }

  // Faces (see the header): the lids' planes (c2 != 0) and the sides' quadrics, negative inside.
  static double side(const Vec4& c, const Vec3& x) {
    if (c[2] != 0.0) return c[2] * x[2] + c[3];
    return 2.0 * (c[0] * x[0] + c[1] * x[1]) + c[3] * (1.0 + x[0] * x[0] + x[1] * x[1]);
  }
  static Vec3 side_gradient(const Vec4& c, const Vec3& x) {
    if (c[2] != 0.0) return {0.0, 0.0, c[2]};
    return {2.0 * (c[0] + c[3] * x[0]), 2.0 * (c[1] + c[3] * x[1]), 0.0};
  }
  // A lid's side has second derivative c2 ph''; a side's at most |gradient| K + 2 |c3| |w'|^2, with
  // |gradient| <= 2 |(c0, c1)| + 2 |c3| on the disk and 4 |w'|^2 <= K (acceleration_bound).
  static double side_acceleration_bound(const Vec4& c, double K) {
    if (c[2] != 0.0) return std::abs(c[2]) * K;
    return (2.0 * std::hypot(c[0], c[1]) + 2.5 * std::abs(c[3])) * K;
  }

 private:
  // The chart state as a model point and tangent: (alpha, beta) = (e^{i phi/2}, w e^{-i phi/2}) / sqrt(1 - |w|^2).
  static void to_model(const Vec3& x, const Vec3& v, Vec4& P, Vec4& V) {
    const Complex w(x[0], x[1]), dw(v[0], v[1]);
    const double q = 1.0 - std::norm(w);
    const Complex alpha = std::polar(1.0 / std::sqrt(q), 0.5 * x[2]), beta = w * std::conj(alpha);
    const double radial = std::real(std::conj(w) * dw) / q;
    const Complex da = alpha * Complex(radial, 0.5 * v[2]);
    const Complex db = beta * Complex(radial, -0.5 * v[2]) + dw * std::conj(alpha);
    P = {alpha.real(), alpha.imag(), beta.real(), beta.imag()};
    V = {da.real(), da.imag(), db.real(), db.imag()};
  }
};

}  // namespace thurston
