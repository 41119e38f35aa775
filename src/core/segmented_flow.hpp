// The geodesic of a flow whose segments are integrated pieces (Sol, graph): from p with unit chart
// velocity v at arclength t, segment after segment, the errors summed; NaN where a segment cannot
// advance.
#pragma once

#include "vec.hpp"

namespace thurston {

template <class Flow>
void flow_by_segments(const Flow& flow, const Vec3& p, const Vec3& v, double t, double accuracy,
                      Vec3& xt, Vec3& vt, double& error) {
  typename Flow::Segment s;
  xt = p;
  vt = v;
  error = 0.0;
  for (double done = 0.0; done < t;) {
    flow.segment(xt, vt, t - done, accuracy, s);
    if (!(s.length > 0.0)) {
      xt = vt = {kNaN, kNaN, kNaN};
      return;
    }
    s.at(s.length, xt, vt);
    done += s.length;
    error += s.error;
  }
}

}  // namespace thurston
