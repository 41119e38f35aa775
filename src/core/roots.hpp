// One-dimensional root and minimum searches on a bracket, for the connecting geodesics of the
// flows whose connection problem reduces to one unknown along a branch (Nil, SL2).
#pragma once

#include <algorithm>
#include <cmath>

namespace thurston {

// The root of f in [a, b], where f(a) = fa and f(b) = fb have opposite signs (or one is zero):
// Brent's method (inverse quadratic interpolation and secant steps, bisection where they would
// leave the bracket or shrink it too slowly), to |b - a| <= tol.
template <class F>
double bracketed_root(F&& f, double a, double b, double fa, double fb, double tol) {
  if (fa == 0.0) return a;
  if (fb == 0.0) return b;
  double c = a, fc = fa, d = b - a, e = d;
  for (int iteration = 0; iteration < 200; ++iteration) {
    if ((fb > 0.0 && fc > 0.0) || (fb < 0.0 && fc < 0.0)) {  // c: the bracket's other end
      c = a;
      fc = fa;
      d = e = b - a;
    }
    if (std::abs(fc) < std::abs(fb)) {  // b: the better end
      a = b;
      b = c;
      c = a;
      fa = fb;
      fb = fc;
      fc = fa;
    }
    const double half = 0.5 * (c - b), tol1 = 4e-16 * std::abs(b) + 0.5 * tol;
    if (std::abs(half) <= tol1 || fb == 0.0) return b;
    if (std::abs(e) >= tol1 && std::abs(fa) > std::abs(fb)) {
      const double s = fb / fa;
      double p, q;
      if (a == c) {  // secant
        p = 2.0 * half * s;
        q = 1.0 - s;
      } else {  // inverse quadratic
        const double r = fa / fc, u = fb / fc;
        p = s * (2.0 * half * r * (r - u) - (b - a) * (u - 1.0));
        q = (r - 1.0) * (u - 1.0) * (s - 1.0);
      }
      if (p > 0.0) q = -q;
      p = std::abs(p);
      if (2.0 * p < std::min(3.0 * half * q - std::abs(tol1 * q), std::abs(e * q))) {
        e = d;
        d = p / q;
      } else {
        d = e = half;
      }
    } else {
      d = e = half;
    }
    a = b;
    fa = fb;
    b += std::abs(d) > tol1 ? d : std::copysign(tol1, half);
    fb = f(b);
  }
  return b;
}

// The minimum of a function f that decreases and then increases on [a, b]: golden-section
// search to |b - a| <= tol.
template <class F>
double unimodal_minimum(F&& f, double a, double b, double tol) {
  constexpr double kGolden = 0.3819660112501051;  // (3 - sqrt 5) / 2
  double x1 = a + kGolden * (b - a), x2 = b - kGolden * (b - a);
  double f1 = f(x1), f2 = f(x2);
  while (b - a > tol) {
    if (f1 < f2) {
      b = x2;
      x2 = x1;
      f2 = f1;
      x1 = a + kGolden * (b - a);
      f1 = f(x1);
    } else {
      a = x1;
      x1 = x2;
      f1 = f2;
      x2 = b - kGolden * (b - a);
      f2 = f(x2);
    }
  }
  return 0.5 * (a + b);
}

}  // namespace thurston
