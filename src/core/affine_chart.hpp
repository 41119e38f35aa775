// How the model 4-vectors and face maps of flows whose model is their chart (Nil, Sol) meet the
// marching kernel: points (x, 1), tangent vectors (v, 0), face maps affine, faces chart planes.
#pragma once

#include "chart_planes.hpp"
#include "vec.hpp"

namespace thurston {

struct AffineChart : ChartPlanes {
  // A model point and tangent vector as chart (x, 1) and (v, 0); false where P is no point.
  static bool to_chart(Vec4& P, Vec4& V) {
    if (!(P[3] != 0.0)) return false;
    P = scaled(1.0 / P[3], P);
    P[3] = 1.0;
    V[3] = 0.0;
    return true;
  }
  // The face map M applied to the chart point x and the tangent vector v there.
  static void map(const Mat4& M, Vec3& x, Vec3& v) {
    Vec3 y, u;
    for (int r = 0; r < 3; ++r) {
      y[r] = M[4 * r] * x[0] + M[4 * r + 1] * x[1] + M[4 * r + 2] * x[2] + M[4 * r + 3];
      u[r] = M[4 * r] * v[0] + M[4 * r + 1] * v[1] + M[4 * r + 2] * v[2];
    }
    x = y;
    v = u;
  }
};

}  // namespace thurston
