// The bound things of the thurston_core module, one file each: the compiled-scene record
// (scene_record.cpp), the Tracer (tracer_binding.cpp) and the geodesics of the marching geometries
// (geodesics_binding.cpp); module.cpp puts them together.
#pragma once

#include <nanobind/nanobind.h>

namespace thurston::bindings {

void bind_scene_record(nanobind::module_& m);
void bind_tracer(nanobind::module_& m);
void bind_geodesics(nanobind::module_& m);

}  // namespace thurston::bindings
