// The thurston_core module: the Embree version, the registry's geometries and the bound things.
#include <nanobind/nanobind.h>
#include <nanobind/stl/string.h>

#include <string>

#include "bind.hpp"
#include "embree.hpp"
#include "registry.hpp"
#include "thread_pool.hpp"
#include "tracer.hpp"

namespace nb = nanobind;

NB_MODULE(thurston_core, m) {
  m.doc() = "C++ core of Thurston: the ray tracer through fundamental domains (Embree).";
  m.attr("EMBREE_VERSION") = RTC_VERSION_STRING;
  m.attr("RAY_BLOCK") = thurston::kRayBlock;  // the ray ids that learn visibility together
  nb::exception<thurston::ThreadStartError>(m, "ThreadStartError", PyExc_RuntimeError);

  // The kernel registry's geometries, by name (a contract test checks them against Python's).
  nb::list kernels;
  for (const std::string& name : thurston::geometry_names()) kernels.append(name);
  m.attr("KERNELS") = nb::steal<nb::tuple>(PyList_AsTuple(kernels.ptr()));
  thurston::bindings::bind_scene_record(m);
  thurston::bindings::bind_tracer(m);
  thurston::bindings::bind_geodesics(m);
}
