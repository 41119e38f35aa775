// Sol: R^3 with the metric e^{2z} dx^2 + e^{-2z} dy^2 + dz^2.
// Geodesics have no elementary closed form. Along one, p_x = e^{2z} x' and p_y = e^{-2z} y' are
// constant, which leaves z'' = p_x^2 e^{-2z} - p_y^2 e^{2z} with x' = p_x e^{-2z}, y' = p_y e^{2z}:
// this reduced system is integrated by a Taylor series method (the series of z', e^{2z} and
// e^{-2z} by their recurrences; order and step from the accuracy asked for, Jorba and Zou's rule),
// started from the origin by the isometry that moves the point there, so that far from z = 0 it is
// as accurate. The first integrals p_x, p_y are kept exactly. Connecting geodesics by Newton's
// method on the exponential map from seeds out of a table of it (connections).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <vector>

#include "affine_chart.hpp"
#include "exp_table.hpp"
#include "kernel.hpp"
#include "segmented_flow.hpp"
#include "vec.hpp"

namespace thurston {

// 1 / k for the series' recurrences and integrals (divisions would dominate them).
inline constexpr auto kReciprocal = [] {
  std::array<double, 32> r{};
  for (int k = 1; k < 32; ++k) r[k] = 1.0 / k;
  return r;
}();

struct SolFlow : AffineChart {
  // The segment's acceleration bound, from its series, is far tighter than the state's.
  static constexpr bool kSegmentBounds = true;
  // A stretch of geodesic from p with unit chart velocity v: Taylor pieces of the reduced system in
  // the coordinates that move p to the origin, evaluated anywhere in [0, length] by Horner's rule.
  struct Segment {
    static constexpr int kMaxOrder = 24;
    static constexpr int kMaxPieces = 8;
    struct Piece {
      double t0, z, x, y, e2;  // start: arclength, local state, e^{2z}
      int order;
      double Q[kMaxOrder + 1], E[kMaxOrder + 1], U[kMaxOrder + 1];  // z', e^{2z}/e2, e^{-2z}e2
    };
    Vec3 p;
    double ez, px, py;  // e^{z0}; the first integrals in local coordinates
    int pieces = 0;
    double length = 0.0;  // what the pieces cover (at most the length asked for)
    double error = 0.0;   // a bound of the position error they add (chart units)
    Piece piece[kMaxPieces];

    // A bound of the chart acceleration |x''| over [0, h] (h <= length), from the pieces' series:
    // the curve's own derivatives, far tighter than a bound for every geodesic of the state.
    double acceleration_bound(double h) const {
      double K2 = 0.0;
      for (int k = 0; k < pieces && piece[k].t0 < h; ++k) {
        const Piece& c = piece[k];
        const double tau = (k + 1 < pieces ? std::min(h, piece[k + 1].t0) : h) - c.t0;
        double dQ = 0.0, dE = 0.0, dU = 0.0, power = 1.0;  // sums of j |c_j| tau^(j-1)
        for (int j = 1; j <= c.order; ++j) {
          dQ += j * std::abs(c.Q[j]) * power;
          dE += j * std::abs(c.E[j]) * power;
          dU += j * std::abs(c.U[j]) * power;
          power *= tau;
        }
        const double ddx = std::abs(px) / (ez * c.e2) * dU, ddy = std::abs(py) * ez * c.e2 * dE;
        K2 = std::max(K2, ddx * ddx + ddy * ddy + dQ * dQ);
      }
      return std::sqrt(K2) * (1.0 + 1e-6);  // the series' truncation, far below this margin
    }

    void at(double t, Vec3& x, Vec3& v) const {
      int k = pieces - 1;
      while (k > 0 && t < piece[k].t0) --k;
      const Piece& c = piece[k];
      const double h = t - c.t0;
      const int N = c.order;
      double dz = 0.0, dx = 0.0, dy = 0.0, zeta = c.Q[N], E = c.E[N], U = c.U[N];
      for (int j = N - 1; j >= 0; --j) {
        zeta = zeta * h + c.Q[j];
        E = E * h + c.E[j];
        U = U * h + c.U[j];
        const double r = kReciprocal[j + 1];
        dz = (dz + c.Q[j] * r) * h;
        dx = (dx + c.U[j] * r) * h;
        dy = (dy + c.E[j] * r) * h;
      }
      const double iez = 1.0 / ez, ie2 = 1.0 / c.e2;
      // back from the local coordinates: (X, Y, Z) -> (x0 + e^{-z0} X, y0 + e^{z0} Y, z0 + Z)
      x = {p[0] + iez * (c.x + px * ie2 * dx), p[1] + ez * (c.y + py * c.e2 * dy), p[2] + c.z + dz};
      v = {iez * px * ie2 * U, ez * py * c.e2 * E, zeta};
    }
  };

  // The segment from p over up to `length`: Taylor pieces whose order grows until the series'
  // last two terms over the piece fall below the accuracy asked for (relative to the local
  // coordinates' unit scale); a piece that needs more than the highest order is shortened to where
  // it reaches it (Jorba and Zou's rule).
  void segment(const Vec3& p, const Vec3& v, double length, double accuracy, Segment& s) const {
    // (x, y, z) -> (e^{z0} (x - x0), e^{-z0} (y - y0), z - z0) is an isometry to the origin
    s.p = p;
    s.ez = std::exp(p[2]);
    s.px = s.ez * v[0];
    s.py = v[1] / s.ez;
    const double scale = std::max(s.ez, 1.0 / s.ez);  // local position errors grow by at most this
    const double eps = std::clamp(accuracy / scale / std::max(length, 1.0), 1e-16, 1e-3);
    double z = 0.0, zd = v[2], x = 0.0, y = 0.0, done = 0.0;
    s.pieces = 0;
    s.error = 0.0;
    while (done < length && s.pieces < Segment::kMaxPieces) {
      Segment::Piece& c = s.piece[s.pieces++];
      c.t0 = done;
      c.z = z;
      c.x = x;
      c.y = y;
      c.e2 = z == 0.0 ? 1.0 : std::exp(2.0 * z);
      const double a = s.px * s.px / c.e2, b = s.py * s.py * c.e2;  // a + b + z'^2 = 1
      double *Q = c.Q, *E = c.E, *U = c.U;
      Q[0] = zd;
      E[0] = U[0] = 1.0;
      const auto size = [&](int k) {
        return std::max({std::abs(Q[k]), std::abs(E[k]), std::abs(U[k]), 1e-300});
      };
      double h = std::min(kMaxStep, length - done), power = h, previous = size(0);
      int N = Segment::kMaxOrder;
      for (int k = 0; k < Segment::kMaxOrder; ++k) {
        const double r = kReciprocal[k + 1];
        Q[k + 1] = (a * U[k] - b * E[k]) * r;
        double sE = 0.0, sU = 0.0;
        for (int j = 0; j <= k; ++j) {
          sE += Q[j] * E[k - j];
          sU += Q[j] * U[k - j];
        }
        E[k + 1] = 2.0 * sE * r;
        U[k + 1] = -2.0 * sU * r;
        const double term = size(k + 1) * power * h;
        if (k >= 2 && term < eps && previous < eps) {
          N = k + 1;
          break;
        }
        previous = term;
        power *= h;
      }
      if (N == Segment::kMaxOrder)  // Jorba and Zou: the step at which the last two terms reach eps
        h = std::min(
            {h, std::pow(eps / size(N - 1), 1.0 / (N - 1)), std::pow(eps / size(N), 1.0 / N)});
      c.order = N;
      if (!(h > 0.0) || !std::isfinite(h)) break;  // the series overflowed: no unit-speed geodesic
      done += h;
      s.error += eps * scale * std::max(1.0, h);
      if (done < length) {  // the next piece starts where this one ends
        Vec3 xe, ve;
        s.length = done;
        s.at(done, xe, ve);
        z = xe[2] - p[2];
        zd = ve[2];
        x = s.ez * (xe[0] - p[0]);
        y = (xe[1] - p[1]) / s.ez;
      }
    }
    s.length = done;
  }

  // The geodesic from p with unit chart velocity v at arclength t (segment after segment).
  void flow(const Vec3& p, const Vec3& v, double t, double accuracy, Vec3& xt, Vec3& vt,
            double& error) const {
    flow_by_segments(*this, p, v, t, accuracy, xt, vt, error);
  }

  // x'' = -2 x' z', y'' = 2 y' z', z'' = e^{2z} x'^2 - e^{-2z} y'^2, with |e^z x'|, |e^-z y'|,
  // |z'| <= 1 (unit speed), p_x, p_y constant, |z - z0| <= h and |z'| <= |z0'| + h |z''|max over
  // the step.
  double acceleration_bound(const Vec3& p, const Vec3& v, double h) const {
    const double ez = std::exp(p[2]), eh = std::exp(h);
    const double Px = std::abs(ez * ez * v[0]), Py = std::abs(v[1] / (ez * ez));
    // e^{-2z} and e^{-z} at most at z0 - h, e^{2z} and e^{z} at most at z0 + h
    const double low2 = eh * eh / (ez * ez), high2 = ez * ez * eh * eh;
    const double dx = std::min(Px * low2, eh / ez), dy = std::min(Py * high2, ez * eh);
    const double ddz = std::min(1.0, std::max(Px * Px * low2, Py * Py * high2));
    const double dz = std::min(1.0, std::abs(v[2]) + h * ddz);
    return std::sqrt(4.0 * dz * dz * (dx * dx + dy * dy) + ddz * ddz);
  }
  // Sectional curvatures lie in [-1, 1], so nearby geodesics separate at most like e^t.
  double growth_rate() const { return 1.0; }
  // The acceleration bound grows like e^{2h} over a step of length h.
  double max_step() const { return 0.5; }

  double dot(const Vec3& p, const Vec3& a, const Vec3& b) const {
    const double e2 = std::exp(2.0 * p[2]);
    return e2 * a[0] * b[0] + a[1] * b[1] / e2 + a[2] * b[2];
  }
  Vec3 raise(const Vec3& p, const Vec3& n) const {
    const double e2 = std::exp(2.0 * p[2]);
    return {n[0] / e2, e2 * n[1], n[2]};
  }

  // Light along every geodesic. Sol is homogeneous, so the geodesics from h to l are those from
  // the origin to T, l moved by the isometry that takes h there, carried back: exp_O(w) = T for
  // the tangent vectors w of the ball of radius reach. The table of exp_O over that ball
  // (prepare_connections) gives a seed in each cell whose linear interpolation reaches T; Newton's
  // method from each converges to the geodesic in that cell. Its falloff: r^2 |det d exp_O(w)|
  // (det g = 1: chart determinants are the frames'). Every geodesic whose seed converges is found:
  // below the shortest period of Sol's oscillation in z, pi sqrt 2 = 4.44, the one geodesic of each
  // copy (the shortest; beyond a period the cut locus begins, Coiculescu and Schwartz); beyond it
  // near caustics, where exp_O folds within a cell, two geodesics may have no seeds or seeds that
  // do not converge: those seeds are counted (the return value), the others cannot be.
  void prepare_connections(double reach) {
    const double radius = std::min(reach, kLongestConnection);
    if (table_ && table_->radius() == radius) return;
    table_ = std::make_shared<const ExpTable>(
        radius, kTableCell, kTableCells,
        [this](const Vec3& d, const std::vector<double>& radii, std::vector<Vec3>& images) {
          Vec3 x{0.0, 0.0, 0.0}, v = d;
          double done = 0.0, error;
          for (std::size_t k = 0; k < radii.size(); ++k) {
            Vec3 u;
            flow(x, v, radii[k] - done, kTableAccuracy, images[k], u, error);
            x = images[k];
            v = u;
            done = radii[k];
          }
        });
  }
  int connections(const Vec3& h, const Vec3& l, double reach, std::vector<LightPath>& paths) const {
    if (!table_) return 0;
    reach = std::min(reach, table_->radius());
    const double ez = std::exp(h[2]);
    const Vec3 T{ez * (l[0] - h[0]), (l[1] - h[1]) / ez, l[2] - h[2]};
    if (!(std::abs(T[2]) <= reach) || !(std::abs(T[0]) <= drift(reach, T[2])) ||
        !(std::abs(T[1]) <= drift(reach, -T[2])))
      return 0;
    thread_local std::vector<ExpTable::Seed> seeds;
    thread_local std::vector<Vec3> found;
    seeds.clear();
    found.clear();
    table_->seeds(T, kSeedMargin, seeds);
    const auto near = [&](const Vec3& w, double within) {  // a geodesic found already
      return std::any_of(found.begin(), found.end(),
                         [&](const Vec3& f) { return norm3(sub3(f, w)) <= within; });
    };
    int missed = 0;
    for (const ExpTable::Seed& seed : seeds) {
      if (near(seed.w, kSameSeed * table_->cell())) continue;  // a seed beside one leads to it
      Vec3 w;
      std::array<Vec3, 3> J;
      if (!shoot(T, seed, w, J)) {
        ++missed;
        continue;
      }
      const double r = norm3(w);
      if (!(r <= reach) || near(w, 1e-7 * (1.0 + r))) continue;
      found.push_back(w);
      paths.push_back({vector4({w[0] / (ez * r), w[1] * ez / r, w[2] / r}), r,
                       floored_falloff(r * r * std::abs(dot3(J[0], cross3(J[1], J[2]))))});
    }
    return missed;
  }

 private:
  static constexpr double kMaxStep = 2.0;
  // The table: cells about this long in w at its rim, at most this many (the longest reach it
  // serves is kLongestConnection), its images to this accuracy (seeds need no more).
  static constexpr double kTableCell = 0.15;
  static constexpr std::size_t kTableCells = 200000;
  static constexpr double kLongestConnection = 12.0;
  static constexpr double kTableAccuracy = 1e-8;
  // Seeds from tetrahedra this far outside (barycentric): the cells' seams, rounding.
  static constexpr double kSeedMargin = 0.02;
  // Seeds within this many cells of a geodesic found are taken for it.
  static constexpr double kSameSeed = 0.3;
  // Connections are flowed to this accuracy and end within kConverged (1 + |T|) of the target.
  static constexpr double kConnectionAccuracy = 1e-11;
  static constexpr double kConverged = 1e-9;

  // How far x can get from 0 (in the coordinates at the origin) along a curve of length L from
  // the origin to height Z: |x'| <= e^{-z} and z >= max(-s, Z - (L - s)) at arclength s, so
  // |x| <= int_0^L min(e^s, e^{L - s - Z}) ds (y likewise with -Z, as |y'| <= e^z).
  static double drift(double L, double Z) {
    const double middle = 0.5 * (L - Z);
    if (middle <= 0.0) return std::exp(-Z) * std::expm1(L);
    if (middle >= L) return std::expm1(L);
    return 2.0 * std::exp(middle) - 1.0 - std::exp(-Z);
  }
  // exp_O(w) for a tangent vector w at the origin (orthonormal there).
  bool exp_origin(const Vec3& w, Vec3& x) const {
    const double r = norm3(w);
    if (!(r > 0.0) || !std::isfinite(r)) return false;
    Vec3 v;
    double error;
    flow({0.0, 0.0, 0.0}, scaled3(1.0 / r, w), r, kConnectionAccuracy, x, v, error);
    return std::isfinite(x[0] + x[1] + x[2]);
  }
  // d exp_O at w (x = exp_O(w)) by forward differences, good to about 1e-5 (the falloff needs no
  // more).
  bool jacobian(const Vec3& w, const Vec3& x, std::array<Vec3, 3>& J) const {
    const double delta = 1e-5 * std::max(norm3(w), 1e-3);
    for (int j = 0; j < 3; ++j) {
      Vec3 plus = w, xp;
      plus[j] += delta;
      if (!exp_origin(plus, xp)) return false;
      for (int i = 0; i < 3; ++i) J[i][j] = (xp[i] - x[i]) / delta;
    }
    return true;
  }
  // exp_O(w) = T by Newton's method from the seed: its interpolation's inverse as the iteration
  // matrix while it converges fast, the Jacobian (forward differences) once the steps are small
  // (and wherever they stop shrinking), which is then d exp_O at the solution to the falloff's
  // need.
  bool shoot(const Vec3& T, const ExpTable::Seed& seed, Vec3& w, std::array<Vec3, 3>& J) const {
    constexpr int kIterations = 16;
    const double tolerance = kConverged * (1.0 + norm3(T));
    w = seed.w;
    std::array<Vec3, 3> inverse = seed.inverse;
    bool exact = false;
    double previous = kInf;
    for (int iteration = 0; iteration < kIterations; ++iteration) {
      Vec3 x;
      if (!exp_origin(w, x)) return false;
      const Vec3 miss = sub3(x, T);
      const double size = norm3(miss);
      Vec3 step{dot3(inverse[0], miss), dot3(inverse[1], miss), dot3(inverse[2], miss)};
      const bool small = norm3(step) < 1e-5 * (1.0 + norm3(w));
      if (!exact && (small || !(size < 0.5 * previous))) {
        if (!jacobian(w, x, J)) return false;
        Vec3 column;
        for (int c = 0; c < 3; ++c) {  // the inverse's columns: J^-1 e_c
          Vec3 e{0.0, 0.0, 0.0};
          e[c] = 1.0;
          if (!solve3(J, e, column)) return false;
          for (int r = 0; r < 3; ++r) inverse[r][c] = column[r];
        }
        exact = true;
        step = {dot3(inverse[0], miss), dot3(inverse[1], miss), dot3(inverse[2], miss)};
      } else if (exact && !(size < 0.5 * previous) && !(size < tolerance)) {
        return false;  // diverging with the Jacobian
      }
      if (size < tolerance && exact) return true;
      previous = size;
      w = sub3(w, step);
    }
    return false;
  }

  std::shared_ptr<const ExpTable> table_;
};

}  // namespace thurston
