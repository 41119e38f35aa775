// Sol: R^3 with the metric e^{2z} dx^2 + e^{-2z} dy^2 + dz^2.
// Geodesics have no elementary closed form. Along one, p_x = e^{2z} x' and p_y = e^{-2z} y' are
// constant, which leaves z'' = p_x^2 e^{-2z} - p_y^2 e^{2z} with x' = p_x e^{-2z}, y' = p_y e^{2z}:
// this reduced system is integrated by an error-controlled Dormand-Prince 5(4) method, started
// from the origin by the isometry that moves the point there (so far from z = 0 it is as accurate).
#pragma once

#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <utility>

#include "vec.hpp"

namespace thurston {

struct SolFlow {
  // The geodesic from p with unit chart velocity v at arclength t; `accuracy` bounds the position
  // error the integration may add (chart units at p's scale), `error` is its estimate.
  void flow(const Vec3& p, const Vec3& v, double t, double accuracy, Vec3& xt, Vec3& vt,
            double& error) const {
    // (x, y, z) -> (e^{z0} (x - x0), e^{-z0} (y - y0), z - z0) is an isometry to the origin
    const double ez = std::exp(p[2]), iez = 1.0 / ez;
    const double px = ez * v[0], py = iez * v[1];
    State s{0.0, 0.0, 0.0, v[2]};
    const double scale = std::max(ez, iez);  // local position errors grow by at most this
    error = integrate(px, py, s, t, std::max(accuracy / scale, 1e-15));
    const double e2 = std::exp(2.0 * s.z);
    xt = {p[0] + iez * s.x, p[1] + ez * s.y, p[2] + s.z};
    vt = {iez * px / e2, ez * py * e2, s.zd};
    error *= scale;
  }

  // x'' = -2 x' z', y'' = 2 y' z', z'' = e^{2z} x'^2 - e^{-2z} y'^2, with |e^z x'|, |e^-z y'|,
  // |z'| <= 1 (unit speed), p_x, p_y constant and |z - z0| <= h over the step.
  double acceleration_bound(const Vec3& p, const Vec3& v, double h) const {
    const double low = p[2] - h, high = p[2] + h;
    const double Px = std::abs(std::exp(2.0 * p[2]) * v[0]), Py = std::abs(std::exp(-2.0 * p[2]) * v[1]);
    const double dx = std::min(Px * std::exp(-2.0 * low), std::exp(-low));
    const double dy = std::min(Py * std::exp(2.0 * high), std::exp(high));
    const double ddz = std::min(1.0, std::max(Px * Px * std::exp(-2.0 * low), Py * Py * std::exp(2.0 * high)));
    return std::sqrt(4.0 * dx * dx + 4.0 * dy * dy + ddz * ddz);
  }
  // Sectional curvatures lie in [-1, 1], so nearby geodesics separate at most like e^t.
  double growth_rate() const { return 1.0; }

  double dot(const Vec3& p, const Vec3& a, const Vec3& b) const {
    const double e2 = std::exp(2.0 * p[2]);
    return e2 * a[0] * b[0] + a[1] * b[1] / e2 + a[2] * b[2];
  }
  Vec3 raise(const Vec3& p, const Vec3& n) const {
    const double e2 = std::exp(2.0 * p[2]);
    return {n[0] / e2, e2 * n[1], n[2]};
  }
  double volume_density(const Vec3&) const { return 1.0; }
  // The chart length of p moved by the isometry that takes q to the origin.
  double separation(const Vec3& q, const Vec3& p) const {
    const double ez = std::exp(q[2]);
    const Vec3 d{ez * (p[0] - q[0]), (p[1] - q[1]) / ez, p[2] - q[2]};
    return norm3(d);
  }

 private:
  struct State {
    double x, y, z, zd;
  };
  static State rate(double px, double py, const State& s) {
    const double e2 = std::exp(2.0 * s.z), ie2 = 1.0 / e2;
    return {px * ie2, py * e2, s.zd, px * px * ie2 - py * py * e2};
  }
  static State axpy(const State& s, double h, std::initializer_list<std::pair<double, const State*>> terms) {
    State r = s;
    for (const auto& [a, k] : terms) {
      r.x += h * a * k->x;
      r.y += h * a * k->y;
      r.z += h * a * k->z;
      r.zd += h * a * k->zd;
    }
    return r;
  }

  // Integrates s over [0, t] with local errors per unit length below accuracy / max(t, 1), so that
  // they sum to at most `accuracy`; returns the sum of the accepted local error estimates.
  static double integrate(double px, double py, State& s, double t, double accuracy) {
    if (!(t > 0.0)) return 0.0;
    const double per_length = accuracy / std::max(t, 1.0);
    double done = 0.0, h = std::min(t, 0.25), total = 0.0;
    State k1 = rate(px, py, s);
    for (int steps = 0; done < t && steps < 100000; ++steps) {
      h = std::min(h, t - done);
      const State k2 = rate(px, py, axpy(s, h, {{1.0 / 5, &k1}}));
      const State k3 = rate(px, py, axpy(s, h, {{3.0 / 40, &k1}, {9.0 / 40, &k2}}));
      const State k4 = rate(px, py, axpy(s, h, {{44.0 / 45, &k1}, {-56.0 / 15, &k2}, {32.0 / 9, &k3}}));
      const State k5 = rate(px, py, axpy(s, h, {{19372.0 / 6561, &k1}, {-25360.0 / 2187, &k2},
                                                 {64448.0 / 6561, &k3}, {-212.0 / 729, &k4}}));
      const State k6 = rate(px, py, axpy(s, h, {{9017.0 / 3168, &k1}, {-355.0 / 33, &k2},
                                                 {46732.0 / 5247, &k3}, {49.0 / 176, &k4},
                                                 {-5103.0 / 18656, &k5}}));
      const State next = axpy(s, h, {{35.0 / 384, &k1}, {500.0 / 1113, &k3}, {125.0 / 192, &k4},
                                     {-2187.0 / 6784, &k5}, {11.0 / 84, &k6}});
      const State k7 = rate(px, py, next);
      // the difference of the 5th- and embedded 4th-order solutions
      const State e = axpy(State{0, 0, 0, 0}, h, {{71.0 / 57600, &k1}, {-71.0 / 16695, &k3},
                                                  {71.0 / 1920, &k4}, {-17253.0 / 339200, &k5},
                                                  {22.0 / 525, &k6}, {-1.0 / 40, &k7}});
      const double err = std::max({std::abs(e.x), std::abs(e.y), std::abs(e.z), std::abs(e.zd)});
      const double allowed = per_length * h;
      if (err <= allowed || h < 1e-12) {
        s = next;
        k1 = k7;  // first same as last
        done += h;
        total += err;
      }
      // the usual controller: the step that would have met the tolerance, with a safety factor
      const double factor = err > 0.0 ? 0.9 * std::pow(allowed / err, 0.2) : 5.0;
      h *= std::clamp(factor, 0.2, 5.0);
    }
    return total;
  }
};

}  // namespace thurston
