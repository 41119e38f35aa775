// One-dimensional root and minimum searches on a bracket, for the connecting geodesics of the
// flows whose connection problem reduces to one unknown along a branch (Nil, SL2).
#pragma once

#include <algorithm>
#include <cmath>
#include <initializer_list>

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

// A root of f beyond `from` (where f = f_from <= 0) towards `end`: the midpoints towards end are
// tried until f is positive at one (at most 64 halvings), and that bracket is solved to tol.
// False where f stayed at or below zero.
template <class F>
bool root_towards(F&& f, double from, double f_from, double end, double tol, double& root) {
  double far = from, f_far = f_from;
  for (int i = 0; i < 64 && f_far <= 0.0; ++i) f_far = f(far = 0.5 * (far + end));
  if (!(f_far > 0.0)) return false;
  root = bracketed_root(f, from, far, f_from, f_far, tol);
  return true;
}

// The roots of f on [lo, hi], where f falls to one minimum and rises again: none where the
// minimum (to 1e-12 hi) is above zero, else the one on each side of it (to tol), each passed to
// add, the side towards lo first.
template <class F, class Add>
void roots_about_minimum(F&& f, double lo, double hi, double tol, Add&& add) {
  const double bottom = unimodal_minimum(f, lo, hi, 1e-12 * hi), f_bottom = f(bottom);
  if (f_bottom > 0.0) return;
  double root;
  for (const double end : {lo, hi})
    if (root_towards(f, bottom, f_bottom, end, tol, root)) add(root);
}

}  // namespace thurston
