// SL2~: the Poincare disk x R, chart (x, y, phi), w = x + iy, with the metric
//   lam^2 (dx^2 + dy^2) + (dphi + lam (x dy - y dx))^2,   lam = 2 / (1 - |w|^2)
// (geometries/sl2.py). Geodesics in closed form, branch-free: from the origin with unit body
// velocity (a e^{i a0}, c) the element (alpha, beta, phi) of
//   alpha = e^{ict} (C - i c S), beta = S a e^{i(a0 - ct)},  C = cosh sqrt(q), S = (t/2) sinh
//   sqrt(q) / sqrt(q), q = (a^2 - c^2) t^2 / 4 (cos and sin of sqrt(-q) below zero), phi = 2
//   Arg(alpha) unwrapped;
// from any chart state by composing on the left with the element taking the origin there. Model
// vectors are the first rows (Re alpha, Im alpha, Re beta, Im beta) of SU(1,1) matrices, on which
// the face maps (left multiplications and fibre translations) are linear; the chart's phi is read
// back in
// (-2 pi, 2 pi]. Faces are planes of (Klein(w), phi, 1): the lids c2 phi + c3 = 0 (c0 = c1 = 0),
// and the octagon's sides c0 kx + c1 ky + c3 = 0 (c2 = 0), evaluated as (1 + |w|^2) times that, 2
// (c0 x + c1 y) + c3 (1 + |w|^2), a quadric of the chart.
#pragma once

#include <algorithm>
#include <cmath>
#include <complex>
#include <vector>

#include "closed_form.hpp"
#include "kernel.hpp"
#include "roots.hpp"
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
    double C, S;
    radial(a2, c, t, C, S);
    const Complex turn = std::polar(1.0, c * t);
    const Complex alpha = turn * Complex(C, -c * S), beta = S * horizontal / turn;
    const double phi = fibre_angle(a2, c, t, C, S);
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
  // |phi''| <= r^2 a^2 + 2 r |w'| |phi'| / q <= r a (|c| + 2 r a), r = |w| at most tanh((d0 + a h)
  // / 2) over the step (d0 the hyperbolic distance of w from the centre). At least a^2, which
  // bounds 4 |w'|^2 for the faces' own curvature (side_acceleration_bound).
  double acceleration_bound(const Vec3& p, const Vec3& v, double h) const {
    const Complex w(p[0], p[1]), dw(v[0], v[1]);
    const double lam = 2.0 / (1.0 - std::norm(w));
    const double a = lam * std::abs(dw), c = std::abs(v[2] + lam * std::imag(std::conj(w) * dw));
    const double r =
        std::tanh(std::min(std::atanh(std::min(std::abs(w), 1.0 - 1e-16)) + 0.5 * a * h, 20.0));
    return std::max(a * (0.5 * (c + 3.0 * r * a) + r * (c + 2.0 * r * a)), a * a);
  }
  // Sectional curvatures lie in [-7/4, 1/4]: nearby geodesics separate at most like e^(sqrt(7/4)
  // t).
  double growth_rate() const { return 1.3228756555322954; }
  double max_step() const { return 1.0; }
  static double chart_scale(const Vec3&) {
    return 1.0;
  }  // the chart is about isometric over the domain

  double dot(const Vec3& p, const Vec3& a, const Vec3& b) const {
    const double lam = 2.0 / (1.0 - p[0] * p[0] - p[1] * p[1]);
    const double fa = a[2] + lam * (p[0] * a[1] - p[1] * a[0]),
                 fb = b[2] + lam * (p[0] * b[1] - p[1] * b[0]);
    return lam * lam * (a[0] * b[0] + a[1] * b[1]) + fa * fb;
  }
  // g = F^T F with F u = (lam u_x, lam u_y, u_phi + f . u), f = lam (-y, x): g^-1 = F^-1 F^-T.
  Vec3 raise(const Vec3& p, const Vec3& n) const {
    const double lam = 2.0 / (1.0 - p[0] * p[0] - p[1] * p[1]);
    const double fx = -lam * p[1], fy = lam * p[0];
    const double mx = (n[0] - fx * n[2]) / lam, my = (n[1] - fy * n[2]) / lam;
    return {mx / lam, my / lam, n[2] - (fx * mx + fy * my) / lam};
  }

  // Light along every geodesic: every geodesic from h to the light's copies l + (0, 0, 4 pi k)
  // (chart points; the model, SU(1,1), is SL2~ modulo the fibre translation by 4 pi) no longer than
  // reach. Rotations of the disk about the origin are isometries, so seen from h (moved to the
  // origin) the target is its hyperbolic distance d from the fibre through h and its fibre angle
  // Phi, and a geodesic leaving with body velocity (a e^{i a0}, c) reaches them at arclength t
  // where
  //   sinh(d / 2) = a |S| =: sigma,   Phi = phi(t, c)
  // (|w| = a |S| / |C + i c S| and 1 - |w|^2 = 1 / |C + i c S|^2), which a0 does not enter. With
  // k^2 = a^2 - c^2 = 1 - 2 c^2 the first gives t for each c: below |c| = 1/sqrt 2 one t,
  // sinh(k t / 2) = k sigma / a; above it |sin u| = k' sigma / a for u = k' t / 2, k'^2 = -k^2,
  // i.e.
  //   c^2 = (sigma^2 + sin^2 u) / (2 sigma^2 + sin^2 u),   t = 2 u sqrt(2 sigma^2 + sin^2 u) / |sin
  //   u|.
  // Along these curves phi (for c >= 0; c -> -c turns Phi to -Phi) rises monotonically from 0 at
  // c = 0 through the parabolic point to infinity as u -> pi (component 0: the one geodesic to each
  // Phi, the shortest), and on each u in (n pi, (n + 1) pi), n >= 1, falls from and returns to
  // infinity (two geodesics where its minimum is below Phi, none elsewhere), with t >= 2 n pi /
  // k' >= 2 n pi there: within a reach below 2 pi, one geodesic per copy. On the fibre through h
  // (sigma = 0) the geodesics of every u = n pi form cones that focus there: only the fibre itself
  // (t = |Phi|) is kept. Volume: sinh d dd = 2 d(sigma^2) and arg w = a0 + f(t, c), so
  //   r^2 |det d exp| = |d(2 sigma^2, phi) / d(t, c)|
  // (the sphere of directions has area da0 dc). Length bounds for the copies: t >= d, and
  // t >= |Phi| / sqrt 2, since phi' = c - lam Im(conj(w) w') has |phi'| <= |c| + |w| a < sqrt 2.
  static void connections(const Vec3& h, const Vec3& l, double reach,
                          std::vector<LightPath>& paths) {
    const Complex wh(h[0], h[1]), wl(l[0], l[1]), along = 1.0 - std::conj(wh) * wl;
    const Complex w = (wl - wh) / along;  // the target seen from h
    const double r = std::abs(w);
    if (!(r < 1.0)) return;
    const double sigma = r / std::sqrt((1.0 - r) * (1.0 + r)),
                 phi0 = l[2] - h[2] - 2.0 * std::arg(along);
    if (!(2.0 * std::asinh(sigma) <= reach)) return;
    const double widest = kSqrt2 * reach;  // of |Phi|
    for (double k = std::ceil((-widest - phi0) / (4.0 * kPi)); phi0 + 4.0 * kPi * k <= widest;
         ++k) {
      const double Phi = phi0 + 4.0 * kPi * k, up = Phi < 0.0 ? -1.0 : 1.0, P = std::abs(Phi);
      // the geodesic of fibre speed up * c and length t (c >= 0), if no longer than reach
      const auto add = [&](double c, double t) {
        if (t <= reach && t > 0.0) paths.push_back(connection(h, w, r, up * c, t));
      };
      if (!(sigma > kAxis * (1.0 + P))) {  // on the fibre through h
        add(1.0, P);
        continue;
      }
      const double s2 = sigma * sigma, tolerance = 1e-15;
      // component 0, below the parabolic point: t from c in [0, 1/sqrt 2]
      const auto below = [&](double c) {
        const double k = std::sqrt(std::max(1.0 - 2.0 * c * c, 0.0)),
                     x = k * sigma / std::sqrt(1.0 - c * c);
        return 2.0 * sigma / std::sqrt(1.0 - c * c) *
               (x > 1e-8 ? std::asinh(x) / x : 1.0 - x * x / 6.0);
      };
      const auto f_below = [&](double c) { return phase(c, below(c)) - P; };
      const double parabolic = kSqrt2 / 2.0, f_parabolic = f_below(parabolic);
      if (f_parabolic >= 0.0) {
        const double c = bracketed_root(f_below, 0.0, parabolic, -P, f_parabolic, tolerance);
        add(c, below(c));
      }
      // above it (and the components n >= 1): c and t from u
      const auto c_of = [&](double u) {
        const double s = sq(std::sin(u));
        return std::sqrt((s2 + s) / (2.0 * s2 + s));
      };
      const auto t_of = [&](double u) {  // (at u = 0 the parabolic point's 2 sqrt 2 sigma)
        const double s = std::sin(u);
        return u > 0.0 ? 2.0 * u * std::sqrt(2.0 * s2 + s * s) / std::abs(s) : 2.0 * kSqrt2 * sigma;
      };
      const auto f_above = [&](double u) { return phase(c_of(u), t_of(u)) - P; };
      const auto add_above = [&](double u) { add(c_of(u), t_of(u)); };
      double u;
      if (f_parabolic < 0.0 &&
          root_towards(f_above, 0.0, f_parabolic, kPi, tolerance * (1.0 + kPi), u))
        add_above(u);
      for (int n = 1; 2.0 * kPi * n <= reach; ++n)
        roots_about_minimum(f_above, kPi * n, kPi * (n + 1), tolerance * (1.0 + kPi * (n + 1)),
                            add_above);
    }
  }

  // A model point (Re alpha, Im alpha, Re beta, Im beta) and tangent vector as chart (x, 1), (v,
  // 0).
  static bool to_chart(Vec4& P, Vec4& V) {
    const Complex alpha(P[0], P[1]), beta(P[2], P[3]), da(V[0], V[1]), db(V[2], V[3]);
    if (!(std::norm(alpha) > std::norm(beta))) return false;
    const Complex ca = std::conj(alpha), w = beta / ca,
                  dw = db / ca - beta * std::conj(da) / (ca * ca);
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
  static constexpr double kSqrt2 = 1.4142135623730951;
  // Targets closer than this to the fibre through h (sigma relative to 1 + |Phi|) count as on it.
  static constexpr double kAxis = 1e-12;
  static double sq(double x) { return x * x; }

  // C = cosh sqrt(s2) and S = (t/2) sinh(sqrt s2) / sqrt(s2) for s2 = (a^2 - c^2) t^2 / 4 (cos and
  // sin of sqrt(-s2) below zero), a2 = a^2: the radial part of the geodesic from the origin.
  static void radial(double a2, double c, double t, double& C, double& S) {
    const double s2 = 0.25 * (a2 - c * c) * t * t;
    if (s2 >= 0.0) {
      const double s = std::sqrt(s2);
      C = std::cosh(s);
      S = 0.5 * t * (s > 0.0 ? std::sinh(s) / s : 1.0);
    } else {
      const double s = std::sqrt(-s2);
      C = std::cos(s);
      S = 0.5 * t * std::sin(s) / s;
    }
  }
  // phi = 2 Arg(alpha), alpha = e^{ict} (C - i c S), unwrapped: Arg(alpha) turns without bound
  // where a < |c|, and e^{-i sigma} alpha keeps a positive real part.
  static double fibre_angle(double a2, double c, double t, double C, double S) {
    const double sigma = (c - 0.5 * std::copysign(std::sqrt(std::max(c * c - a2, 0.0)), c)) * t;
    return 2.0 * sigma + 2.0 * std::arg(std::polar(1.0, c * t - sigma) * Complex(C, -c * S));
  }
  // phi at arclength t of a geodesic from the origin with unit body velocity of fibre part c.
  static double phase(double c, double t) {
    const double a2 = 1.0 - c * c;
    double C, S;
    radial(a2, c, t, C, S);
    return fibre_angle(a2, c, t, C, S);
  }
  // The connecting geodesic of fibre speed c and length t from h towards the target w seen from h
  // (|w| = r): its direction at h, from the body velocity (a e^{i a0}, c) with
  // e^{i a0} = (w / r) sign(S) (C + i c S) / |C + i c S|, carried to h by the element (1, w_h) / n;
  // and its falloff from d(2 sigma^2, phi) / d(t, c) (connections), with S' = C / 2 along t,
  // dC/dq = Shat / 2, q = (1 - 2 c^2) t^2 / 4, S = (t / 2) Shat(q).
  static LightPath connection(const Vec3& h, Complex w, double r, double c, double t) {
    const double a2 = 1.0 - c * c, a = std::sqrt(a2), k2 = a2 - c * c, q = 0.25 * k2 * t * t;
    double C, S;
    radial(a2, c, t, C, S);
    const Complex A(C, -c * S);
    const Complex toward = r > 0.0 ? w / r : Complex(1.0, 0.0);
    const Complex heading = toward * (S < 0.0 ? -1.0 : 1.0) * std::conj(A) / std::abs(A);
    const Complex dw = 0.5 * a * heading;  // the chart velocity at the origin
    const Complex wh(h[0], h[1]);
    const Complex dw_h = dw * (1.0 - std::norm(wh));
    const Vec3 direction{dw_h.real(), dw_h.imag(), c - 2.0 * std::imag(std::conj(wh) * dw)};
    // derivatives along t and c
    const double Shat = 2.0 * S / t;
    const double dShat =
        std::abs(q) < 0.1
            ? 1.0 / 6.0 +
                  q * (1.0 / 60.0 + q * (1.0 / 1680.0 + q * (1.0 / 90720.0 + q / 7983360.0)))
            : (C - Shat) / (2.0 * q);
    const double S_t = 0.5 * C, S_c = 0.5 * t * dShat * (-c * t * t);
    const double C_t = 0.5 * k2 * S, C_c = 0.5 * Shat * (-c * t * t);
    const double area_t = 2.0 * a2 * 2.0 * S * S_t,
                 area_c = 2.0 * (-2.0 * c * S * S + a2 * 2.0 * S * S_c);
    const double phi_t = 2.0 * c + 2.0 * std::imag(Complex(C_t, -c * S_t) / A);
    const double phi_c = 2.0 * t + 2.0 * std::imag(Complex(C_c, -S - c * S_c) / A);
    return {vector4(direction), t, floored_falloff(std::abs(area_t * phi_c - area_c * phi_t))};
  }

  // The chart state as a model point and tangent: (alpha, beta) = (e^{i phi/2}, w e^{-i phi/2}) /
  // sqrt(1 - |w|^2).
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
