// The projective kernel: E3, S3 and H3 in their homogeneous models, where geodesics and the
// domain's faces are straight in the chart, so every cell of the domain is crossed by one exact
// chord.
//
// Points are model 4-vectors X; the projective chart is x = X[:3] / X[3] (Euclidean: affine,
// spherical: gnomonic, hyperbolic: Klein).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <limits>
#include <vector>

#include "kernel.hpp"

namespace thurston {

// Curvature k in {+1, 0, -1} fixes the model: S3 (unit sphere in R^4), E3 (w = 1 affine space),
// H3 (upper hyperboloid <X,X> = -1 of the Lorentz form).
struct ProjectiveKernel {
  int k;

  // Metric on tangent vectors (and the form the model is a unit sphere of, for k != 0).
  double inner(const Vec4& a, const Vec4& b) const {
    const double s = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    return k == 0 ? s : k > 0 ? s + a[3] * b[3] : s - a[3] * b[3];
  }

  // Whether a chart point is a point of the geometry: H3's Klein chart is the open unit ball; E3's
  // and S3's gnomonic charts are all of R^3.
  bool in_chart(const Vec3& x) const { return k >= 0 || dot3(x, x) < 1.0; }

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
  // none), which a valid domain never leaves by first: when every key is +inf, the search falls
  // back to exit_order.
  double exit_key(double a, double b) const {
    if (k <= 0) return exit_order(a, b);
    const double special = (b > 0.0) | ((a > 0.0) & (b >= 0.0)) ? -kInf : kInf;
    return a < 0.0 ? b / a : special;
  }
  void exit_keys(const double* a, const double* b, double* key, std::size_t n) const {
    // One loop per curvature, so that each is a straight-line body.
    if (k == 0)
      for (std::size_t j = 0; j < n; ++j) key[j] = ProjectiveKernel{0}.exit_key(a[j], b[j]);
    else if (k > 0)
      for (std::size_t j = 0; j < n; ++j) key[j] = ProjectiveKernel{1}.exit_key(a[j], b[j]);
    else
      for (std::size_t j = 0; j < n; ++j) key[j] = ProjectiveKernel{-1}.exit_key(a[j], b[j]);
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
    double p =
        z * (0.9998660 + z2 * (-0.3302995 + z2 * (0.1801410 + z2 * (-0.0851330 + z2 * 0.0208351))));
    p = s > ac ? 0.5 * kPi - p : p;
    return c < 0.0 ? kPi - p : p;
  }

  THURSTON_HOT Turn exit_turn(double a, double b) const {  // requires a finite exit_order(a, b)
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
  THURSTON_HOT bool renormalise(Vec4& P, Vec4& V) const {
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

  // Intensity falloff of a point light at distance r: the inverse area of the geodesic sphere.
  double falloff(double r) const {
    const double rho = k == 0 ? r : k > 0 ? std::sin(r) : std::sinh(r);
    return floored_falloff(rho * rho);
  }

  // Model normal vector at a point of the chart plane with covector c (c . X = 0 on the plane):
  // the tangent vector N with <N, Y> = c . Y for all Y, made tangent at X.
  Vec4 plane_normal(const Vec4& X, const Vec4& c) const {
    const Vec4 n = k == 0 ? Vec4{c[0], c[1], c[2], 0.0} : k > 0 ? c : Vec4{c[0], c[1], c[2], -c[3]};
    return tangent_part(X, n);
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

  // --- the kernel interface (kernel.hpp) ---------------------------------------------------------
  bool start(Vec4& P, Vec4& V) const { return renormalise(P, V); }
  double dot(const Vec4&, const Vec4& a, const Vec4& b) const { return inner(a, b); }
  bool normalise(const Vec4&, Vec4& v) const { return normalise(v); }

  // A chart chord: the exact geodesic segment from the walk's (P, V) to its exit.
  struct Chord {
    Vec3 x0, x1;
    static constexpr double margin = 0.0;  // the curve is the chord
  };

  static constexpr bool kChordsBend = false;  // each chord is the geodesic itself

  // Every geodesic from H to the lifts (model points) no longer than reach, in closed form: the
  // segment to each lift, and in S3 also the long arc round the great circle, of length 2 pi - d,
  // leaving in the opposite direction (the same falloff, sin^2 being symmetric). A lift on H (or
  // antipodal to it in S3) has no direction and is skipped. None is missed, and nothing needs
  // preparing for the reach. Those leaving against `facing` are left out before their distance is
  // taken.
  void prepare_light_paths(double) {}
  int light_paths(const Vec4& H, const std::vector<Vec4>& lifts, double reach,
                  std::vector<LightPath>& paths, const Vec4& facing = {}) const {
    const bool culls = facing != Vec4{};
    const bool long_arcs = k > 0 && kPi < reach;
    for (std::size_t i = 0; i < lifts.size(); ++i) {
      const Vec4& L = lifts[i];
      // the short arc leaves H along L's part across H, the long arc against it
      const double ahead = culls ? inner(facing, k == 0 ? sub4(L, H) : L) : 1.0;
      if (!(ahead > 0.0) && !long_arcs) continue;
      const double r = distance(H, L);
      if (r > reach) continue;
      Vec4 direction = toward(H, L);
      if (!normalise(direction)) continue;
      // sin^2 r (S3, the long arc's too) and sinh^2 r (H3) from the cosine, without their functions
      const double c = k > 0 ? dot4(H, L) : -inner(H, L);
      const double spread = k == 0 ? r * r : k > 0 ? 1.0 - c * c : c * c - 1.0;
      if (ahead > 0.0 || !culls)
        paths.push_back({direction, r, floored_falloff(spread), std::int32_t(i)});
      const double long_arc = 2.0 * kPi - r;
      if (k > 0 && long_arc <= reach && (ahead < 0.0 || !culls))
        paths.push_back(
            {scaled(-1.0, direction), long_arc, floored_falloff(spread), std::int32_t(i)});
    }
    return 0;
  }
  Vec4 arrival(const Vec4& H, const LightPath& path) const {
    Vec4 X, Xv;
    advance(H, path.direction, turn(path.distance), X, Xv);
    return scaled(-1.0, Xv);
  }
  // What the light's visibility map is looked up with (integrator.hpp): a vector whose products
  // with tangent vectors at the lift X are those of the path's leaving tangent there (towards H)
  // times a positive factor. The tangent towards H is H's part across X: the short arc leaves
  // along it, S3's long arc (longer than pi) against it.
  Vec4 leaving(const Vec4& H, const Vec4& X, const LightPath& path) const {
    if (k == 0) return sub4(H, X);
    return path.distance > kPi ? scaled(-1.0, H) : H;
  }
  Vec4 chart_point(const Vec3& x) const { return model(x); }
  // The model point of x + e t is s (x + e t, 1) up to the part along X itself, s = X[3].
  Vec4 chart_tangent(const Vec4& X, const Vec3& e) const {
    return scaled(X[3], tangent_part(X, {e[0], e[1], e[2], 0.0}));
  }
  void move(const Mat4& M, Vec4& X, Vec4& V) const {
    Vec4 Y{}, U{};
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) {
        Y[r] += M[4 * r + c] * X[c];
        U[r] += M[4 * r + c] * V[c];
      }
    X = Y;
    V = U;
    renormalise(X, V);
  }

  // The exit from the domain along the geodesic (P, V): the face through which it leaves first
  // (lowest index on ties). In S3 the edge of the gnomonic chart's hemisphere X[3] > 0 competes as
  // a pseudo-face (it loses ties): a valid domain is left through a face before it, and chords must
  // stop (just) short of it. In S3 the turn of a usual exit (exact == false) has exact cosine and
  // sine but an estimated t.
  static constexpr int kChartEdge = -2;
  struct Exit {
    Turn turn;
    int face;    // a face, -1 if none lies ahead, or kChartEdge
    bool exact;  // whether turn.t is exact (else an estimate: S3's usual exits)
    // Where nonzero, (cu, su) = (c, s) / r for some r > 0, known before the turn's square root:
    // cu P + su V has the exit point's chart image.
    double cu = 0.0, su = 0.0;
  };
  Exit find_exit(const Domain& domain, const Vec4& P, const Vec4& V) const;
  Exit find_exit_exact(const Domain& domain, const Vec4& P, const Vec4& V) const;

  // `carried` (optional): two tangent vectors at P, carried along by the face maps crossed (model
  // vectors normal to the geodesic's plane are parallel along it: exact parallel transport).
  struct ChordHit;
  template <class Query, class OnHit>
  WalkEnd walk(const WalkContext& context, Vec4 P, Vec4 V, double length, int max_crossings,
               double first_skip, Query&& query, OnHit&& on_hit, Vec4* carried = nullptr) const;

 private:
  double scene_escape(const WalkContext& context, const Vec3& x0) const;
  static Vec4 sub4(const Vec4& a, const Vec4& b) { return lin4(1.0, a, -1.0, b); }
};

inline ProjectiveKernel::Exit ProjectiveKernel::find_exit(const Domain& domain, const Vec4& P,
                                                          const Vec4& V) const {
  // Blocks of faces on the stack, each pass a simple loop that the compiler vectorises; the face
  // arrays are padded with zero covectors (never an exit) to a multiple of 4.
  constexpr std::size_t kBlock = 16;
  const std::size_t faces = domain.components[0].size();
  const double *c0 = domain.components[0].data(), *c1 = domain.components[1].data(),
               *c2 = domain.components[2].data(), *c3 = domain.components[3].data();
  double best = kInf, best_a = 0.0, best_b = 0.0;
  int face = -1;
  for (std::size_t begin = 0; begin < faces; begin += kBlock) {
    const std::size_t n = std::min(kBlock, faces - begin);
    double a[kBlock], b[kBlock], key[kBlock];
    for (std::size_t g = 0; g < n; g += 4)
      for (std::size_t j = g; j < g + 4; ++j) {
        const std::size_t f = begin + j;
        a[j] = c0[f] * P[0] + c1[f] * P[1] + c2[f] * P[2] + c3[f] * P[3];
        b[j] = c0[f] * V[0] + c1[f] * V[1] + c2[f] * V[2] + c3[f] * V[3];
      }
    exit_keys(a, b, key, n);
    // The block's least key and its first index, branch-free in 4 lanes (face j in lane j % 4).
    double lane_key[4] = {kInf, kInf, kInf, kInf}, lane_index[4] = {-1.0, -1.0, -1.0, -1.0};
    for (std::size_t g = 0; g < n; g += 4)
      for (std::size_t l = 0; l < 4; ++l) {
        const bool less = key[g + l] < lane_key[l];
        lane_key[l] = less ? key[g + l] : lane_key[l];
        lane_index[l] = less ? double(g + l) : lane_index[l];
      }
    for (std::size_t l = 0; l < 4; ++l) {
      const double j = lane_index[l];
      if (lane_key[l] < best || (lane_key[l] == best && j >= 0.0 && int(begin) + int(j) < face)) {
        best = lane_key[l];
        face = int(begin) + int(j);
        best_a = a[std::size_t(j)];
        best_b = b[std::size_t(j)];
      }
    }
  }
  if (k > 0) {
    if (best == kInf) return find_exit_exact(domain, P, V);  // no usual exit: the general search
    if (exit_key(-P[3], -V[3]) < best) {
      if (P[3] > 0.0) return {s3_exit_turn(-P[3], -V[3]), kChartEdge, false, -V[3], P[3]};
      return {exit_turn(-P[3], -V[3]), kChartEdge, true};
    }
    if (best == -kInf) return {{0.0, 1.0, 0.0}, face, true};
    return {s3_exit_turn(best_a, best_b), face, false, best_b, -best_a};
  }
  if (face < 0) return {{kInf, 0.0, 0.0}, -1, true};
  if (k < 0 && best_a <= 0.0)  // H3: (c, s) = (b, -a) / sqrt((b - a) (b + a))
    return {exit_turn(best_a, best_b), face, true, best_b, -best_a};
  return {exit_turn(best_a, best_b), face, true};
}

// S3's exit search for the unusual case of no exit in [0, pi): exact turns, keys in [0, 3).
inline ProjectiveKernel::Exit ProjectiveKernel::find_exit_exact(const Domain& domain, const Vec4& P,
                                                                const Vec4& V) const {
  double best = kInf, best_a = 0.0, best_b = 0.0;
  int face = -1;
  for (std::size_t f = 0; f < domain.components[0].size(); ++f) {
    const Vec4 c = domain.covector(f);
    const double a = dot4(c, P), b = dot4(c, V);
    const double order = exit_order(a, b);
    if (order < best) {
      best = order;
      best_a = a;
      best_b = b;
      face = int(f);
    }
  }
  if (exit_order(-P[3], -V[3]) < best) return {exit_turn(-P[3], -V[3]), kChartEdge, true};
  if (face < 0) return {{kInf, 0.0, 0.0}, -1, true};
  return {exit_turn(best_a, best_b), face, true};
}

// The geodesic length travelled across a walk's crossings. Exact turns add up as numbers; S3's
// usual turns, whose t is only estimated, multiply as unit complex numbers (cos t, sin t), which
// fixes their sum modulo 2 pi, and the sum of the estimates picks the multiple of 2 pi (it is off
// by at most kFold * kTurnEstimateError, far below pi) and bounds the total from above.
class Odometer {
 public:
  void add_exact(double t) { exact_ += t; }
  void add_turn(const ProjectiveKernel::Turn& u) {
    const double c = c_ * u.c - s_ * u.s, s = s_ * u.c + c_ * u.s;
    c_ = c;
    s_ = s;
    estimate_ += u.t;
    if (++turns_ == kFold) fold();
  }
  // An upper bound of the distance after one more estimated turn of `t`.
  double upper_after(double t) const {
    return exact_ + estimate_ + t + (turns_ + 1) * ProjectiveKernel::kTurnEstimateError;
  }
  double value() const {
    if (turns_ == 0) return exact_;
    const double theta = std::atan2(s_, c_);
    const double wraps = std::nearbyint((estimate_ - theta) * (0.5 / kPi));
    return exact_ + (theta + 2.0 * kPi * wraps);
  }

 private:
  static constexpr int kFold = 1024;
  void fold() {
    exact_ = value();
    c_ = 1.0;
    s_ = estimate_ = 0.0;
    turns_ = 0;
  }
  double exact_ = 0.0, c_ = 1.0, s_ = 0.0, estimate_ = 0.0;
  int turns_ = 0;
};

// Y = M X and Yv = M Xv for a column-major M, each row summed left to right like a row-major
// product (the same roundings).
void mat_vec2(const Mat4& Mt, const Vec4& x, const Vec4& xv, Vec4& y, Vec4& yv);

// A hit on a chord, for refinement: the chord is the exact geodesic segment from (P, V) over
// `turn`.
struct ProjectiveKernel::ChordHit {
  const ProjectiveKernel& kernel;
  const Vec4 &P, &V;
  const Vec3 &x0, &x1;
  const Turn& turn;
  bool exact;  // whether turn.t is exact (else an estimate: S3's usual exits)

  // Embree's float hit at chord parameter u on the triangle's chart plane, refined in double
  // precision; Embree's parameter is kept where the chord grazes the plane and the double solution
  // is meaningless.
  Hit refine(const Vec4& plane, double u) const {
    const ProjectiveKernel& k = kernel;
    const Vec3 n{plane[0], plane[1], plane[2]};
    const Vec3 d = sub3(x1, x0);
    const double denom = dot3(n, d);
    if (std::abs(denom) > 1e-9 * std::sqrt(dot3(n, n) * dot3(d, d))) {
      const double refined = -(dot3(n, x0) + plane[3]) / denom;
      if (refined > -1e-3 && refined < 1.0 + 1e-3) u = refined;
    }
    u = std::clamp(u, 0.0, 1.0);
    Hit hit;
    hit.x = {x0[0] + u * d[0], x0[1] + u * d[1], x0[2] + u * d[2]};
    hit.X = k.model(hit.x);
    const double length = exact ? turn.t : std::atan2(turn.s, turn.c);
    hit.s = std::clamp(k.arclength(P, V, hit.X), 0.0, length);
    Vec4 on_ray;
    k.advance(P, V, k.turn(hit.s), on_ray, hit.V);
    return hit;
  }
};

// One exact chord per cell: to the exit face, or to the end of the walk's length. The state
// stays in local variables (the loop runs once per cell of every ray: this is the hot path).
template <class Query, class OnHit>
WalkEnd ProjectiveKernel::walk(const WalkContext& context, Vec4 P, Vec4 V, double length,
                               int max_crossings, double first_skip, Query&& query, OnHit&& on_hit,
                               Vec4* carried) const {
  constexpr double kH3Reach =
      40.0;  // beyond this a Klein chart point is within e^-80 of the sphere
  constexpr int kS3Renormalise = 8;
  Odometer odometer;
  int crossings = 0;
  for (bool first = true;; first = false) {
    if (context.stopped()) return {kCancelled, 0.0, 0, 0.0};
    Exit exit = find_exit(context.domain, P, V);
    // Whether the walk crosses the exit face within its length: an estimated turn decides from
    // the odometer's bound while that is clear of the length, else from the exact numbers.
    bool crosses;
    double dist = kNaN;   // the distance before this step, where computed
    double limit = kNaN;  // where a walk that leaves no face ends
    if (exit.face >= 0 && !exit.exact && odometer.upper_after(exit.turn.t) <= length) {
      crosses = true;
    } else {
      if (!exit.exact) {
        exit.turn.t = std::atan2(exit.turn.s, exit.turn.c);
        exit.exact = true;
      }
      dist = odometer.value();
      // How far the chart can follow the geodesic: S3 to its hemisphere's edge, H3 until the
      // point is indistinguishable from the sphere at infinity.
      const double reach = exit.face == kChartEdge ? exit.turn.t * (1.0 - 1e-6)
                           : k < 0                 ? kH3Reach
                                                   : kInf;
      limit = std::min(length - dist, reach);
      crosses = exit.face >= 0 && exit.turn.t <= limit;
      // A ray that leaves no face ends in this copy at `limit`; its chord need not go beyond the
      // scene's extent.
      if (!crosses) {
        exit.turn = turn(std::min(limit, scene_escape(context, chart(P))));
        exit.cu = exit.su = 0.0;
      }
    }
    const Turn& u = exit.turn;
    Vec4 X, Xv;
    advance(P, V, u, X, Xv);
    if (u.t > 0.0) {
      // The chord's end from (cu, su) where known, so that Embree need not wait for the turn.
      const Chord chord{chart(P), exit.cu != 0.0 || exit.su != 0.0
                                      ? chart(lin4(exit.cu, P, exit.su, V))
                                      : chart(X)};
      const Vec3 d = sub3(chord.x1, chord.x0);
      const double tnear = first ? first_skip / std::sqrt(dot3(d, d)) : 0.0;
      if (tnear < 1.0 && context.may_hit(chord.x0, chord.x1, chord.margin) &&
          query(chord, float(tnear))) {
        on_hit(ChordHit{*this, P, V, chord.x0, chord.x1, u, exit.exact});
        return {kHit, std::isnan(dist) ? odometer.value() : dist, crossings, 0.0};
      }
    }
    if (!crosses) {
      Vec4 end, velocity;
      advance(P, V, turn(limit), end, velocity);
      return {kDistanceLimit, length, crossings, 0.0, chart(end)};
    }
    if (exit.exact)
      odometer.add_exact(u.t);
    else
      odometer.add_turn(u);
    if (crossings == max_crossings)
      return {kCrossingLimit, odometer.value(), crossings, 0.0, chart(X)};
    ++crossings;
    mat_vec2(context.domain.maps_t[exit.face], X, Xv, P, V);
    if (carried) {
      const Vec4 a = carried[0], b = carried[1];
      mat_vec2(context.domain.maps_t[exit.face], a, b, carried[0], carried[1]);
    }
    // S3's pairings are rotations and its turns unit complex numbers, so (P, V) stays orthonormal
    // to a few roundings per crossing; the exit points lie on the face planes whatever the scale.
    // Projecting back every kS3Renormalise crossings keeps the drift below 1e-14.
    if ((k <= 0 || crossings % kS3Renormalise == 0) && !renormalise(P, V))
      return {kDistanceLimit, odometer.value(), crossings, 0.0};
  }
}

// E3 only: a chord from x0 longer than this leaves the scene's bounding ball for good.
inline double ProjectiveKernel::scene_escape(const WalkContext& context, const Vec3& x0) const {
  if (k != 0) return kInf;
  const Vec3 &lo = context.bounds_lo, &hi = context.bounds_hi;
  if (lo[0] > hi[0]) return 0.0;  // no triangles
  Vec3 centre, half;
  for (int a = 0; a < 3; ++a) {
    centre[a] = 0.5 * (lo[a] + hi[a]);
    half[a] = 0.5 * (hi[a] - lo[a]);
  }
  const Vec3 d = sub3(x0, centre);
  return (std::sqrt(dot3(d, d)) + std::sqrt(dot3(half, half))) * 1.001;
}

}  // namespace thurston
