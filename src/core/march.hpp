// The marching kernel: geodesics that bend in the chart, followed in chords whose deviation from
// the true curve is bounded by the walk's tolerance.
//
// MarchingKernel<Flow> turns a geometry's flow (nil.hpp, sol.hpp, h2xr.hpp, s2xr.hpp, sl2.hpp) into
// the kernel interface of kernel.hpp. Points and tangent vectors are chart 4-vectors (x, 1) and
// (v, 0); the domain is bounded by faces (chart planes, or what the flow's side functions make of
// the covectors: S2xR's spheres) whose face maps need not map faces onto faces: after every
// crossing the point is reduced into the domain by the maps of the faces it lies outside of.
//
// A Flow provides the meeting of its model with the chart (AffineChart where they are one):
//   static bool to_chart(Vec4& P, Vec4& V)   a ray's model point and tangent as chart 4-vectors;
//   static void map(const Mat4& M, Vec3& x, Vec3& v)   a face map applied to a chart state;
//   static side(c, x), side_gradient(c, x), side_acceleration_bound(c, K)   a face covector's side
//                                       function (negative inside), its gradient, and a bound of
//                                       its second derivative along a curve with |x''| <= K
//                                       (ChartPlanes where faces are chart planes);
// and for a chart point x and chart velocity v of unit length in the metric:
//   void flow(const Vec3& x, const Vec3& v, double t, double accuracy, Vec3& xt, Vec3& vt,
//             double& error) const      the geodesic at arclength t (error: a bound of the
//                                       position error of (xt, vt) when accuracy is asked for);
//   Segment, void segment(x, v, length, accuracy, Segment&) const   the geodesic over [0, s.length]
//                                       (at most `length`), with s.at(t, xt, vt) anywhere in it,
//                                       s.acceleration_bound(h) a bound of |x''| over [0, h] and
//                                       s.error a bound of its position error: exits and hits are
//                                       searched on it without flowing again; kSegmentBounds says
//                                       whether that bound is tighter than acceleration_bound's
//                                       (worth the extra work: Sol's series) or the same (Nil);
//   double acceleration_bound(const Vec3& x, const Vec3& v, double h) const
//                                       a bound of the chart acceleration |x''| over [0, h];
//   double growth_rate() const          nearby geodesics separate at most like e^(rate t);
//   double max_step() const             the longest step, which keeps the bounds over it tight;
//   static double chart_scale(x)        the chart length of a unit of the walk's tolerance about x
//                                       (ChartPlanes: 1; S2xR, whose chart scales with |x|: |x| /
//                                       e);
//   double dot(const Vec3& x, const Vec3& a, const Vec3& b) const   the metric at x;
//   Vec3 raise(const Vec3& x, const Vec3& covector) const           g^-1 at x;
//   void connections(const Vec3& h, const Vec3& l, double reach, std::vector<LightPath>&) const
//                                       every geodesic from h to the light's copy l (chart points)
//                                       no longer than reach, each with its direction, length and
//                                       falloff: closed forms (H2xR, S2xR), one-dimensional root
//                                       searches per branch (Nil, SL2) or shooting from a table of
//                                       the exponential map (Sol, which returns the number of
//                                       geodesics it could tell it missed, and has
//                                       prepare_connections(reach) to build its table).
#pragma once

#include <algorithm>
#include <cmath>
#include <type_traits>
#include <vector>

#include "chart_planes.hpp"
#include "kernel.hpp"

namespace thurston {

enum class Advance { kContinue, kCross, kLimit };

// The walk loop over a Walk, which provides next() (lay the next chord: kCross, kLimit
// or kContinue in the same cell), has_chord(), chord(), cross(crossings), chord_start_distance(),
// distance(), end_distance(), error(), end_point(), followed() (false once the state was lost)
// and refine(plane, u).
template <class Walk, class Query, class OnHit>
WalkEnd walk_chords(Walk& w, const WalkContext& context, double length, int max_crossings,
                    double first_skip, Query&& query, OnHit&& on_hit) {
  int crossings = 0;
  for (bool first = true;; first = false) {
    if (context.stopped()) return {kCancelled, 0.0, 0, 0.0};
    const Advance advance = w.next();
    if (w.has_chord()) {
      const auto& chord = w.chord();
      const Vec3 d = sub3(chord.x1, chord.x0);
      const double tnear = first ? first_skip / std::sqrt(dot3(d, d)) : 0.0;
      if (tnear < 1.0 && context.may_hit(chord.x0, chord.x1, chord.margin) &&
          query(chord, float(tnear))) {
        on_hit(w);
        return {kHit, w.chord_start_distance(), crossings, w.error()};
      }
    }
    if (advance == Advance::kLimit) {
      // a state that could not be brought into the domain (or kept finite) ends where it was lost,
      // with no end point: not at the distance limit, outside the domain
      if (!w.followed()) return {kDistanceLimit, w.distance(), crossings, 0.0};
      return {kDistanceLimit, length, crossings, 0.0, w.end_point()};
    }
    if (advance == Advance::kCross) {
      if (crossings == max_crossings)
        return {kCrossingLimit, w.end_distance(), crossings, 0.0, w.end_point()};
      ++crossings;
      if (!w.cross(crossings)) return {kDistanceLimit, w.distance(), crossings, 0.0};
    }
  }
}

// Whether a flow prepares its connections for a reach (Flow::prepare_connections).
template <class Flow, class = void>
struct HasPrepare : std::false_type {};
template <class Flow>
struct HasPrepare<Flow, std::void_t<decltype(&Flow::prepare_connections)>> : std::true_type {};

template <class Flow>
class MarchingKernel {
 public:
  explicit MarchingKernel(Flow flow = Flow()) : flow_(flow) {}
  const Flow& flow() const { return flow_; }

  // Chords are not the curve: a refined hit may lie on a neighbour of the chord's triangle.
  static constexpr bool kChordsBend = true;

  // The flow used for exits, hits and lights is asked for this position accuracy relative to the
  // chord tolerance: integration errors stay well inside the tolerance.
  static constexpr double kFlowAccuracy = 0.05;
  // Points closer than this to a face plane (chart units, unit covectors) count as on it.
  static constexpr double kOnFace = 1e-13;

  bool start(Vec4& P, Vec4& V) const {
    if (!finite4(P) || !finite4(V) || !Flow::to_chart(P, V)) return false;
    return normalise(P, V);
  }
  double dot(const Vec4& X, const Vec4& a, const Vec4& b) const {
    return flow_.dot(head3(X), head3(a), head3(b));
  }
  bool normalise(const Vec4& X, Vec4& v) const {
    const double q = dot(X, v, v);
    if (!(q > 0.0) || !std::isfinite(q)) return false;
    v = scaled(inverse_sqrt(q), v);
    v[3] = 0.0;
    return true;
  }
  Vec4 plane_normal(const Vec4& X, const Vec4& plane) const {
    return vector4(flow_.raise(head3(X), {plane[0], plane[1], plane[2]}));
  }
  static Vec3 chart_vector(const Vec4&, const Vec4& v) {
    const Vec3 d = head3(v);
    const double n = norm3(d);
    return n > 0.0 ? scaled3(1.0 / n, d) : d;
  }

  struct Chord {
    Vec3 x0, x1;
    double margin;  // the curve stays within this of the chord
    double length;  // its arclength
  };

  // Every geodesic from H to the lifts no longer than reach (the flow's connections); returns how
  // many it could tell were missed.
  int light_paths(const Vec4& H, const std::vector<Vec4>& lifts, double reach,
                  std::vector<LightPath>& paths, const Vec4& = {}) const {
    int missed = 0;
    for (std::size_t i = 0; i < lifts.size(); ++i) {
      const std::size_t first = paths.size();
      missed += connect(head3(H), head3(lifts[i]), reach, paths);
      for (std::size_t p = first; p < paths.size(); ++p) paths[p].lift = std::int32_t(i);
    }
    return missed;
  }
  // What the flow needs to know of the reach before it connects (Sol's table of its exponential
  // map).
  void prepare_light_paths(double reach) {
    if constexpr (HasPrepare<Flow>::value) flow_.prepare_connections(reach);
  }
  // The path flowed to its end (to the flow's accuracy for light directions, 1e-9).
  Vec4 arrival(const Vec4& H, const LightPath& path) const {
    Vec3 x, v;
    double error;
    flow_.flow(head3(H), head3(path.direction), path.distance, 1e-9, x, v, error);
    return vector4(scaled3(-1.0, v));
  }
  // The path's leaving tangent at its lift, for the light's visibility map: its arrival.
  Vec4 leaving(const Vec4& H, const Vec4&, const LightPath& path) const { return arrival(H, path); }
  static Vec4 chart_point(const Vec3& x) { return point4(x); }
  static Vec4 chart_tangent(const Vec4&, const Vec3& e) { return vector4(e); }
  void move(const Mat4& M, Vec4& X, Vec4& V) const {
    Vec3 x = head3(X), v = head3(V);
    Flow::map(M, x, v);
    X = point4(x);
    V = vector4(v);
  }

  class Walk;
  // `carried` (optional): two tangent vectors at P, carried along by the face maps the walk
  // applies (their differentials at the walk's point); between maps their chart components stay.
  template <class Query, class OnHit>
  WalkEnd walk(const WalkContext& context, const Vec4& P, const Vec4& V, double length,
               int max_crossings, double first_skip, Query&& query, OnHit&& on_hit,
               Vec4* carried = nullptr) const;

 private:
  // The flow's connections, with the misses they count (none where they are closed forms).
  int connect(const Vec3& h, const Vec3& l, double reach, std::vector<LightPath>& paths) const {
    if constexpr (std::is_void_v<decltype(flow_.connections(h, l, reach, paths))>) {
      flow_.connections(h, l, reach, paths);
      return 0;
    } else {
      return flow_.connections(h, l, reach, paths);
    }
  }

  // The root of Sides::side(c, x(t)) = 0 in [t0, t1] along the segment (Sides: the flow's faces, or
  // ChartPlanes for a triangle's plane), where the side function goes from f0 at t0 to the other
  // sign; `guess` is a starting point in [t0, t1].
  template <class Sides>
  static double find_root(const typename Flow::Segment& segment, double t0, double t1,
                          const Vec4& c, double f0, double guess) {
    double lo = t0, hi = t1, flo = f0;
    const double h = t1 - t0;
    double t = std::clamp(guess, lo, hi);
    for (int iteration = 0; iteration < 60; ++iteration) {
      Vec3 x, v;
      segment.at(t, x, v);
      const Vec3 n = Sides::side_gradient(c, x);
      const double f = Sides::side(c, x), df = dot3(n, v);
      // on the face to rounding: this is the root (whichever side of it t lies); side values are
      // distances times |n|
      if (std::abs(f) <= 4e-16 * norm3(n) * (1.0 + norm3(x))) return t;
      if ((f < 0.0) == (flo < 0.0)) {
        lo = t;
        flo = f;
      } else {
        hi = t;
      }
      if (hi - lo <= 1e-15 * (1.0 + h)) break;
      double next = df != 0.0 ? t - f / df : lo - 1.0;
      if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);  // Newton left the bracket: bisect
      t = next;
    }
    // the bracket has closed: its end on the far side of the plane
    return (f0 < 0.0) ? hi : lo;
  }

  Flow flow_;
};

// Marches one ray: chords within the tolerance where the scene may be near, steps to the exit with
// no Embree query where it is not, exits on the true curve, reductions after every crossing.
template <class Flow>
class MarchingKernel<Flow>::Walk {
 public:
  Walk(const MarchingKernel& kernel, const WalkContext& context, const Vec4& P, const Vec4& V,
       double length, Vec4* carried = nullptr)
      : flow_(kernel.flow()),
        context_(context),
        x_(head3(P)),
        v_(head3(V)),
        length_(length),
        carried_(carried) {
    ok_ = settle();
  }

  Advance next() {
    has_chord_ = false;
    chord_start_ = distance_;
    const double remaining = length_ - distance_;
    if (!ok_ || !(remaining > 0.0)) return Advance::kLimit;
    const Domain& domain = context_.domain;
    const double hmax = std::min(remaining, flow_.max_step());
    const double tolerance = context_.tolerance_at(distance_) * Flow::chart_scale(x_);
    const double accuracy = kFlowAccuracy * tolerance;

    // Leaving now: numerically on a face and heading out (carries rays across edges and vertices).
    for (std::size_t f = 0; f < domain.faces; ++f) {
      const Vec4 c = domain.covector(f);
      if (Flow::side(c, x_) > -kOnFace && dot3(Flow::side_gradient(c, x_), v_) > 0.0) {
        exit_face_ = int(f);
        return Advance::kCross;
      }
    }
    // The step's stretch of geodesic: the longest step allowed where the last step met empty
    // space, else three tolerance chords by a bound for every geodesic of this state; where the
    // stretch's own acceleration bound is tighter (Sol's series), longer chords by that.
    // (Sol's own bound over the whole step is the tighter one: then the state's is not needed.)
    const bool a_priori = near_ || !Flow::kSegmentBounds;
    const double K0 = a_priori ? std::max(flow_.acceleration_bound(x_, v_, hmax), 1e-300) : kInf;
    const double h0 = std::min(hmax, std::sqrt(8.0 * tolerance / K0));
    flow_.segment(x_, v_, near_ ? std::min(hmax, 3.0 * h0) : hmax, accuracy, segment_);
    const double span = segment_.length;
    double K = K0, h_tolerance = std::min(span, h0);
    const double K_span = Flow::kSegmentBounds ? segment_.acceleration_bound(span) : K0;
    if (K_span < K0) {
      // the longest chord within the tolerance: from the bound over the span, then over that chord
      K = std::max(K_span, 1e-300);
      h_tolerance = std::min(span, std::max(h0, std::sqrt(8.0 * tolerance / K)));
      const double longer =
          std::min(span, std::sqrt(8.0 * tolerance / segment_.acceleration_bound(h_tolerance)));
      if (longer > h_tolerance &&
          segment_.acceleration_bound(longer) * longer * longer <= 8.0 * tolerance)
        h_tolerance = longer;
    }
    // Along the stretch, steps that the bound |x''| <= K keeps clear of every face plane, until
    // one falls short of a chord: then a chord beyond the last (an excursion past a face and back
    // within a chord stays within the tolerance of the face).
    double clear = 0.0, step = safe_step(x_, v_, K, span);
    for (int i = 0; i < kClearSteps && step >= h_tolerance && clear + step < span; ++i) {
      clear += step;
      Vec3 xc, vc;
      segment_.at(clear, xc, vc);
      step = safe_step(xc, vc, K, span - clear);
    }
    double h = std::min(span, clear + std::max(step, h_tolerance));
    Vec3 x1, v1;
    segment_.at(h, x1, v1);
    double margin = K * h * h / 8.0;
    // Where the scene may be near the step, its longest empty part by halving, down to a chord;
    // a chord within the tolerance where not even that is clear of the scene.
    near_ = false;
    while (h > h_tolerance && context_.may_hit(x_, x1, margin)) {
      h = std::max(0.5 * h, h_tolerance);
      segment_.at(h, x1, v1);
      margin = chord_bound(K, h) * h * h / 8.0;
      near_ = h == h_tolerance;
    }
    // The first face plane the curve crosses within the step (beyond the clear steps only).
    int face = -1;
    double exit = h;
    for (std::size_t f = 0; f < domain.faces; ++f) {
      const Vec4 c = domain.covector(f);
      const double f1 = Flow::side(c, x1);
      if (!(f1 > 0.0)) continue;
      const double f0 = std::min(Flow::side(c, x_), -kOnFace);
      const double guess = h * f0 / (f0 - f1);
      const double t = find_root<Flow>(segment_, 0.0, h, c, f0, guess);
      if (t < exit || face < 0) {
        exit = t;
        face = int(f);
      }
    }
    if (face >= 0) {
      h = exit;
      segment_.at(h, x1, v1);
      margin = chord_bound(K, h) * h * h / 8.0;
    }
    if (h > 0.0) {
      chord_ = {x_, x1, margin, h};
      has_chord_ = true;
    }
    // errors of earlier steps grow with the separation of geodesics; this step adds its own
    const double g =
        flow_.growth_rate() * h;  // 1 + g (1 + g) >= e^g for g <= 1 (steps are shorter)
    drift_ = drift_ * (1.0 + g * (1.0 + g)) + segment_.error;
    chord_margin_ = margin;
    distance_ += h;
    x_ = x1;
    v_ = v1;  // unit to the flow's accuracy; crossings renormalise
    if (face >= 0) {
      exit_face_ = face;
      return Advance::kCross;
    }
    return distance_ >= length_ ? Advance::kLimit : Advance::kContinue;
  }
  bool has_chord() const { return has_chord_; }
  const Chord& chord() const { return chord_; }
  double chord_start_distance() const { return chord_start_; }

  // The point where the curve of the last chord meets a triangle's plane near Embree's parameter
  // u: the chord's ends are points of the curve, so a plane the chord crosses is crossed by the
  // curve in the same interval, where a safeguarded Newton iteration on the step's segment finds
  // it.
  Hit refine(const Vec4& plane, double u) const {
    return refine_between(plane, 0.0, chord_.length, std::clamp(u, 0.0, 1.0));
  }
  // The same on the curve between its points at arclengths t0 < t1 of the last chord (u now the
  // parameter on the chord between those points).
  Hit refine_between(const Vec4& plane, double t0, double t1, double u) const {
    const Vec3 n{plane[0], plane[1], plane[2]};
    double t = t0 + std::clamp(u, 0.0, 1.0) * (t1 - t0);
    Vec3 x0, x1, v;
    segment_.at(t0, x0, v);
    segment_.at(t1, x1, v);
    const double f0 = dot3(n, x0) + plane[3], f1 = dot3(n, x1) + plane[3];
    if ((f0 < 0.0) != (f1 < 0.0) && f0 != 0.0)
      t = find_root<ChartPlanes>(segment_, t0, t1, plane, f0, t);
    return at(t);
  }
  // The curve's point at arclength t from the last chord's start.
  Hit at(double t) const {
    Vec3 x, v;
    segment_.at(t, x, v);
    return {t, point4(x), vector4(v), x};
  }
  // The chart chord between the last chord's curve points at arclengths t0 <= t1 from its start.
  void curve_chord(double t0, double t1, Vec3& a, Vec3& b) const {
    Vec3 v;
    segment_.at(t0, a, v);
    segment_.at(t1, b, v);
  }
  double distance() const { return distance_; }
  double end_distance() const { return distance_; }
  // How far the last chord may be from the true geodesic: its own margin plus what the flow and
  // the crossings have drifted.
  double error() const { return chord_margin_ + drift_; }
  // Where the walk stands: the end of the last step (at a face, or at the end of its length).
  Vec3 end_point() const { return x_; }
  // Whether the state is still the ray's: false where it could not be brought into the domain
  // (a start too far out for kMaxReductions face maps) or stopped being finite.
  bool followed() const { return ok_; }

  bool cross(int) {
    apply(exit_face_);
    ok_ = settle();
    return ok_;
  }

 private:
  // Face maps that settle() may apply in a row: one or two after a crossing, some hundreds for a
  // start far out in the cover (Sol at |z| = 20: about 500, as Space.move_inside needs).
  static constexpr int kMaxReductions = 2048;

  // The acceleration bound over a chord of length h within the step (K bounds the whole step).
  double chord_bound(double K, double h) const {
    return Flow::kSegmentBounds ? std::min(K, segment_.acceleration_bound(h)) : K;
  }

  // The longest step from the state (x, v), up to `limit`, that a chart acceleration bound K
  // keeps clear of every face: the first root of a + b t + B t^2 / 2 (a the side at x, b its
  // rate, B the bound of its second derivative), in its stable form.
  double safe_step(const Vec3& x, const Vec3& v, double K, double limit) const {
    const Domain& domain = context_.domain;
    double safe = limit;
    for (std::size_t f = 0; f < domain.faces; ++f) {
      const Vec4 c = domain.covector(f);
      const double a = std::min(Flow::side(c, x), 0.0), b = dot3(Flow::side_gradient(c, x), v);
      const double bound = Flow::side_acceleration_bound(c, K);
      const double root = std::sqrt(b * b - 2.0 * bound * a);
      if (b > 0.0)
        safe = std::min(safe, -2.0 * a / (b + root));
      else if (bound > 0.0)
        safe = std::min(safe, (root - b) / bound);  // else never reached
    }
    return safe;
  }

  void apply(int face) {
    const Mat4& M = context_.domain.maps[face];
    if (carried_)
      for (int j = 0; j < 2; ++j) {
        Vec3 x = x_, c = head3(carried_[j]);
        Flow::map(M, x, c);
        carried_[j] = vector4(c);
      }
    Flow::map(M, x_, v_);
  }

  // Into the domain: the maps of the faces the point lies (farthest) outside of, then off the face
  // planes it still touches while heading in, so that the next step starts strictly inside them.
  bool settle() {
    const Domain& domain = context_.domain;
    for (int reduction = 0;; ++reduction) {
      int worst = -1;
      double worst_side = kReduce;
      for (std::size_t f = 0; f < domain.faces; ++f) {
        const Vec4 c = domain.covector(f);
        const double side = Flow::side(c, x_);
        if (side > worst_side) {
          worst_side = side;
          worst = int(f);
        }
      }
      if (worst < 0) break;
      if (reduction == kMaxReductions) return false;
      apply(worst);
    }
    for (std::size_t f = 0; f < domain.faces; ++f) {
      const Vec4 c = domain.covector(f);
      const Vec3 n = Flow::side_gradient(c, x_);
      const double side = Flow::side(c, x_), rate = dot3(n, v_);
      if (!(side > -kOnFace && rate <= 0.0)) continue;
      const double gap = side + 2.0 * kOnFace;
      if (rate < -1e-6 * norm3(n)) {
        // along the geodesic itself, which keeps the ray the same ray (a step off it would not:
        // Nil's vertical component w = z' - x y' changes when x moves and the velocity stays)
        const double t = gap / -rate;
        Vec3 x, v;
        double error;
        flow_.flow(x_, v_, t, kOnFace, x, v, error);
        x_ = x;
        v_ = v;
        distance_ += t;
      } else {  // grazing: straight off the face, which is a step off the geodesic
        x_ = sub3(x_, scaled3(gap / dot3(n, n), n));
        drift_ += gap / norm3(n);
      }
    }
    return renormalise();
  }

  bool renormalise() {
    const double q = flow_.dot(x_, v_, v_);
    if (!(q > 0.0) || !std::isfinite(q) || !std::isfinite(x_[0] + x_[1] + x_[2])) return false;
    v_ = scaled3(inverse_sqrt(q), v_);
    return true;
  }

  static constexpr double kReduce = 1e-12;  // outside a face by more than this: reduce
  static constexpr int kClearSteps = 16;    // safe steps along one stretch at the most

  const Flow& flow_;
  const WalkContext& context_;
  typename Flow::Segment segment_;  // the current step's stretch of geodesic
  Vec3 x_, v_;
  double length_;
  Vec4* carried_;  // two tangent vectors the face maps carry along (or none)
  double distance_ = 0.0, chord_start_ = 0.0;
  double drift_ = 0.0, chord_margin_ = 0.0;
  Chord chord_{};
  bool has_chord_ = false;
  bool near_ = false;  // whether the last step was a chord near the scene
  bool ok_ = true;
  int exit_face_ = -1;
};

template <class Flow>
template <class Query, class OnHit>
WalkEnd MarchingKernel<Flow>::walk(const WalkContext& context, const Vec4& P, const Vec4& V,
                                   double length, int max_crossings, double first_skip,
                                   Query&& query, OnHit&& on_hit, Vec4* carried) const {
  Walk w(*this, context, P, V, length, carried);
  return walk_chords(w, context, length, max_crossings, first_skip, query, on_hit);
}

}  // namespace thurston
