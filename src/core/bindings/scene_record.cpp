// The compiled-scene record's parts, each bound once: its arrays as given (no conversion: a wrong
// dtype is a ValueError when the Tracer checks the record), read-only fields of the same names.
#include "scene_record.hpp"

#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include "bind.hpp"

namespace thurston::bindings {

namespace {

const char* const kSceneDoc =
    R"(The compiled scene that a Tracer renders (render.compile_scene's arrays by part).

geometry: "E3", "S3" (gnomonic chart), "H3" (Klein chart): points are model 4-vectors X whose
chart point is X[:3] / X[3] and geodesics are exact chart lines; the marching geometries ("Nil",
"Sol", "H2xR", "S2xR", "SL2"): points are (x, 1) and tangent vectors (v, 0) in the chart, and
geodesics are followed in chords within the trace's tolerance (thurston_core.KERNELS names
them all). domain, meshes, surfaces, lights: the parts of those names; instances (without them:
one mesh of all triangles, placed once by the identity) and emitters (without them: none).
geometry_parameters: what configures the geometry ("graph": its bumps, geometries.graph.Graph.
kernel_parameters; the other geometries take none).)";

const char* const kDomainDoc = R"(The fundamental domain and its face pairings.

face_covectors: float64 (F,4); the fundamental domain is {X : c_f . X <= 0 for all f}.
face_maps: float64 (F,4,4); a ray leaving through face f continues from M_f X (then, for the
marching geometries, reduced into the domain by the maps of the faces it lies outside of).)";

const char* const kMeshesDoc =
    R"(The triangles: meshes one after the other, each stored and built once.

vertices: float64 (NV,3) chart coordinates (with instances: the meshes' coordinates);
triangles: int32 (NT,3); triangle_object: int32 (NT,).
mesh_first_triangle (optional): int32 (NMESH,), the first triangle of each mesh (from 0,
ascending; mesh m runs to the next one's first). Without it: one mesh.)";

const char* const kInstancesDoc = R"(The placements of the meshes (Embree instancing): what is seen.

Together: instance_mesh: int32 (NI,) the mesh each instance places; instance_transform: float64
(NI,3,4) the affine chart map [L | t] of each (x -> L x + t, L invertible: vertices, and with them
triangle planes and corner normals, are in the mesh's own coordinates; Embree traverses the map in
float32, hits are refined in float64 from it); instance_object: int32 (NI,) added to the
triangle_object of the instance's triangles for the object of a hit. Without them: one mesh of all
triangles, placed once by the identity (an identity map is traversed without an instance level).)";

const char* const kSurfacesDoc = R"(The triangles' materials and their corner attributes.

object_color, object_emission: float32 (NO,3), each object's one material where triangle_material
is not given. Triangles of emissive materials cast no shadows on the point lights' light (they do
on the emitters').
Optional:
corner_normals: float32 (NT,3,3) per triangle corner, the chart covector of the surface's normal
(the chart plane's normal for a flat triangle); the shading normal at a hit is the metric normal
of the chart plane through it whose covector interpolates the corners' (barycentric), on the side
of the geometric normal facing the ray. Without it: the geometric normal.
corner_uvs: float32 (NT,3,2) texture coordinates per corner, interpolated likewise.
triangle_material: int32 (NT,) index into material_color, material_emission: float32 (NM,3);
material_color_texture, material_emission_texture: int32 (NM,), -1 or an index into textures, a
list of float32 (H,W,3) or (H,W,4) linear images (rows top-down, v = 0 the bottom row, bilinear,
repeating) that multiply the material's colour or emission at the hit's UV.
material_one_sided: int32 (NM,), 1 where a material's emission is seen from the front only.
material_scattering: float32 (NM,4) per material roughness, metallic, specular IOR level and IOR
as Blender's Principled BSDF takes them: a Lambert base under a dielectric GGX specular layer (the
level scales its normal reflectance, 0.5: the IOR's own; 0: no layer) and a metallic GGX lobe
coloured by the base colour (Schlick). Without it, or with metallic and level 0: Lambert.)";

const char* const kLightsDoc = R"(The point lights, and how far light is summed.

light_lifts: float64 (K,4) points (copies of the point lights in the universal cover);
light_of_lift: int32 (K,) light index of each lift; light_radiance: float32 (NL,3). Every geodesic
from a shaded point to each lift no longer than light_reach is summed (S3 also the long arc, of
length 2 pi - d; S2xR every arc round the sphere, either way and winding; Nil, Sol and SL2 every
geodesic of the universal cover, SL2 to the lifts' copies along the fibre by 4 pi too).
geodesic_loop: the length after which every geodesic returns to its start (S3 with -1 in the
group: pi); light paths longer than it from an opaque surface are shadowed by that surface.
Spot lights (optional, together): light_cone float64 (NL,2) per light (cos of the cone's half
angle, smoothness 1 / ((1 - cos) blend)), light leaving at angle theta from the axis scaled by
smoothstep((cos theta - cos) * smoothness) as in Cycles (cos -1: no cone); light_axis float64
(K,4) the unit axis (a model tangent vector) at each lift of a light with a cone.
light_copies (optional) float64 (K,4,4): the group element (model map) that takes its light to each
lift; a light one of whose lifts is its own (the identity) then has a visibility map (trace's
visibility_map).)";

const char* const kEmittersDoc =
    R"(Emissive triangles sampled as lights at every shaded point (trace's light_samples points each).

Together: emitter_triangles float64 (E,3,3) chart triangles of one copy of each emitter,
emitter_radiance float32 (E,3), emitter_one_sided int32 (E,) (1: emits from the side of its
winding normal only), emitter_group int32 (E,) and emitter_copies float64 (C,4,4) the group
elements (model maps) whose copies of their group (emitter_copy_group int32 (C,)) light, each
along every geodesic as a point light does. Without them: no emitters.)";

// An optional array argument: taken as it is, or None (the default).
auto optional(const char* name) { return nb::arg(name).noconvert().none() = nb::none(); }

}  // namespace

void bind_scene_record(nb::module_& m) {
  nb::class_<DomainArrays>(m, "Domain", kDomainDoc)
      .def(nb::init<Array, Array>(), nb::arg("face_covectors").noconvert(),
           nb::arg("face_maps").noconvert())
      .def_ro("face_covectors", &DomainArrays::face_covectors)
      .def_ro("face_maps", &DomainArrays::face_maps);

  nb::class_<MeshArrays>(m, "Meshes", kMeshesDoc)
      .def(nb::init<Array, Array, Array, OptionalArray>(), nb::arg("vertices").noconvert(),
           nb::arg("triangles").noconvert(), nb::arg("triangle_object").noconvert(),
           optional("mesh_first_triangle"))
      .def_ro("vertices", &MeshArrays::vertices)
      .def_ro("triangles", &MeshArrays::triangles)
      .def_ro("triangle_object", &MeshArrays::triangle_object)
      .def_ro("mesh_first_triangle", &MeshArrays::mesh_first_triangle);

  nb::class_<InstanceArrays>(m, "Instances", kInstancesDoc)
      .def(nb::init<OptionalArray, OptionalArray, OptionalArray>(), optional("instance_mesh"),
           optional("instance_transform"), optional("instance_object"))
      .def_ro("instance_mesh", &InstanceArrays::instance_mesh)
      .def_ro("instance_transform", &InstanceArrays::instance_transform)
      .def_ro("instance_object", &InstanceArrays::instance_object);

  nb::class_<SurfaceArrays>(m, "Surfaces", kSurfacesDoc)
      .def(nb::init<Array, Array, OptionalArray, OptionalArray, OptionalArray, OptionalArray,
                    OptionalArray, OptionalArray, OptionalArray, OptionalArray, OptionalArray,
                    std::vector<Array>>(),
           nb::arg("object_color").noconvert(), nb::arg("object_emission").noconvert(),
           optional("corner_normals"), optional("corner_uvs"), optional("triangle_material"),
           optional("material_color"), optional("material_emission"),
           optional("material_color_texture"), optional("material_emission_texture"),
           optional("material_one_sided"), optional("material_scattering"),
           nb::arg("textures") = std::vector<Array>())
      .def_ro("object_color", &SurfaceArrays::object_color)
      .def_ro("object_emission", &SurfaceArrays::object_emission)
      .def_ro("corner_normals", &SurfaceArrays::corner_normals)
      .def_ro("corner_uvs", &SurfaceArrays::corner_uvs)
      .def_ro("triangle_material", &SurfaceArrays::triangle_material)
      .def_ro("material_color", &SurfaceArrays::material_color)
      .def_ro("material_emission", &SurfaceArrays::material_emission)
      .def_ro("material_color_texture", &SurfaceArrays::material_color_texture)
      .def_ro("material_emission_texture", &SurfaceArrays::material_emission_texture)
      .def_ro("material_one_sided", &SurfaceArrays::material_one_sided)
      .def_ro("material_scattering", &SurfaceArrays::material_scattering)
      .def_ro("textures", &SurfaceArrays::textures);

  nb::class_<LightArrays>(m, "Lights", kLightsDoc)
      .def(nb::init<Array, Array, Array, OptionalArray, OptionalArray, OptionalArray, double,
                    double>(),
           nb::arg("light_lifts").noconvert(), nb::arg("light_of_lift").noconvert(),
           nb::arg("light_radiance").noconvert(), optional("light_cone"), optional("light_axis"),
           optional("light_copies"), nb::arg("light_reach") = kInf, nb::arg("geodesic_loop") = kInf)
      .def_ro("light_lifts", &LightArrays::light_lifts)
      .def_ro("light_of_lift", &LightArrays::light_of_lift)
      .def_ro("light_radiance", &LightArrays::light_radiance)
      .def_ro("light_cone", &LightArrays::light_cone)
      .def_ro("light_axis", &LightArrays::light_axis)
      .def_ro("light_copies", &LightArrays::light_copies)
      .def_ro("light_reach", &LightArrays::light_reach)
      .def_ro("geodesic_loop", &LightArrays::geodesic_loop);

  nb::class_<EmitterArrays>(m, "Emitters", kEmittersDoc)
      .def(nb::init<OptionalArray, OptionalArray, OptionalArray, OptionalArray, OptionalArray,
                    OptionalArray>(),
           optional("emitter_triangles"), optional("emitter_radiance"),
           optional("emitter_one_sided"), optional("emitter_group"), optional("emitter_copies"),
           optional("emitter_copy_group"))
      .def_ro("emitter_triangles", &EmitterArrays::emitter_triangles)
      .def_ro("emitter_radiance", &EmitterArrays::emitter_radiance)
      .def_ro("emitter_one_sided", &EmitterArrays::emitter_one_sided)
      .def_ro("emitter_group", &EmitterArrays::emitter_group)
      .def_ro("emitter_copies", &EmitterArrays::emitter_copies)
      .def_ro("emitter_copy_group", &EmitterArrays::emitter_copy_group);

  nb::class_<SceneRecord>(m, "Scene", kSceneDoc)
      .def(
          "__init__",
          [](SceneRecord* self, std::string geometry, DomainArrays domain, MeshArrays meshes,
             SurfaceArrays surfaces, LightArrays lights, InstanceArrays instances,
             EmitterArrays emitters, std::vector<double> geometry_parameters) {
            new (self) SceneRecord{std::move(geometry),  std::move(geometry_parameters),
                                   std::move(domain),    std::move(meshes),
                                   std::move(surfaces),  std::move(lights),
                                   std::move(instances), std::move(emitters)};
          },
          nb::arg("geometry"), nb::arg("domain"), nb::arg("meshes"), nb::arg("surfaces"),
          nb::arg("lights"), nb::arg("instances").sig("Instances()") = InstanceArrays{},
          nb::arg("emitters").sig("Emitters()") = EmitterArrays{},
          nb::arg("geometry_parameters") = std::vector<double>{})
      .def_ro("geometry", &SceneRecord::geometry)
      .def_ro("geometry_parameters", &SceneRecord::geometry_parameters)
      .def_ro("domain", &SceneRecord::domain)
      .def_ro("meshes", &SceneRecord::meshes)
      .def_ro("surfaces", &SceneRecord::surfaces)
      .def_ro("lights", &SceneRecord::lights)
      .def_ro("instances", &SceneRecord::instances)
      .def_ro("emitters", &SceneRecord::emitters);
}

}  // namespace thurston::bindings
