// The compiled-scene record checked into the core's SceneData: every array's dtype, shape, indices
// and values, with ValueErrors naming the array and the row.
#include <algorithm>
#include <cmath>
#include <optional>
#include <string>

#include "registry.hpp"
#include "scene_record.hpp"

namespace thurston::bindings {

namespace {

// Per-corner float32 (NT,3,C) rows, finite; empty where not given.
template <std::size_t C>
std::vector<std::array<std::array<float, C>, 3>> corner_rows(const OptionalArray& given,
                                                             std::int64_t NT, const char* name) {
  std::vector<std::array<std::array<float, C>, 3>> out;
  if (!given) return out;
  const Array& a = *given;
  const std::string shape = "(NT,3," + std::to_string(C) + ") with NT = len(triangles)";
  check<float>(a, name, {NT, 3, std::int64_t(C)}, shape.c_str());
  const auto* p = static_cast<const float*>(a.data());
  out.resize(NT);
  for (std::int64_t t = 0; t < NT; ++t)
    for (std::int64_t k = 0; k < 3; ++k)
      for (std::size_t c = 0; c < C; ++c) {
        const float x = p[t * a.stride(0) + k * a.stride(1) + std::int64_t(c) * a.stride(2)];
        if (!std::isfinite(x))
          throw nb::value_error(
              (std::string(name) + " contain NaN or inf at triangle " + std::to_string(t)).c_str());
        out[t][k][c] = x;
      }
  return out;
}

Texture make_texture(const Array& a, std::size_t index) {
  const std::string name = "textures[" + std::to_string(index) + "]";
  const std::int64_t channels = a.ndim() == 3 ? std::int64_t(a.shape(2)) : -1;
  check<float>(a, name.c_str(), {-1, -1, channels == 4 ? 4 : 3}, "(H,W,3) or (H,W,4)");
  if (a.shape(0) == 0 || a.shape(1) == 0 || a.shape(0) > (1 << 20) || a.shape(1) > (1 << 20))
    throw nb::value_error(
        (name + " must have between 1 and 2^20 rows and columns, got " + shape_text(a)).c_str());
  Texture t{int(a.shape(1)), int(a.shape(0)), int(channels), {}};
  t.texels.resize(std::size_t(t.width) * t.height * t.channels);
  const auto* p = static_cast<const float*>(a.data());
  std::size_t k = 0;
  for (std::int64_t r = 0; r < t.height; ++r)
    for (std::int64_t c = 0; c < t.width; ++c)
      for (std::int64_t ch = 0; ch < channels; ++ch) {
        const float x = p[r * a.stride(0) + c * a.stride(1) + ch * a.stride(2)];
        if (!std::isfinite(x))
          throw nb::value_error((name + " contains NaN or inf at row " + std::to_string(r) +
                                 ", column " + std::to_string(c))
                                    .c_str());
        t.texels[k++] = x;
      }
  return t;
}

// Each material's scattering from float32 (NM,4) rows (roughness, metallic, specular IOR level,
// IOR) as Blender's Principled BSDF has them; Lambert where not given.
std::vector<Principled> make_scattering(const OptionalArray& given, std::int64_t NM) {
  std::vector<Principled> out(NM);
  if (!given) return out;
  check<float>(*given, "material_scattering", {NM, 4}, "(NM,4) with NM = len(material_color)");
  const auto rows_ = rows<float, 4>(*given);
  for (std::int64_t m = 0; m < NM; ++m) {
    const auto& r = rows_[m];
    const auto bad = [&](const char* what) {
      return nb::value_error(("material_scattering row " + std::to_string(m) + ": " + what +
                              ", got " + std::to_string(r[0]) + ", " + std::to_string(r[1]) + ", " +
                              std::to_string(r[2]) + ", " + std::to_string(r[3]))
                                 .c_str());
    };
    for (float x : r)
      if (!std::isfinite(x)) throw bad("NaN or inf");
    if (!(r[0] >= 0.0f && r[0] <= 1.0f)) throw bad("roughness must be in [0, 1]");
    if (!(r[1] >= 0.0f && r[1] <= 1.0f)) throw bad("metallic must be in [0, 1]");
    if (!(r[2] >= 0.0f)) throw bad("the specular IOR level must be >= 0");
    if (!(r[3] > 0.0f)) throw bad("the IOR must be > 0");
    out[m] = Principled::from(r[0], r[1], r[2], r[3]);
  }
  return out;
}

// Materials by triangle (triangle_material given), their textures and the corner attributes.
Surfaces make_surfaces(const SurfaceArrays& given, std::int64_t NT) {
  Surfaces s;
  const Array& triangle_material = *given.triangle_material;
  check<std::int32_t>(triangle_material, "triangle_material", {NT},
                      "(NT,) with NT = len(triangles)");
  if (!given.material_color || !given.material_emission)
    throw nb::value_error("triangle_material needs material_color and material_emission");
  check<float>(*given.material_color, "material_color", {-1, 3}, "(NM,3)");
  const std::int64_t NM = given.material_color->shape(0);
  check<float>(*given.material_emission, "material_emission", {NM, 3},
               "(NM,3) with NM = len(material_color)");
  s.triangle_material = indices(triangle_material, NM, "triangle_material", "NM");
  const auto colors = rows<float, 3>(*given.material_color);
  const auto emissions = rows<float, 3>(*given.material_emission);
  require_finite(colors, "material_color");
  require_finite(emissions, "material_emission");
  for (std::size_t i = 0; i < given.textures.size(); ++i)
    s.textures.push_back(make_texture(given.textures[i], i));
  // -1 (no texture) or an index into textures
  const auto texture_of = [&](const OptionalArray& a, const char* name) {
    std::vector<std::int32_t> out(NM, -1);
    if (!a) return out;
    check<std::int32_t>(*a, name, {NM}, "(NM,) with NM = len(material_color)");
    const Strided2<std::int32_t> v = view2<std::int32_t>(*a);
    for (std::int64_t m = 0; m < NM; ++m) {
      out[m] = v(m, 0);
      if (out[m] < -1 || out[m] >= std::int64_t(s.textures.size()))
        throw nb::value_error((std::string(name) + " has " + std::to_string(out[m]) + " at row " +
                               std::to_string(m) + ", neither -1 (none) nor an index of the " +
                               std::to_string(s.textures.size()) + " textures")
                                  .c_str());
    }
    return out;
  };
  const auto color_texture = texture_of(given.material_color_texture, "material_color_texture");
  const auto emission_texture =
      texture_of(given.material_emission_texture, "material_emission_texture");
  std::vector<std::int32_t> one_sided(NM, 0);
  if (given.material_one_sided) {
    check<std::int32_t>(*given.material_one_sided, "material_one_sided", {NM},
                        "(NM,) with NM = len(material_color)");
    one_sided =
        indices(*given.material_one_sided, 2, "material_one_sided", "2 (0: both sides, 1: front)");
  }
  const std::vector<Principled> scattering = make_scattering(given.material_scattering, NM);
  for (std::int64_t m = 0; m < NM; ++m)
    s.materials.push_back({colors[m], emissions[m], color_texture[m], emission_texture[m],
                           one_sided[m] == 1, scattering[m]});
  s.corner_normals = corner_rows<3>(given.corner_normals, NT, "corner_normals");
  s.corner_uvs = corner_rows<2>(given.corner_uvs, NT, "corner_uvs");
  if (s.corner_uvs.empty() && NT > 0)  // (no triangles reach the domain: no texture is read)
    for (std::int64_t m = 0; m < NM; ++m)
      if (s.materials[m].color_texture >= 0 || s.materials[m].emission_texture >= 0)
        throw nb::value_error(
            ("material " + std::to_string(m) + " has a texture, which needs corner_uvs").c_str());
  return s;
}

// The meshes (ranges of triangles) and their instances; without them one mesh of all triangles
// placed once by the identity.
void make_instances(const OptionalArray& mesh_first_triangle, const InstanceArrays& given,
                    const std::string& geometry, std::int64_t NO, SceneData& scene) {
  Meshes& meshes = scene.meshes;
  const std::int64_t NT = meshes.triangles.size();
  meshes.first = {0};
  if (mesh_first_triangle) {
    check<std::int32_t>(*mesh_first_triangle, "mesh_first_triangle", {-1}, "(NMESH,)");
    const Strided2<std::int32_t> v = view2<std::int32_t>(*mesh_first_triangle);
    meshes.first.clear();
    for (std::size_t m = 0; m < mesh_first_triangle->shape(0); ++m) {
      const std::int32_t first = v(m, 0);
      if ((m == 0 && first != 0) || (m > 0 && first < std::int32_t(meshes.first.back())) ||
          first > NT)
        throw nb::value_error(("mesh_first_triangle must start at 0 and ascend to at most NT = " +
                               std::to_string(NT) + "; row " + std::to_string(m) + " is " +
                               std::to_string(first))
                                  .c_str());
      meshes.first.push_back(std::uint32_t(first));
    }
    if (meshes.first.empty())
      throw nb::value_error("mesh_first_triangle must name at least one mesh");
  }
  const std::int64_t NMESH = meshes.first.size();
  const bool any = given.instance_mesh || given.instance_transform || given.instance_object;
  if (!any) {
    if (NMESH != 1)
      throw nb::value_error(
          "meshes besides the first need instances (instance_mesh, instance_transform, "
          "instance_object)");
    scene.instances = {{0, 0, Affine{}}};
  } else {
    if (!given.instance_mesh || !given.instance_transform || !given.instance_object)
      throw nb::value_error("instance_mesh, instance_transform and instance_object go together");
    check<std::int32_t>(*given.instance_mesh, "instance_mesh", {-1}, "(NI,)");
    const std::int64_t NI = given.instance_mesh->shape(0);
    check<double>(*given.instance_transform, "instance_transform", {NI, 3, 4},
                  "(NI,3,4) with NI = len(instance_mesh)");
    check<std::int32_t>(*given.instance_object, "instance_object", {NI},
                        "(NI,) with NI = len(instance_mesh)");
    const std::vector<std::int32_t> mesh =
        indices(*given.instance_mesh, NMESH, "instance_mesh", "NMESH");
    const Strided2<std::int32_t> object = view2<std::int32_t>(*given.instance_object);
    const Array& t = *given.instance_transform;
    const auto* p = static_cast<const double*>(t.data());
    // the largest triangle object of each mesh, which the instance's object offset must keep below
    // NO
    std::vector<std::int32_t> top(NMESH, -1);
    for (std::int64_t m = 0; m < NMESH; ++m)
      for (std::int64_t k = meshes.first[m]; k < (m + 1 < NMESH ? meshes.first[m + 1] : NT); ++k)
        top[m] = std::max(top[m], meshes.triangle_object[k]);
    for (std::int64_t i = 0; i < NI; ++i) {
      Instance instance{std::uint32_t(mesh[i]), object(i, 0), {}};
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 4; ++c)
          instance.to_chart.m[4 * r + c] = p[i * t.stride(0) + r * t.stride(1) + c * t.stride(2)];
      const std::string row = "instance_transform row " + std::to_string(i);
      Affine inverse;
      for (double x : instance.to_chart.m) {
        if (!std::isfinite(x)) throw nb::value_error((row + " contains NaN or inf").c_str());
        if (!fits_float(x))
          throw nb::value_error(
              (row + " is beyond the range of float32, which Embree keeps it in").c_str());
      }
      if (!instance.to_chart.inverse(inverse))
        throw nb::value_error((row + " is singular (its 3x3 part has no inverse)").c_str());
      if (instance.object < 0 || instance.object + std::max(top[mesh[i]], 0) >= NO)
        throw nb::value_error(
            ("instance_object row " + std::to_string(i) + " is " + std::to_string(instance.object) +
             ": with its mesh's triangle_object it must stay in [0, NO = " + std::to_string(NO) +
             ")")
                .c_str());
      scene.instances.push_back(instance);
    }
  }
  const std::optional<ChartRegion> chart = chart_region(geometry);
  if (!chart) return;
  for (std::size_t i = 0; i < scene.instances.size(); ++i) {
    const Instance& instance = scene.instances[i];
    const std::uint32_t m = instance.mesh;
    for (std::int64_t k = meshes.first[m]; k < (m + 1 < NMESH ? meshes.first[m + 1] : NT); ++k)
      for (std::uint32_t v : meshes.triangles[k]) {
        if (!(*chart)(instance.to_chart.point(meshes.vertices[v])))
          throw nb::value_error(("vertices must lie inside " + std::string(chart->words) + " for " +
                                 geometry + "; vertex " + std::to_string(v) +
                                 " placed by instance " + std::to_string(i) + " does not")
                                    .c_str());
      }
  }
}

// The (C,4,4) float64 array m as row-major matrices.
std::vector<Mat4> matrices(const Array& m) {
  const auto* mp = static_cast<const double*>(m.data());
  std::vector<Mat4> out(std::size_t(m.shape(0)));
  for (std::size_t c = 0; c < out.size(); ++c)
    for (int r = 0; r < 4; ++r)
      for (int k = 0; k < 4; ++k)
        out[c][4 * r + k] = mp[std::int64_t(c) * m.stride(0) + r * m.stride(1) + k * m.stride(2)];
  return out;
}

// Spot cones, with each spot light's axis at each of its lifts.
void make_spots(const LightArrays& given, const std::string& geometry, Lights& lights) {
  const std::int64_t NL = lights.radiance.size(), K = lights.lifts.size();
  if (!given.light_cone && !given.light_axis) return;
  if (!given.light_cone || !given.light_axis)
    throw nb::value_error("light_cone and light_axis go together");
  check<double>(*given.light_cone, "light_cone", {NL, 2}, "(NL,2) with NL = len(light_radiance)");
  check<double>(*given.light_axis, "light_axis", {K, 4}, "(K,4) with K = len(light_lifts)");
  for (const auto& c : rows<double, 2>(*given.light_cone)) {
    if (!(c[0] >= -1.0 && c[0] <= 1.0) || !(c[1] > 0.0))
      throw nb::value_error(
          "light_cone rows must be (cos of the half angle in [-1, 1], smoothness > 0)");
    lights.cone.push_back({c[0], c[1]});
  }
  const auto lifts = rows<double, 4>(given.light_lifts), axes = rows<double, 4>(*given.light_axis);
  for (std::int64_t k = 0; k < K; ++k) {
    Vec4 X = lifts[k], V = axes[k];
    if (lights.cone[lights.of_lift[k]].active() && !normalise_direction(geometry, X, V))
      throw nb::value_error(
          ("light_axis row " + std::to_string(k) + " is no direction at its lift").c_str());
    lights.axis.push_back(V);
  }
}

// The emitters, where given.
void make_emitters(const EmitterArrays& given, Emitters& e) {
  const bool any = given.emitter_triangles || given.emitter_radiance || given.emitter_one_sided ||
                   given.emitter_group || given.emitter_copies || given.emitter_copy_group;
  if (!any) return;
  if (!given.emitter_triangles || !given.emitter_radiance || !given.emitter_one_sided ||
      !given.emitter_group || !given.emitter_copies || !given.emitter_copy_group)
    throw nb::value_error(
        "emitter_triangles, emitter_radiance, emitter_one_sided, emitter_group, "
        "emitter_copies and emitter_copy_group go together");
  check<double>(*given.emitter_triangles, "emitter_triangles", {-1, 3, 3}, "(E,3,3)");
  const std::int64_t E = given.emitter_triangles->shape(0);
  check<float>(*given.emitter_radiance, "emitter_radiance", {E, 3},
               "(E,3) with E = len(emitter_triangles)");
  check<std::int32_t>(*given.emitter_one_sided, "emitter_one_sided", {E},
                      "(E,) with E = len(emitter_triangles)");
  check<std::int32_t>(*given.emitter_group, "emitter_group", {E},
                      "(E,) with E = len(emitter_triangles)");
  check<double>(*given.emitter_copies, "emitter_copies", {-1, 4, 4}, "(C,4,4)");
  const std::int64_t C = given.emitter_copies->shape(0);
  check<std::int32_t>(*given.emitter_copy_group, "emitter_copy_group", {C},
                      "(C,) with C = len(emitter_copies)");
  const Array& t = *given.emitter_triangles;
  const auto* tp = static_cast<const double*>(t.data());
  for (std::int64_t i = 0; i < E; ++i) {
    std::array<Vec3, 3> tri;
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a)
        tri[k][a] = tp[i * t.stride(0) + k * t.stride(1) + a * t.stride(2)];
    for (const Vec3& x : tri)
      if (!std::isfinite(x[0] + x[1] + x[2]))
        throw nb::value_error(
            ("emitter_triangles row " + std::to_string(i) + " contains NaN or inf").c_str());
    if (!(norm3(cross3(sub3(tri[1], tri[0]), sub3(tri[2], tri[0]))) > 0.0))
      throw nb::value_error(
          ("emitter_triangles row " + std::to_string(i) + " has no area").c_str());
    e.triangles.push_back(tri);
  }
  e.radiance = rows<float, 3>(*given.emitter_radiance);
  require_finite(e.radiance, "emitter_radiance");
  for (const Rgb& r : e.radiance)
    if (r[0] < 0.0f || r[1] < 0.0f || r[2] < 0.0f)
      throw nb::value_error("emitter_radiance must be >= 0");
  for (std::int32_t one :
       indices(*given.emitter_one_sided, 2, "emitter_one_sided", "2 (0: both sides, 1: front)"))
    e.one_sided.push_back(std::uint8_t(one));
  const std::int64_t groups = C;  // every group has a copy, so there are at most C
  e.group = indices(*given.emitter_group, groups, "emitter_group", "C");
  e.copy_group = indices(*given.emitter_copy_group, std::max<std::int64_t>(groups, 1),
                         "emitter_copy_group", "C");
  e.copies = matrices(*given.emitter_copies);
  require_finite(e.copies, "emitter_copies");
}

}  // namespace

SceneData scene_from_record(const SceneRecord& record) {
  const std::string& geometry = record.geometry;
  const DomainArrays& domain = record.domain;
  const MeshArrays& meshes = record.meshes;
  const SurfaceArrays& surfaces = record.surfaces;
  const LightArrays& lights = record.lights;
  if (!(lights.light_reach >= 0.0))
    throw nb::value_error("light_reach must be a distance >= 0 (inf: every lift)");
  if (!(lights.geodesic_loop > 0.0)) throw nb::value_error("geodesic_loop must be > 0 (inf: none)");
  if (!has_geometry(geometry)) {
    std::string known;
    for (const std::string& name : geometry_names()) known += (known.empty() ? "" : ", ") + name;
    throw nb::value_error(("unknown geometry '" + geometry + "' (known: " + known + ")").c_str());
  }
  if (!accepts_parameters(geometry, record.geometry_parameters))
    throw nb::value_error(("geometry_parameters are not " + geometry +
                           "'s (graph: its kernel_parameters; the others: none)")
                              .c_str());
  SceneData scene;
  scene.geometry_parameters = record.geometry_parameters;

  check<double>(domain.face_covectors, "face_covectors", {-1, 4}, "(F,4)");
  const std::int64_t F = domain.face_covectors.shape(0);
  check<double>(domain.face_maps, "face_maps", {F, 4, 4}, "(F,4,4) with F = len(face_covectors)");
  scene.domain.covectors = rows<double, 4>(domain.face_covectors);
  require_finite(scene.domain.covectors, "face_covectors");
  scene.domain.maps.resize(F);
  {
    const auto* m = static_cast<const double*>(domain.face_maps.data());
    for (std::int64_t f = 0; f < F; ++f)
      for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c)
          scene.domain.maps[f][4 * r + c] =
              m[f * domain.face_maps.stride(0) + r * domain.face_maps.stride(1) +
                c * domain.face_maps.stride(2)];
  }
  require_finite(scene.domain.maps, "face_maps");

  check<double>(meshes.vertices, "vertices", {-1, 3}, "(NV,3)");
  const auto vertex_rows = rows<double, 3>(meshes.vertices);
  require_finite(vertex_rows, "vertices");
  require_float_range(vertex_rows, "vertices");
  scene.meshes.vertices = vertex_rows;

  check<std::int32_t>(meshes.triangles, "triangles", {-1, 3}, "(NT,3)");
  const std::int64_t NT = meshes.triangles.shape(0);
  check<std::int32_t>(meshes.triangle_object, "triangle_object", {NT},
                      "(NT,) with NT = len(triangles)");
  check<float>(surfaces.object_color, "object_color", {-1, 3}, "(NO,3)");
  const std::int64_t NO = surfaces.object_color.shape(0);
  check<float>(surfaces.object_emission, "object_emission", {NO, 3},
               "(NO,3) with NO = len(object_color)");
  const std::int64_t NV = vertex_rows.size();
  for (const auto& tri : rows<std::int32_t, 3>(meshes.triangles)) {
    for (std::int32_t v : tri)
      if (v < 0 || v >= NV)
        throw nb::value_error(("triangles has vertex index " + std::to_string(v) +
                               ", outside [0, NV = " + std::to_string(NV) + ")")
                                  .c_str());
    scene.meshes.triangles.push_back(
        {std::uint32_t(tri[0]), std::uint32_t(tri[1]), std::uint32_t(tri[2])});
  }
  scene.meshes.triangle_object = indices(meshes.triangle_object, NO, "triangle_object", "NO");
  make_instances(meshes.mesh_first_triangle, record.instances, geometry, NO, scene);
  const auto colors = rows<float, 3>(surfaces.object_color),
             emissions = rows<float, 3>(surfaces.object_emission);
  require_finite(colors, "object_color");
  require_finite(emissions, "object_emission");
  if (surfaces.triangle_material) {
    scene.surfaces = make_surfaces(surfaces, NT);
  } else {  // one material per object
    for (std::int64_t o = 0; o < NO; ++o)
      scene.surfaces.materials.push_back({colors[o], emissions[o]});
    scene.surfaces.triangle_material = scene.meshes.triangle_object;
    scene.surfaces.corner_normals = corner_rows<3>(surfaces.corner_normals, NT, "corner_normals");
    scene.surfaces.corner_uvs = corner_rows<2>(surfaces.corner_uvs, NT, "corner_uvs");
    if (surfaces.material_color || surfaces.material_emission || surfaces.material_color_texture ||
        surfaces.material_emission_texture || surfaces.material_one_sided ||
        surfaces.material_scattering || !surfaces.textures.empty())
      throw nb::value_error(
          "material arrays and textures need triangle_material (the material of each triangle)");
  }

  check<double>(lights.light_lifts, "light_lifts", {-1, 4}, "(K,4)");
  const std::int64_t K = lights.light_lifts.shape(0);
  check<std::int32_t>(lights.light_of_lift, "light_of_lift", {K}, "(K,) with K = len(light_lifts)");
  check<float>(lights.light_radiance, "light_radiance", {-1, 3}, "(NL,3)");
  Lights& lit = scene.lights;
  lit.radiance = rows<float, 3>(lights.light_radiance);
  require_finite(lit.radiance, "light_radiance");
  lit.of_lift =
      indices(lights.light_of_lift, lights.light_radiance.shape(0), "light_of_lift", "NL");
  lit.lifts = rows<double, 4>(lights.light_lifts);
  for (std::size_t i = 0; i < lit.lifts.size(); ++i)
    if (!finite4(lit.lifts[i]) || !normalise_point(geometry, lit.lifts[i]))
      throw nb::value_error(
          ("light_lifts row " + std::to_string(i) + " is not a point of " + geometry).c_str());
  make_spots(lights, geometry, lit);
  if (lights.light_copies) {
    check<double>(*lights.light_copies, "light_copies", {K, 4, 4},
                  "(K,4,4) with K = len(light_lifts)");
    lit.copies = matrices(*lights.light_copies);
    require_finite(lit.copies, "light_copies");
  }
  make_emitters(record.emitters, scene.emitters);
  lit.reach = lights.light_reach;
  lit.geodesic_loop = lights.geodesic_loop;
  return scene;
}

}  // namespace thurston::bindings
