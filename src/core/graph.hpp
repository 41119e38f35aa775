// Graphs of Gaussians: R^3 with the metric g = I + grad f grad f^T of the graph of
//   f(x) = s . x + sum_b h_b exp(-sum_i (x_i - c_bi)^2 / (2 w_bi^2))
// in R^4 (geometries/graph.py, docs/mathematics.md#graphs-of-gaussians), its bumps repeated on the
// lattice of `period` where one is given (the flat 3-torus of that lattice). A bump's lattice sum
// factorises by axes: prod_i S_i with S_i the 1-d sums of exp(-u^2 / (2 w_i^2)) over the images
// |n| <= m_i (Python's image counts), so f, grad f and Hess f cost 3 (2 m + 1) exponentials a bump.
// Geodesics x'' = -grad f (x'^T Hess f x') / (1 + |grad f|^2) have no closed form: segments are
// Dormand-Prince 5(4) steps with their local error held below the accuracy asked for, evaluated
// anywhere by one more step from the knot below. No light paths (connections).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include "affine_chart.hpp"
#include "kernel.hpp"
#include "segmented_flow.hpp"
#include "vec.hpp"

namespace thurston {

struct GraphFlow : AffineChart {
  static constexpr bool kSegmentBounds = false;
  // Values per bump in the parameters: centre (3), height, width (3), image counts (3).
  static constexpr int kBumpValues = 10;

  struct Bump {
    Vec3 centre;
    double height;
    Vec3 width;
    std::array<int, 3> images;
  };
  Vec3 period{0.0, 0.0, 0.0};  // 0: no period (R^3)
  Vec3 slope{0.0, 0.0, 0.0};
  std::vector<Bump> bumps;
  double hessian_bound = 0.0;  // of |Hess f| (Frobenius) over R^3: the growth rate

  GraphFlow() = default;
  // The parameters of geometries/graph.py's kernel_parameters: period, slope, then the bumps.
  // Empty: the flat graph (f = 0). false where they are not such a list.
  static bool from_parameters(const std::vector<double>& p, GraphFlow& flow) {
    flow = GraphFlow();
    if (p.empty()) return true;
    if (p.size() < 6 || (p.size() - 6) % kBumpValues != 0) return false;
    for (double v : p)
      if (!std::isfinite(v)) return false;
    flow.period = {p[0], p[1], p[2]};
    flow.slope = {p[3], p[4], p[5]};
    const bool periodic = p[0] > 0.0 && p[1] > 0.0 && p[2] > 0.0;
    if (!periodic && (p[0] != 0.0 || p[1] != 0.0 || p[2] != 0.0)) return false;
    for (std::size_t k = 6; k < p.size(); k += kBumpValues) {
      Bump b{{p[k], p[k + 1], p[k + 2]},
             p[k + 3],
             {p[k + 4], p[k + 5], p[k + 6]},
             {int(p[k + 7]), int(p[k + 8]), int(p[k + 9])}};
      for (int a = 0; a < 3; ++a)
        if (!(b.width[a] > 0.0) || b.images[a] < 0 || b.images[a] > 64 ||
            (!periodic && b.images[a] != 0))
          return false;
      flow.bumps.push_back(b);
    }
    // |Hess G|_F <= |h| sqrt(sum_ij (max|S_i''| or max|S_i'| max|S_j'|)^2 prod others' max S)
    for (const Bump& b : flow.bumps) {
      Vec3 S, dS, ddS;
      for (int a = 0; a < 3; ++a) {
        const double w = b.width[a], n = 2.0 * b.images[a] + 1.0;
        S[a] = n;                            // every image at most 1, ...
        dS[a] = n * 0.6065306597126334 / w;  // ... |u / w^2| e^{-u^2 / 2w^2} <= e^{-1/2} / w
        ddS[a] = n / (w * w);                // |u^2 / w^4 - 1 / w^2| e^{...} <= 1 / w^2
      }
      double sum = 0.0;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          const int k = 3 - i - j;
          const double term =
              i == j ? ddS[i] * S[(i + 1) % 3] * S[(i + 2) % 3] : dS[i] * dS[j] * S[k];
          sum += term * term;
        }
      flow.hessian_bound += std::abs(b.height) * std::sqrt(sum);
    }
    return true;
  }

  // f's gradient and Hessian at x (value: f itself where asked).
  void terms(const Vec3& x, Vec3& grad, std::array<double, 9>& hess,
             double* value = nullptr) const {
    grad = slope;
    hess.fill(0.0);
    if (value) *value = dot3(slope, x);
    for (const Bump& b : bumps) {
      Vec3 S, dS, ddS;
      axis_sums(b, x, S, dS, ddS);
      const double h = b.height;
      if (value) *value += h * S[0] * S[1] * S[2];
      for (int i = 0; i < 3; ++i) {
        const int j1 = (i + 1) % 3, j2 = (i + 2) % 3;
        grad[i] += h * dS[i] * S[j1] * S[j2];
        hess[4 * i] += h * ddS[i] * S[j1] * S[j2];
        const double off = h * dS[i] * dS[j1] * S[j2];
        hess[3 * i + j1] += off;
        hess[3 * j1 + i] += off;
      }
    }
  }

  Vec3 acceleration(const Vec3& x, const Vec3& u) const {
    Vec3 g;
    std::array<double, 9> H;
    terms(x, g, H);
    double q = 0.0;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) q += u[i] * H[3 * i + j] * u[j];
    return scaled3(-q / (1.0 + dot3(g, g)), g);
  }

  // Dormand-Prince 5(4): the state (x, u) after a step h, and the embedded error estimate.
  void step(const Vec3& x, const Vec3& u, double h, Vec3& x5, Vec3& u5, double* error) const {
    static constexpr double a21 = 1.0 / 5, a31 = 3.0 / 40, a32 = 9.0 / 40, a41 = 44.0 / 45,
                            a42 = -56.0 / 15, a43 = 32.0 / 9, a51 = 19372.0 / 6561,
                            a52 = -25360.0 / 2187, a53 = 64448.0 / 6561, a54 = -212.0 / 729,
                            a61 = 9017.0 / 3168, a62 = -355.0 / 33, a63 = 46732.0 / 5247,
                            a64 = 49.0 / 176, a65 = -5103.0 / 18656, b1 = 35.0 / 384,
                            b3 = 500.0 / 1113, b4 = 125.0 / 192, b5 = -2187.0 / 6784,
                            b6 = 11.0 / 84, e1 = 71.0 / 57600, e3 = -71.0 / 16695, e4 = 71.0 / 1920,
                            e5 = -17253.0 / 339200, e6 = 22.0 / 525, e7 = -1.0 / 40;
    std::array<Vec3, 7> kx, ku;
    const auto stage = [&](int s, std::initializer_list<double> a) {
      Vec3 xs = x, us = u;
      int j = 0;
      for (double c : a) {
        xs = add3(xs, scaled3(h * c, kx[j]));
        us = add3(us, scaled3(h * c, ku[j]));
        ++j;
      }
      kx[s] = us;
      ku[s] = acceleration(xs, us);
    };
    stage(0, {});
    stage(1, {a21});
    stage(2, {a31, a32});
    stage(3, {a41, a42, a43});
    stage(4, {a51, a52, a53, a54});
    stage(5, {a61, a62, a63, a64, a65});
    x5 = x;
    u5 = u;
    const double b[6] = {b1, 0.0, b3, b4, b5, b6};
    for (int j = 0; j < 6; ++j) {
      x5 = add3(x5, scaled3(h * b[j], kx[j]));
      u5 = add3(u5, scaled3(h * b[j], ku[j]));
    }
    if (!error) return;
    kx[6] = u5;
    ku[6] = acceleration(x5, u5);
    const double e[7] = {e1, 0.0, e3, e4, e5, e6, e7};
    Vec3 ex{0, 0, 0}, eu{0, 0, 0};
    for (int j = 0; j < 7; ++j) {
      ex = add3(ex, scaled3(h * e[j], kx[j]));
      eu = add3(eu, scaled3(h * e[j], ku[j]));
    }
    // the position error, and the velocity's over the next unit of length
    *error = std::max(norm3(ex), norm3(eu));
  }

  // A stretch of geodesic: adaptive steps whose knots are kept; at(t) is one step from the knot
  // below (a shorter step than the accepted one, so within its error).
  struct Segment {
    static constexpr int kMaxKnots = 16;
    const GraphFlow* flow = nullptr;
    int knots = 0;
    double t[kMaxKnots];
    Vec3 x[kMaxKnots], u[kMaxKnots];
    double length = 0.0, error = 0.0;
    void at(double s, Vec3& xs, Vec3& us) const {
      int k = knots - 1;
      while (k > 0 && s < t[k]) --k;
      const double h = s - t[k];
      if (h == 0.0) {
        xs = x[k];
        us = u[k];
        return;
      }
      flow->step(x[k], u[k], h, xs, us, nullptr);
    }
    double acceleration_bound(double h) const { return flow->acceleration_bound(x[0], u[0], h); }
  };

  void segment(const Vec3& p, const Vec3& v, double length, double accuracy, Segment& s) const {
    s.flow = this;
    s.knots = 1;
    s.t[0] = 0.0;
    s.x[0] = p;
    s.u[0] = v;
    s.error = 0.0;
    // per step: the local error allowed, so that the steps of a unit length add up to accuracy
    const double eps = std::max(accuracy, 1e-15);
    double done = 0.0, h = std::min(length, initial_step(p, v, eps));
    Vec3 x = p, u = v;
    while (done < length && s.knots < Segment::kMaxKnots) {
      h = std::min(h, length - done);
      Vec3 x1, u1;
      double err;
      step(x, u, h, x1, u1, &err);
      if (!std::isfinite(err) || !std::isfinite(x1[0] + x1[1] + x1[2])) break;
      const double allowed = eps * std::max(h, 1e-3);
      if (err <= allowed) {
        done += h;
        x = x1;
        u = u1;
        s.error += err;
        s.t[s.knots] = done;
        s.x[s.knots] = x;
        s.u[s.knots] = u;
        ++s.knots;
      }
      // the next step from the error's fifth-order growth, kept within [h / 5, 4 h]
      const double grow = err > 0.0 ? 0.9 * std::pow(allowed / err, 0.2) : 4.0;
      h *= std::clamp(grow, 0.2, 4.0);
      if (!(h > 1e-12)) break;
    }
    s.length = done;
  }

  void flow(const Vec3& p, const Vec3& v, double t, double accuracy, Vec3& xt, Vec3& vt,
            double& error) const {
    flow_by_segments(*this, p, v, t, accuracy, xt, vt, error);
  }

  // |x''| = |grad f| |u^T H u| / (1 + |grad f|^2) <= |H| / 2 (|u| <= 1: g >= I, and
  // a / (1 + a^2) <= 1 / 2), |H| bounded over the ball of radius h about x by the 1-d sums'
  // envelopes at each image's nearest distance to the ball (bounds).
  double acceleration_bound(const Vec3& x, const Vec3&, double h) const {
    double total = 0.0;
    for (const Bump& b : bumps) {
      Vec3 S, dS, ddS;
      axis_bounds(b, x, h, S, dS, ddS);
      double sum = 0.0;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          const double term =
              i == j ? ddS[i] * S[(i + 1) % 3] * S[(i + 2) % 3] : dS[i] * dS[j] * S[3 - i - j];
          sum += term * term;
        }
      total += std::abs(b.height) * std::sqrt(sum);
    }
    return 0.5 * total;
  }
  // Sectional curvatures of the graph are products of principal curvatures, each at most |Hess f|.
  double growth_rate() const { return std::max(hessian_bound, 1e-3); }
  double max_step() const {
    double step = 1.0;
    for (const Bump& b : bumps) step = std::min({step, b.width[0], b.width[1], b.width[2]});
    return step;
  }

  double dot(const Vec3& p, const Vec3& a, const Vec3& b) const {
    const Vec3 g = gradient(p);
    return dot3(a, b) + dot3(g, a) * dot3(g, b);
  }
  Vec3 raise(const Vec3& p, const Vec3& n) const {
    const Vec3 g = gradient(p);
    return sub3(n, scaled3(dot3(g, n) / (1.0 + dot3(g, g)), g));
  }
  Vec3 gradient(const Vec3& p) const {
    Vec3 g;
    std::array<double, 9> H;
    terms(p, g, H);
    return g;
  }

  // No light paths: shooting for them costs some 30 ms a copy of the light per shaded point, so
  // graph spaces render in the pseudo-colour modes only (the library refuses point lights there);
  // every copy within reach counts as missed.
  int connections(const Vec3& h, const Vec3& l, double reach, std::vector<LightPath>&) const {
    return norm3(sub3(l, h)) <= reach ? 1
                                      : 0;  // g >= I: no path is shorter than the chart distance
  }

 private:
  // The 1-d sums S_i, S_i', S_i'' of bump b at x (x reduced into the cell about the centre first).
  void axis_sums(const Bump& b, const Vec3& x, Vec3& S, Vec3& dS, Vec3& ddS) const {
    for (int a = 0; a < 3; ++a) {
      const double w2 = b.width[a] * b.width[a], L = period[a];
      double y = x[a] - b.centre[a];
      if (L > 0.0) y -= L * std::nearbyint(y / L);
      S[a] = dS[a] = ddS[a] = 0.0;
      for (int n = -b.images[a]; n <= b.images[a]; ++n) {
        const double u = y - n * L, c = u / w2, phi = std::exp(-0.5 * u * c);
        S[a] += phi;
        dS[a] -= c * phi;
        ddS[a] += (c * c - 1.0 / w2) * phi;
      }
    }
  }
  // Bounds of |S_i|, |S_i'|, |S_i''| over [x_i - r, x_i + r]: each image's at its nearest distance
  // q0 = (u0 / w)^2 to the interval, by envelopes decreasing in q0: e^{-q/2}, sqrt(q) e^{-q/2} /
  // w and (1 + q) e^{-q/2} / w^2 taken at max(q0, 1) (where the last two peak).
  void axis_bounds(const Bump& b, const Vec3& x, double r, Vec3& S, Vec3& dS, Vec3& ddS) const {
    for (int a = 0; a < 3; ++a) {
      const double w = b.width[a], L = period[a];
      double y = x[a] - b.centre[a];
      if (L > 0.0) y -= L * std::nearbyint(y / L);
      S[a] = dS[a] = ddS[a] = 0.0;
      for (int n = -b.images[a]; n <= b.images[a]; ++n) {
        const double u0 = std::max(std::abs(y - n * L) - r, 0.0) / w, q0 = u0 * u0;
        const double q1 = std::max(q0, 1.0), e1 = std::exp(-0.5 * q1);
        S[a] += std::exp(-0.5 * q0);
        dS[a] += std::sqrt(q1) * e1 / w;
        ddS[a] += (1.0 + q1) * e1 / (w * w);
      }
    }
  }

  double initial_step(const Vec3& x, const Vec3& v, double eps) const {
    const double K = acceleration_bound(x, v, max_step());
    // a fifth-order method's local error ~ (K h)^5 h-ish: start near eps^(1/5) / (1 + K)
    return std::min(max_step(), std::pow(eps, 0.2) / (1.0 + K));
  }
};

}  // namespace thurston
