// The scene as the core holds it, checked: the parts of the compiled-scene record that Python hands
// over (bindings/scene_record.hpp), each converted to its struct here (bindings/scene_checks.cpp).
// See the Python docstrings of thurston_core.Scene and its parts for the meaning of each field.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "surface.hpp"
#include "vec.hpp"

namespace thurston {

// The fundamental domain {X : c_f . X <= 0 for all f} and its face pairings: a ray leaving through
// face f continues from maps[f] X.
struct DomainFaces {
  std::vector<Vec4> covectors;
  std::vector<Mat4> maps;
};

// The meshes (prototypes): their triangles one after the other, in the meshes' own coordinates
// (chart coordinates where not moved); what is seen are the instances.
struct Meshes {
  std::vector<Vec3> vertices;
  std::vector<std::array<std::uint32_t, 3>> triangles;
  std::vector<std::int32_t> triangle_object;
  std::vector<std::uint32_t> first;  // first triangle of each mesh, ascending from 0
};

// A placement of a mesh in the chart: its triangles mapped by `to_chart`; the object of a hit is
// `object` plus the triangle's own object.
struct Instance {
  std::uint32_t mesh;
  std::int32_t object;
  Affine to_chart;
};

// A spot light's cone, as Cycles shapes it: the light leaving at angle theta from the axis is
// scaled by smoothstep((cos theta - cos_half) * smooth), smooth = 1 / ((1 - cos_half) blend), and
// is 0 outside the cone (blend 0: smooth = inf, a sharp edge). cos_half <= -1: no cone.
struct SpotCone {
  double cos_half = -1.0, smooth = kInf;
  bool active() const { return cos_half > -1.0; }
  double attenuation(double cos_theta) const {
    const double f = (cos_theta - cos_half) * smooth;
    if (!(f > 0.0)) return 0.0;
    return f >= 1.0 ? 1.0 : f * f * (3.0 - 2.0 * f);
  }
};

// The point lights: their copies in the universal cover (lifts), and how far light is summed.
struct Lights {
  std::vector<Vec4> lifts;  // points of the geometry (normalised by the kernel)
  std::vector<std::int32_t> of_lift;
  std::vector<Rgb> radiance;
  std::vector<SpotCone> cone;  // per light (empty: no spot lights)
  std::vector<Vec4> axis;      // per lift of a spot light: its unit axis there (else zero)
  // per lift, where given: the group element (model map) that takes the light to it, which
  // carries the light's frame there (its visibility map, visibility_map.hpp)
  std::vector<Mat4> copies;
  double reach = kInf;  // light paths longer than this are not summed
  // Every geodesic returns to its start after this length (S3 with -1 in the group: pi), so a light
  // path longer than it from an opaque surface passes through that surface again: shadowed.
  double geodesic_loop = kInf;
};

// Emissive triangles sampled as lights (next-event estimation): chart triangles of one copy of
// each emitter (a group), with their radiance and whether they emit from their front only (the
// side of cross(p1 - p0, p2 - p0)); every copy M of a group lights as the group's own triangles do.
struct Emitters {
  std::vector<std::array<Vec3, 3>> triangles;
  std::vector<Rgb> radiance;
  std::vector<std::uint8_t> one_sided;
  std::vector<std::int32_t> group;
  std::vector<Mat4> copies;  // the group elements (model maps), each of copy_group's group
  std::vector<std::int32_t> copy_group;
};

struct SceneData {
  std::vector<double> geometry_parameters;  // what configures the geometry (graph's bumps)
  DomainFaces domain;
  Meshes meshes;
  std::vector<Instance> instances;
  Surfaces surfaces;  // materials, textures, corner normals and UVs of the triangles
  Lights lights;
  Emitters emitters;
};

}  // namespace thurston
