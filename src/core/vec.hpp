// Small fixed-size vectors and matrices shared by the kernels and the tracer.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <limits>

// The hot path's small functions, inlined where the compiler's budget would stop (the walk loop
// is one function per kernel; see benchmarks/bench_tracer.py).
#if defined(__GNUC__) || defined(__clang__)
#define THURSTON_HOT inline __attribute__((always_inline))
#else
#define THURSTON_HOT inline
#endif

namespace thurston {

using Vec3 = std::array<double, 3>;
using Vec4 = std::array<double, 4>;
using Mat4 = std::array<double, 16>;  // row-major unless named otherwise

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kPi = 3.14159265358979323846;

inline double dot3(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
inline double dot4(const Vec4& a, const Vec4& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
}
inline Vec3 sub3(const Vec3& a, const Vec3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
inline Vec3 add3(const Vec3& a, const Vec3& b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }
inline Vec3 scaled3(double s, const Vec3& a) { return {s * a[0], s * a[1], s * a[2]}; }
inline double norm3(const Vec3& a) { return std::sqrt(dot3(a, a)); }
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
inline Vec3 head3(const Vec4& a) { return {a[0], a[1], a[2]}; }
inline Vec4 point4(const Vec3& x) { return {x[0], x[1], x[2], 1.0}; }
inline Vec4 vector4(const Vec3& v) { return {v[0], v[1], v[2], 0.0}; }

// 1 / sqrt(q) for q > 0. Within rounding of 1, the usual case after an isometry, one Newton step
// from 1 is as exact (error 3/8 (q - 1)^2) and avoids a slow square root and division.
inline double inverse_sqrt(double q) {
  const double e = q - 1.0;
  return std::abs(e) < 1e-8 ? 1.0 - 0.5 * e : 1.0 / std::sqrt(q);
}

// Solves A x = b for a 3x3 A (rows) by Cramer's rule; false if A is (numerically) singular.
inline bool solve3(const std::array<Vec3, 3>& A, const Vec3& b, Vec3& x) {
  const double det = dot3(A[0], cross3(A[1], A[2]));
  const double size = norm3(A[0]) * norm3(A[1]) * norm3(A[2]);
  if (!(std::abs(det) > 1e-13 * size)) return false;
  // columns of the inverse are the cross products of the rows
  const Vec3 c0 = cross3(A[1], A[2]), c1 = cross3(A[2], A[0]), c2 = cross3(A[0], A[1]);
  for (int i = 0; i < 3; ++i) x[i] = (c0[i] * b[0] + c1[i] * b[1] + c2[i] * b[2]) / det;
  return true;
}

// An affine map of the chart, x -> L x + t, as a 3x4 row-major matrix [L | t].
struct Affine {
  std::array<double, 12> m{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};

  Vec3 point(const Vec3& x) const {
    Vec3 y;
    for (int r = 0; r < 3; ++r)
      y[r] = m[4 * r] * x[0] + m[4 * r + 1] * x[1] + m[4 * r + 2] * x[2] + m[4 * r + 3];
    return y;
  }
  // The covector c of the image of a chart plane: c . (x, 1) = plane . (A x, 1) for the plane's
  // covector given in the target's chart, i.e. the pull-back by this map (L^T n, n . t + d).
  Vec4 pull_back(const Vec4& plane) const {
    Vec4 c{0.0, 0.0, 0.0, plane[3]};
    for (int r = 0; r < 3; ++r) {
      for (int k = 0; k < 3; ++k) c[k] += plane[r] * m[4 * r + k];
      c[3] += plane[r] * m[4 * r + 3];
    }
    return c;
  }
  // The inverse map; false where L is (numerically) singular.
  bool inverse(Affine& out) const {
    const std::array<Vec3, 3> rows{{{m[0], m[1], m[2]}, {m[4], m[5], m[6]}, {m[8], m[9], m[10]}}};
    for (int c = 0; c < 4; ++c) {  // the columns of [L^-1 | -L^-1 t]
      Vec3 column;
      const Vec3 rhs =
          c < 3 ? Vec3{double(c == 0), double(c == 1), double(c == 2)} : Vec3{-m[3], -m[7], -m[11]};
      if (!solve3(rows, rhs, column)) return false;
      for (int r = 0; r < 3; ++r) out.m[4 * r + c] = column[r];
    }
    return true;
  }
};

}  // namespace thurston
