// The marching geometries' geodesics as the tracer follows them, for tests against independent
// truth: geodesic_flow and Connections (light paths within a reach).
#include <nanobind/stl/array.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <array>
#include <cmath>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "arrays.hpp"
#include "bind.hpp"
#include "registry.hpp"

namespace thurston::bindings {

namespace {

// ValueError where the geometry is unknown or the parameters are not its.
void check_geometry(const std::string& geometry, const std::vector<double>& parameters) {
  if (!has_geometry(geometry))
    throw nb::value_error(("unknown geometry '" + geometry + "'").c_str());
  if (!accepts_parameters(geometry, parameters))
    throw nb::value_error(("parameters are not " + geometry +
                           "'s (graph: geometries.graph.Graph.kernel_parameters; the others: none)")
                              .c_str());
}

nb::tuple flow_rows(const std::string& geometry, const Array& points, const Array& velocities,
                    const Array& lengths, double accuracy, const std::vector<double>& parameters) {
  check_geometry(geometry, parameters);
  if (!has_flow(geometry))
    throw nb::value_error(
        (geometry + " has no marching flow (its geodesics are chart lines)").c_str());
  check_rays(points, velocities, "points", "velocities", 3, "row");
  check<double>(lengths, "lengths", {std::int64_t(points.shape(0))}, "(N,) with N = len(points)");
  const std::size_t n = points.shape(0);
  const Strided2<double> p = view2<double>(points), v = view2<double>(velocities);
  const double* t = static_cast<const double*>(lengths.data());
  std::unique_ptr<double[]> xt(new double[3 * n]), vt(new double[3 * n]);
  for (std::size_t i = 0; i < n; ++i) {
    Vec3 x, u;
    thurston::geodesic_flow(geometry, parameters, {p(i, 0), p(i, 1), p(i, 2)},
                            {v(i, 0), v(i, 1), v(i, 2)}, t[i * lengths.stride(0)], accuracy, x, u);
    for (int a = 0; a < 3; ++a) {
      xt[3 * i + a] = x[a];
      vt[3 * i + a] = u[a];
    }
  }
  return nb::make_tuple(to_numpy(std::move(xt), {n, 3}), to_numpy(std::move(vt), {n, 3}));
}

// The Python Connections: a marching geometry's light paths within a reach.
struct ConnectionsHandle {
  std::unique_ptr<Connections> connections;
};

nb::tuple connect_points(const ConnectionsHandle& self, const std::array<double, 3>& h,
                         const std::array<double, 3>& l) {
  std::vector<LightPath> paths;
  const int missed = self.connections->connect(h, l, paths);
  const std::size_t n = paths.size();
  std::unique_ptr<double[]> directions(new double[3 * n]), lengths(new double[n]),
      falloffs(new double[n]);
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) directions[3 * i + a] = paths[i].direction[a];
    lengths[i] = paths[i].distance;
    falloffs[i] = paths[i].falloff;
  }
  return nb::make_tuple(to_numpy(std::move(directions), {n, 3}), to_numpy(std::move(lengths), {n}),
                        to_numpy(std::move(falloffs), {n}), missed);
}

}  // namespace

void bind_geodesics(nb::module_& m) {
  m.def("geodesic_flow", &flow_rows, nb::arg("geometry"), nb::arg("points").noconvert(),
        nb::arg("velocities").noconvert(), nb::arg("lengths").noconvert(),
        nb::arg("accuracy") = 1e-12, nb::arg("parameters") = std::vector<double>{},
        "The tracer's geodesic flow of a marching geometry (Nil, Sol): chart points and unit "
        "chart velocities (float64 (N,3)) after arclengths (float64 (N,)), asked for `accuracy` "
        "(chart units), with the geometry's parameters (graph's kernel_parameters; none for the "
        "others). Returns (points, velocities), float64 (N,3) each.");

  nb::class_<ConnectionsHandle>(
      m, "Connections",
      "The tracer's light paths of a marching geometry (Nil, Sol, H2xR, S2xR, SL2) "
      "within a reach: Connections(geometry, reach)(h, l) gives every geodesic from "
      "the chart point h to the chart point l no longer than the reach, as (directions "
      "float64 (n,3): unit chart tangents at h, lengths float64 (n,), falloffs float64 "
      "(n,): the inverse area density of the geodesic sphere along each, missed: how "
      "many the search could tell it missed).")
      .def(
          "__init__",
          [](ConnectionsHandle* self, const std::string& geometry, double reach,
             const std::vector<double>& parameters) {
            check_geometry(geometry, parameters);
            if (!(reach >= 0.0) || !std::isfinite(reach))
              throw nb::value_error("reach must be a finite distance >= 0");
            std::unique_ptr<Connections> connections =
                make_connections(geometry, reach, parameters);
            if (!connections) throw nb::value_error((geometry + " has no marching flow").c_str());
            new (self) ConnectionsHandle{std::move(connections)};
          },
          nb::arg("geometry"), nb::arg("reach"), nb::arg("parameters") = std::vector<double>{})
      .def("__call__", &connect_points, nb::arg("h"), nb::arg("l"));
}

}  // namespace thurston::bindings
