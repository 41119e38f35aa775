// How the marching kernel evaluates a domain face whose covector c is a chart plane (Nil, Sol,
// H2xR): its side n . x + d (negative inside), the side's gradient, and a bound of the side's
// second derivative along a curve whose chart acceleration is at most K. A flow whose faces are
// not chart planes (S2xR's spheres) provides the same three functions for its own faces.
#pragma once

#include "vec.hpp"

namespace thurston {

struct ChartPlanes {
  static double side(const Vec4& c, const Vec3& x) {
    return c[0] * x[0] + c[1] * x[1] + c[2] * x[2] + c[3];
  }
  static Vec3 side_gradient(const Vec4& c, const Vec3&) { return {c[0], c[1], c[2]}; }
  static double side_acceleration_bound(const Vec4& c, double K) {
    return norm3({c[0], c[1], c[2]}) * K;
  }
  // The chart length of a unit of the walk's tolerance at x over a step: 1 where the chart is about
  // isometric over the domain (Nil, Sol, H2xR); S2xR's chart scales with |x|.
  static double chart_scale(const Vec3&) { return 1.0; }
};

}  // namespace thurston
