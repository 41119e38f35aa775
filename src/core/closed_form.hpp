// What flows with a closed-form geodesic share (Nil, H2xR): a segment is the closed form itself,
// evaluated anywhere, and its acceleration bound is the state's (the closed form gives no tighter
// one). Flow provides static geodesic(p, v, t, x, u), static rounding(p, t) (a bound of what the
// closed form's roundings add) and acceleration_bound(p, v, h).
#pragma once

#include "vec.hpp"

namespace thurston {

template <class Flow>
struct ClosedForm {
  static constexpr bool kSegmentBounds = false;
  struct Segment {
    Vec3 p, v;
    double length, error;
    void at(double t, Vec3& x, Vec3& u) const { Flow::geodesic(p, v, t, x, u); }
    double acceleration_bound(double h) const { return Flow().acceleration_bound(p, v, h); }
  };
  void segment(const Vec3& p, const Vec3& v, double length, double, Segment& s) const {
    s = {p, v, length, Flow::rounding(p, length)};
  }
  void flow(const Vec3& p, const Vec3& v, double t, double, Vec3& xt, Vec3& vt,
            double& error) const {
    Flow::geodesic(p, v, t, xt, vt);
    error = Flow::rounding(p, t);
  }
};

}  // namespace thurston
