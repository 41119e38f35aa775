// The compiled-scene record that Python hands the core (thurston_core.Scene): numpy arrays as
// given, grouped into the parts of the core's SceneData (scene.hpp), each part a struct bound once
// (scene_record.cpp) and checked into its SceneData part by scene_from_record (scene_checks.cpp).
// Field names are the arrays' names in the compiled scene (render.compile_scene) and in errors.
#pragma once

#include <nanobind/nanobind.h>

#include <string>
#include <vector>

#include "arrays.hpp"
#include "scene.hpp"

namespace thurston::bindings {

struct DomainArrays {
  Array face_covectors, face_maps;
};

struct MeshArrays {
  Array vertices, triangles, triangle_object;
  OptionalArray mesh_first_triangle;
};

struct InstanceArrays {
  OptionalArray instance_mesh, instance_transform, instance_object;
};

struct SurfaceArrays {
  Array object_color, object_emission;
  OptionalArray corner_normals, corner_uvs, triangle_material, material_color, material_emission,
      material_color_texture, material_emission_texture, material_one_sided, material_scattering;
  std::vector<Array> textures;
};

struct LightArrays {
  Array light_lifts, light_of_lift, light_radiance;
  OptionalArray light_cone, light_axis, light_copies;
  double light_reach = kInf, geodesic_loop = kInf;
};

struct EmitterArrays {
  OptionalArray emitter_triangles, emitter_radiance, emitter_one_sided, emitter_group,
      emitter_copies, emitter_copy_group;
};

struct SceneRecord {
  std::string geometry;
  std::vector<double> geometry_parameters;  // what configures the geometry (graph's bumps)
  DomainArrays domain;
  MeshArrays meshes;
  SurfaceArrays surfaces;
  LightArrays lights;
  InstanceArrays instances;
  EmitterArrays emitters;
};

// The scene checked (ValueError naming the array and row where it is not one) and converted.
SceneData scene_from_record(const SceneRecord& record);

}  // namespace thurston::bindings
