// Geodesics of the three constant-curvature spaces in their homogeneous models.
//
// Points are model 4-vectors X; the projective chart is x = X[:3] / X[3] (Euclidean: affine,
// spherical: gnomonic, hyperbolic: Klein), in which geodesics are straight lines.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <limits>

namespace thurston {

using Vec3 = std::array<double, 3>;
using Vec4 = std::array<double, 4>;

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kPi = 3.14159265358979323846;

inline double dot3(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
inline double dot4(const Vec4& a, const Vec4& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
}
inline Vec3 sub3(const Vec3& a, const Vec3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
inline Vec3 cross3(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
inline Vec4 lin4(double s, const Vec4& a, double t, const Vec4& b) {
  return {s * a[0] + t * b[0], s * a[1] + t * b[1], s * a[2] + t * b[2], s * a[3] + t * b[3]};
}
inline Vec4 scaled(double s, const Vec4& a) { return {s * a[0], s * a[1], s * a[2], s * a[3]}; }
inline bool finite4(const Vec4& a) {
  return std::isfinite(a[0]) && std::isfinite(a[1]) && std::isfinite(a[2]) && std::isfinite(a[3]);
}

// 1 / sqrt(q) for q > 0. Within rounding of 1, the usual case after an isometry, one Newton step
// from 1 is as exact (error 3/8 (q - 1)^2) and avoids a slow square root and division.
inline double inverse_sqrt(double q) {
  const double e = q - 1.0;
  return std::abs(e) < 1e-8 ? 1.0 - 0.5 * e : 1.0 / std::sqrt(q);
}

// Curvature k in {+1, 0, -1} fixes the model: S3 (unit sphere in R^4), E3 (w = 1 affine space),
// H3 (upper hyperboloid <X,X> = -1 of the Lorentz form).
struct Space {
  int k;

  // Metric on tangent vectors (and the form the model is a unit sphere of, for k != 0).
  double inner(const Vec4& a, const Vec4& b) const {
    const double s = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    return k == 0 ? s : k > 0 ? s + a[3] * b[3] : s - a[3] * b[3];
  }

  // A geodesic parameter t with the coefficients of X(t) = c P + s V: (cos t, sin t) in S3,
  // (cosh t, sinh t) in H3, (1, t) in E3.
  struct Turn {
    double t, c, s;
  };
  Turn turn(double t) const {
    if (k == 0) return {t, 1.0, t};
    if (k > 0) return {t, std::cos(t), std::sin(t)};
    return {t, std::cosh(t), std::sinh(t)};
  }

  // Point X(t) and velocity X'(t) of the unit-speed geodesic from P with velocity V.
  void advance(const Vec4& P, const Vec4& V, const Turn& u, Vec4& X, Vec4& Xv) const {
    X = lin4(u.c, P, u.s, V);
    Xv = k == 0 ? V : lin4(k > 0 ? -u.s : u.s, P, u.c, V);
  }

  static Vec3 chart(const Vec4& X) {
    const double w = 1.0 / X[3];
    return {X[0] * w, X[1] * w, X[2] * w};
  }

  Vec4 model(const Vec3& x) const {
    const Vec4 Y{x[0], x[1], x[2], 1.0};
    if (k == 0) return Y;
    const double q = dot3(x, x);
    const double s = k > 0 ? 1.0 / std::sqrt(1.0 + q) : 1.0 / std::sqrt(std::max(1.0 - q, 1e-300));
    return scaled(s, Y);
  }

  // The exit from the half-space c . X <= 0: the first t >= 0 at which c . X(t) crosses zero
  // upwards, given a = c . P and b = c . V. A point already (numerically) outside and heading out
  // leaves at t = 0, which is what carries rays across edges and vertices without leaking.
  // exit_order is a cheap key ordered like t (inf where there is no exit), so that the exit search
  // needs transcendental functions only for the winning face, in exit_turn. Written with selects
  // rather than branches (the cases vary unpredictably from face to face) so that it vectorises.
  double exit_order(double a, double b) const {
    if (k == 0) {
      const double t = std::max(0.0, -a / b);
      return b > 0.0 ? t : kInf;
    }
    if (k > 0) {
      // A pseudo-angle on [0, 3) of the direction (x, y) = (b, -a) of the zero, for exit angles
      // in [0, 3 pi / 2) (quadrant + fraction); angles in [-pi / 2, 0) mean outside and leaving: 0.
      const double x = b, y = -a, ax = std::abs(x), ay = std::abs(y);
      const double quadrant = y >= 0.0 ? (x >= 0.0 ? 0.0 : 1.0) : 2.0;
      const double key = quadrant + (((x < 0.0) & (y >= 0.0)) ? ax : ay) / (ax + ay);
      const double leaving = ((y < 0.0) & (x >= 0.0)) ? 0.0 : key;
      return ax + ay > 0.0 ? leaving : kInf;  // else the whole great circle lies in the face plane
    }
    // a cosh t + b sinh t = 0 at exp(2 t) = (b - a) / (b + a).
    const double ratio = (b - a) / (b + a);
    const double inside = b + a > 0.0 ? ratio : kInf;
    const double outside = b > 0.0 ? 1.0 : kInf;
    return a > 0.0 ? outside : inside;
  }
  // The exit search's key: exit_order's in E3 and H3; in S3 one division, -cot t = b / a, for the
  // usual exits t in (0, pi) from inside (a < 0), -inf for t = 0 and +inf for the rest (t >= pi or
  // none), which a valid domain never leaves by first: when every key is +inf, the search falls back
  // to exit_order.
  double exit_key(double a, double b) const {
    if (k <= 0) return exit_order(a, b);
    const double special = (b > 0.0) | ((a > 0.0) & (b >= 0.0)) ? -kInf : kInf;
    return a < 0.0 ? b / a : special;
  }
  void exit_keys(const double* a, const double* b, double* key, std::size_t n) const {
    // One loop per curvature, so that each is a straight-line body.
    if (k == 0)
      for (std::size_t j = 0; j < n; ++j) key[j] = Space{0}.exit_key(a[j], b[j]);
    else if (k > 0)
      for (std::size_t j = 0; j < n; ++j) key[j] = Space{1}.exit_key(a[j], b[j]);
    else
      for (std::size_t j = 0; j < n; ++j) key[j] = Space{-1}.exit_key(a[j], b[j]);
  }
  // S3, for a finite exit_key(a, b) (a < 0): the turn to the exit without a transcendental
  // function: cos t and sin t exactly, t itself only to within kTurnEstimateError (turn_length
  // gives it exactly).
  static constexpr double kTurnEstimateError = 2e-5;
  static Turn s3_exit_turn(double a, double b) {
    const double r = 1.0 / std::sqrt(a * a + b * b);
    const double c = b * r, s = -a * r;
    return {estimate_angle(c, s), c, s};
  }
  // An estimate of the angle t in [0, pi] with (cos t, sin t) = (c, s), s >= 0, to within 1.2e-5
  // (Abramowitz and Stegun 4.4.49 on the octant).
  static double estimate_angle(double c, double s) {
    const double ac = std::abs(c), lo = std::min(ac, s), hi = std::max(ac, s);
    const double z = hi > 0.0 ? lo / hi : 0.0, z2 = z * z;
    double p = z * (0.9998660 + z2 * (-0.3302995 + z2 * (0.1801410 + z2 * (-0.0851330 +
                                                                           z2 * 0.0208351))));
    p = s > ac ? 0.5 * kPi - p : p;
    return c < 0.0 ? kPi - p : p;
  }

  Turn exit_turn(double a, double b) const {  // requires a finite exit_order(a, b)
    if (k == 0) return turn(std::max(0.0, -a / b));
    if (k > 0) {
      const double t = std::atan2(-a, b);
      if (t < 0.0 && t >= -0.5 * kPi) return {0.0, 1.0, 0.0};
      const double r = std::sqrt(a * a + b * b);
      return {t < 0.0 ? t + 2.0 * kPi : t, b / r, -a / r};
    }
    if (a > 0.0) return {0.0, 1.0, 0.0};
    const double r = std::sqrt((b - a) * (b + a));
    return {0.5 * std::log((b - a) / (b + a)), b / r, -a / r};
  }

  // Project (P, V) back onto the model: P a point, V a unit tangent at P. False if degenerate.
  bool renormalise(Vec4& P, Vec4& V) const {
    if (k == 0) {
      if (P[3] == 0.0) return false;
      if (P[3] != 1.0) P = scaled(1.0 / P[3], P);
      V[3] = 0.0;
    } else if (k > 0) {
      const double q = dot4(P, P);
      if (!(q > 0.0)) return false;
      P = scaled(inverse_sqrt(q), P);
      V = lin4(1.0, V, -dot4(V, P), P);
    } else {
      const double q = -inner(P, P);
      if (!(q > 0.0)) return false;
      // (-P, -V) is the same chart ray on the upper sheet, where the domain's covectors apply.
      const double s = std::copysign(inverse_sqrt(q), P[3]);
      P = scaled(s, P);
      V = scaled(s < 0.0 ? -1.0 : 1.0, V);
      V = lin4(1.0, V, inner(V, P), P);
    }
    return normalise(V) && finite4(P);
  }

  // Scale a tangent vector to unit length; false if it has none.
  bool normalise(Vec4& v) const {
    const double q = inner(v, v);
    if (!(q > 0.0) || !std::isfinite(q)) return false;
    v = scaled(inverse_sqrt(q), v);
    return true;
  }

  // Make v tangent at the point X by removing its normal component.
  Vec4 tangent_part(const Vec4& X, const Vec4& v) const {
    if (k == 0) return {v[0], v[1], v[2], 0.0};
    return lin4(1.0, v, k > 0 ? -dot4(v, X) : inner(v, X), X);
  }

  // Tangent vector at H pointing along the geodesic towards the point L (not normalised).
  Vec4 toward(const Vec4& H, const Vec4& L) const {
    return k == 0 ? sub4(L, H) : tangent_part(H, L);
  }

  double distance(const Vec4& A, const Vec4& B) const {
    if (k == 0) return std::sqrt(inner(sub4(A, B), sub4(A, B)));
    if (k > 0) return std::acos(std::clamp(dot4(A, B), -1.0, 1.0));
    return std::acosh(std::max(1.0, -inner(A, B)));
  }

  // Arclength from P to the point X of the geodesic (P, V).
  double arclength(const Vec4& P, const Vec4& V, const Vec4& X) const {
    if (k == 0) return distance(P, X);
    if (k > 0) return std::atan2(dot4(X, V), dot4(X, P));
    return std::atanh(std::clamp(inner(X, V) / -inner(X, P), -1.0, 1.0));
  }

  // Intensity falloff of a point light at distance r: the inverse area of the geodesic sphere,
  // floored so that lights touching a surface stay finite.
  double falloff(double r) const {
    const double rho = k == 0 ? r : k > 0 ? std::sin(r) : std::sinh(r);
    const double floor = 1e-4;
    return 1.0 / std::max(rho * rho, floor * floor);
  }

  // Model normal vector at a point of the chart plane with covector c (c . X = 0 on the plane):
  // the tangent vector N with <N, Y> = c . Y for all Y.
  Vec4 plane_normal(const Vec4& c) const {
    if (k == 0) return {c[0], c[1], c[2], 0.0};
    if (k > 0) return c;
    return {c[0], c[1], c[2], -c[3]};
  }

  // Chart image of the tangent vector dX at the point X, unit length in the chart.
  static Vec3 chart_vector(const Vec4& X, const Vec4& dX) {
    const Vec3 x = chart(X);
    Vec3 d{(dX[0] - x[0] * dX[3]) / X[3], (dX[1] - x[1] * dX[3]) / X[3],
           (dX[2] - x[2] * dX[3]) / X[3]};
    const double n = std::sqrt(dot3(d, d));
    if (n > 0.0) d = {d[0] / n, d[1] / n, d[2] / n};
    return d;
  }

 private:
  static Vec4 sub4(const Vec4& a, const Vec4& b) { return lin4(1.0, a, -1.0, b); }
};

}  // namespace thurston
