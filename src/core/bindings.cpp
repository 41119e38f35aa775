// Python bindings: argument validation, numpy outputs, and the GIL around traces.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/array.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <algorithm>
#include <cmath>
#include <exception>
#include <iterator>
#include <limits>
#include <string>
#include <utility>

#include "tracer.hpp"

namespace nb = nanobind;
using namespace thurston;

namespace {

// The Python Tracer: the geometry's tracer behind one handle.
struct TracerHandle {
  std::unique_ptr<Tracer> tracer;
  std::string geometry;
};

// Any CPU array; dtype and shape are checked by hand to raise ValueError with a clear message.
using Array = nb::ndarray<nb::ro, nb::device::cpu>;

std::string dtype_name(nb::dlpack::dtype dt) {
  const char* kind = "unknown";
  switch (nb::dlpack::dtype_code(dt.code)) {
    case nb::dlpack::dtype_code::Int: kind = "int"; break;
    case nb::dlpack::dtype_code::UInt: kind = "uint"; break;
    case nb::dlpack::dtype_code::Float: kind = "float"; break;
    case nb::dlpack::dtype_code::Bool: return "bool";
    default: break;
  }
  return kind + std::to_string(int(dt.bits));
}

template <class T> const char* type_name();
template <> const char* type_name<double>() { return "float64"; }
template <> const char* type_name<float>() { return "float32"; }
template <> const char* type_name<std::int32_t>() { return "int32"; }

using OptionalArray = std::optional<Array>;

std::string shape_text(const Array& a) {
  std::string s = "(";
  for (std::size_t d = 0; d < a.ndim(); ++d) s += (d ? ", " : "") + std::to_string(a.shape(d));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

// Checks dtype and shape; -1 in `shape` matches any length. `expected` names the shape for errors.
template <class T>
void check(const Array& a, const char* name, std::initializer_list<std::int64_t> shape,
           const char* expected) {
  if (a.dtype() != nb::dtype<T>())
    throw nb::value_error((std::string(name) + " must have dtype " + type_name<T>() + ", got " +
                           dtype_name(a.dtype())).c_str());
  bool ok = a.ndim() == shape.size();
  std::size_t d = 0;
  for (std::int64_t n : shape) {
    if (ok && n >= 0 && std::int64_t(a.shape(d)) != n) ok = false;
    ++d;
  }
  if (!ok)
    throw nb::value_error((std::string(name) + " must have shape " + expected + ", got " +
                           shape_text(a)).c_str());
}

template <class T>
Strided2<T> view2(const Array& a) {
  return {static_cast<const T*>(a.data()), a.stride(0), a.ndim() > 1 ? a.stride(1) : 0};
}

template <class T, std::size_t C>
std::vector<std::array<T, C>> rows(const Array& a) {
  const Strided2<T> v = view2<T>(a);
  std::vector<std::array<T, C>> out(a.shape(0));
  for (std::size_t i = 0; i < out.size(); ++i)
    for (std::size_t j = 0; j < C; ++j) out[i][j] = v(i, j);
  return out;
}

std::vector<std::int32_t> indices(const Array& a, std::int64_t bound, const char* name,
                                  const char* bound_name) {
  const Strided2<std::int32_t> v = view2<std::int32_t>(a);
  std::vector<std::int32_t> out(a.shape(0));
  for (std::size_t i = 0; i < out.size(); ++i) {
    out[i] = v(i, 0);
    if (out[i] < 0 || out[i] >= bound)
      throw nb::value_error((std::string(name) + " has index " + std::to_string(out[i]) +
                             " at row " + std::to_string(i) + ", outside [0, " + bound_name +
                             " = " + std::to_string(bound) + ")").c_str());
  }
  return out;
}

template <class T, std::size_t C>
void require_finite(const std::vector<std::array<T, C>>& rows, const char* name) {
  for (std::size_t i = 0; i < rows.size(); ++i)
    for (T x : rows[i])
      if (!std::isfinite(x))
        throw nb::value_error((std::string(name) + " contain NaN or inf at row " +
                               std::to_string(i)).c_str());
}

// Embree holds vertices and instance maps as float: a finite double beyond float's range would
// become inf there.
bool fits_float(double x) { return std::isfinite(x) && std::fabs(x) <= double(std::numeric_limits<float>::max()); }

template <std::size_t C>
void require_float_range(const std::vector<std::array<double, C>>& rows, const char* name) {
  for (std::size_t i = 0; i < rows.size(); ++i)
    for (double x : rows[i])
      if (!fits_float(x))
        throw nb::value_error((std::string(name) + " row " + std::to_string(i) +
                               " is beyond the range of float32, which Embree keeps it in").c_str());
}

// The optional surface arguments of the constructor, as given.
struct SurfaceArrays {
  OptionalArray corner_normals, corner_uvs, triangle_material, material_color, material_emission,
      material_color_texture, material_emission_texture, material_one_sided, material_scattering;
  std::vector<Array> textures;
};

// The optional light arguments of the constructor besides the point lights' lifts: spot cones
// and emitters, as given.
struct LightArrays {
  OptionalArray light_cone, light_axis, emitter_triangles, emitter_radiance, emitter_one_sided,
      emitter_group, emitter_copies, emitter_copy_group;
};

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
          throw nb::value_error((std::string(name) + " contain NaN or inf at triangle " +
                                 std::to_string(t)).c_str());
        out[t][k][c] = x;
      }
  return out;
}

Texture make_texture(const Array& a, std::size_t index) {
  const std::string name = "textures[" + std::to_string(index) + "]";
  const std::int64_t channels = a.ndim() == 3 ? std::int64_t(a.shape(2)) : -1;
  check<float>(a, name.c_str(), {-1, -1, channels == 4 ? 4 : 3}, "(H,W,3) or (H,W,4)");
  if (a.shape(0) == 0 || a.shape(1) == 0 || a.shape(0) > (1 << 20) || a.shape(1) > (1 << 20))
    throw nb::value_error((name + " must have between 1 and 2^20 rows and columns, got " +
                           shape_text(a)).c_str());
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
                                 ", column " + std::to_string(c)).c_str());
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
      return nb::value_error(("material_scattering row " + std::to_string(m) + ": " + what + ", got " +
                              std::to_string(r[0]) + ", " + std::to_string(r[1]) + ", " +
                              std::to_string(r[2]) + ", " + std::to_string(r[3])).c_str());
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
  check<std::int32_t>(triangle_material, "triangle_material", {NT}, "(NT,) with NT = len(triangles)");
  if (!given.material_color || !given.material_emission)
    throw nb::value_error("triangle_material needs material_color and material_emission");
  check<float>(*given.material_color, "material_color", {-1, 3}, "(NM,3)");
  const std::int64_t NM = given.material_color->shape(0);
  check<float>(*given.material_emission, "material_emission", {NM, 3}, "(NM,3) with NM = len(material_color)");
  s.triangle_material = indices(triangle_material, NM, "triangle_material", "NM");
  const auto colors = rows<float, 3>(*given.material_color);
  const auto emissions = rows<float, 3>(*given.material_emission);
  require_finite(colors, "material_color");
  require_finite(emissions, "material_emission");
  for (std::size_t i = 0; i < given.textures.size(); ++i) s.textures.push_back(make_texture(given.textures[i], i));
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
                               std::to_string(s.textures.size()) + " textures").c_str());
    }
    return out;
  };
  const auto color_texture = texture_of(given.material_color_texture, "material_color_texture");
  const auto emission_texture = texture_of(given.material_emission_texture, "material_emission_texture");
  std::vector<std::int32_t> one_sided(NM, 0);
  if (given.material_one_sided) {
    check<std::int32_t>(*given.material_one_sided, "material_one_sided", {NM}, "(NM,) with NM = len(material_color)");
    one_sided = indices(*given.material_one_sided, 2, "material_one_sided", "2 (0: both sides, 1: front)");
  }
  const std::vector<Principled> scattering = make_scattering(given.material_scattering, NM);
  for (std::int64_t m = 0; m < NM; ++m)
    s.materials.push_back({colors[m], emissions[m], color_texture[m], emission_texture[m], one_sided[m] == 1,
                           scattering[m]});
  s.corner_normals = corner_rows<3>(given.corner_normals, NT, "corner_normals");
  s.corner_uvs = corner_rows<2>(given.corner_uvs, NT, "corner_uvs");
  if (s.corner_uvs.empty())
    for (std::int64_t m = 0; m < NM; ++m)
      if (s.materials[m].color_texture >= 0 || s.materials[m].emission_texture >= 0)
        throw nb::value_error(("material " + std::to_string(m) +
                               " has a texture, which needs corner_uvs").c_str());
  return s;
}

// The optional mesh and instance arguments of the constructor, as given.
struct InstanceArrays {
  OptionalArray mesh_first_triangle, instance_mesh, instance_transform, instance_object;
};

// The meshes (ranges of triangles) and their instances; without them one mesh of all triangles
// placed once by the identity.
void make_instances(const InstanceArrays& given, const std::string& geometry, std::int64_t NO,
                    SceneData& scene) {
  const std::int64_t NT = scene.triangles.size();
  scene.mesh_first = {0};
  if (given.mesh_first_triangle) {
    check<std::int32_t>(*given.mesh_first_triangle, "mesh_first_triangle", {-1}, "(NMESH,)");
    const Strided2<std::int32_t> v = view2<std::int32_t>(*given.mesh_first_triangle);
    scene.mesh_first.clear();
    for (std::size_t m = 0; m < given.mesh_first_triangle->shape(0); ++m) {
      const std::int32_t first = v(m, 0);
      if ((m == 0 && first != 0) || (m > 0 && first < std::int32_t(scene.mesh_first.back())) || first > NT)
        throw nb::value_error(("mesh_first_triangle must start at 0 and ascend to at most NT = " +
                               std::to_string(NT) + "; row " + std::to_string(m) + " is " +
                               std::to_string(first)).c_str());
      scene.mesh_first.push_back(std::uint32_t(first));
    }
    if (scene.mesh_first.empty()) throw nb::value_error("mesh_first_triangle must name at least one mesh");
  }
  const std::int64_t NMESH = scene.mesh_first.size();
  const bool any = given.instance_mesh || given.instance_transform || given.instance_object;
  if (!any) {
    if (NMESH != 1) throw nb::value_error("meshes besides the first need instances (instance_mesh, instance_transform, instance_object)");
    scene.instances = {{0, 0, Affine{}}};
  } else {
    if (!given.instance_mesh || !given.instance_transform || !given.instance_object)
      throw nb::value_error("instance_mesh, instance_transform and instance_object go together");
    check<std::int32_t>(*given.instance_mesh, "instance_mesh", {-1}, "(NI,)");
    const std::int64_t NI = given.instance_mesh->shape(0);
    check<double>(*given.instance_transform, "instance_transform", {NI, 3, 4}, "(NI,3,4) with NI = len(instance_mesh)");
    check<std::int32_t>(*given.instance_object, "instance_object", {NI}, "(NI,) with NI = len(instance_mesh)");
    const std::vector<std::int32_t> mesh = indices(*given.instance_mesh, NMESH, "instance_mesh", "NMESH");
    const Strided2<std::int32_t> object = view2<std::int32_t>(*given.instance_object);
    const Array& t = *given.instance_transform;
    const auto* p = static_cast<const double*>(t.data());
    // the largest triangle object of each mesh, which the instance's object offset must keep below NO
    std::vector<std::int32_t> top(NMESH, -1);
    for (std::int64_t m = 0; m < NMESH; ++m)
      for (std::int64_t k = scene.mesh_first[m]; k < (m + 1 < NMESH ? scene.mesh_first[m + 1] : NT); ++k)
        top[m] = std::max(top[m], scene.triangle_object[k]);
    for (std::int64_t i = 0; i < NI; ++i) {
      Instance instance{std::uint32_t(mesh[i]), object(i, 0), {}};
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 4; ++c)
          instance.to_chart.m[4 * r + c] = p[i * t.stride(0) + r * t.stride(1) + c * t.stride(2)];
      const std::string row = "instance_transform row " + std::to_string(i);
      Affine inverse;
      for (double x : instance.to_chart.m) {
        if (!std::isfinite(x)) throw nb::value_error((row + " contains NaN or inf").c_str());
        if (!fits_float(x)) throw nb::value_error((row + " is beyond the range of float32, which Embree keeps it in").c_str());
      }
      if (!instance.to_chart.inverse(inverse))
        throw nb::value_error((row + " is singular (its 3x3 part has no inverse)").c_str());
      if (instance.object < 0 || instance.object + std::max(top[mesh[i]], 0) >= NO)
        throw nb::value_error(("instance_object row " + std::to_string(i) + " is " +
                               std::to_string(instance.object) + ": with its mesh's triangle_object it must stay in [0, NO = " +
                               std::to_string(NO) + ")").c_str());
      scene.instances.push_back(instance);
    }
  }
  if (geometry != "H3") return;
  for (std::size_t i = 0; i < scene.instances.size(); ++i) {
    const Instance& instance = scene.instances[i];
    const std::uint32_t m = instance.mesh;
    for (std::int64_t k = scene.mesh_first[m]; k < (m + 1 < NMESH ? scene.mesh_first[m + 1] : NT); ++k)
      for (std::uint32_t v : scene.triangles[k]) {
        const Vec3 x = instance.to_chart.point(scene.vertices[v]);
        if (dot3(x, x) >= 1.0)
          throw nb::value_error(("vertices must lie inside the unit ball (the Klein model) for H3; vertex " +
                                 std::to_string(v) + " placed by instance " + std::to_string(i) + " does not").c_str());
      }
  }
}

SceneData make_scene(const std::string& geometry, const Array& face_covectors, const Array& face_maps,
                     const Array& vertices, const Array& triangles, const Array& triangle_object,
                     const Array& object_color, const Array& object_emission,
                     const Array& light_lifts, const Array& light_of_lift,
                     const Array& light_radiance, const SurfaceArrays& surfaces,
                     const InstanceArrays& instances) {
  if (!has_geometry(geometry)) {
    std::string known;
    for (const std::string& name : geometry_names()) known += (known.empty() ? "" : ", ") + name;
    throw nb::value_error(("unknown geometry '" + geometry + "' (known: " + known + ")").c_str());
  }
  SceneData scene;

  check<double>(face_covectors, "face_covectors", {-1, 4}, "(F,4)");
  const std::int64_t F = face_covectors.shape(0);
  check<double>(face_maps, "face_maps", {F, 4, 4}, "(F,4,4) with F = len(face_covectors)");
  scene.face_covectors = rows<double, 4>(face_covectors);
  require_finite(scene.face_covectors, "face_covectors");
  scene.face_maps.resize(F);
  {
    const auto* m = static_cast<const double*>(face_maps.data());
    for (std::int64_t f = 0; f < F; ++f)
      for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c)
          scene.face_maps[f][4 * r + c] =
              m[f * face_maps.stride(0) + r * face_maps.stride(1) + c * face_maps.stride(2)];
  }
  require_finite(scene.face_maps, "face_maps");

  check<double>(vertices, "vertices", {-1, 3}, "(NV,3)");
  const auto vertex_rows = rows<double, 3>(vertices);
  require_finite(vertex_rows, "vertices");
  require_float_range(vertex_rows, "vertices");
  scene.vertices = vertex_rows;

  check<std::int32_t>(triangles, "triangles", {-1, 3}, "(NT,3)");
  const std::int64_t NT = triangles.shape(0);
  check<std::int32_t>(triangle_object, "triangle_object", {NT}, "(NT,) with NT = len(triangles)");
  check<float>(object_color, "object_color", {-1, 3}, "(NO,3)");
  const std::int64_t NO = object_color.shape(0);
  check<float>(object_emission, "object_emission", {NO, 3},
               "(NO,3) with NO = len(object_color)");
  const std::int64_t NV = vertex_rows.size();
  for (const auto& tri : rows<std::int32_t, 3>(triangles)) {
    for (std::int32_t v : tri)
      if (v < 0 || v >= NV)
        throw nb::value_error(("triangles has vertex index " + std::to_string(v) +
                               ", outside [0, NV = " + std::to_string(NV) + ")").c_str());
    scene.triangles.push_back({std::uint32_t(tri[0]), std::uint32_t(tri[1]), std::uint32_t(tri[2])});
  }
  scene.triangle_object = indices(triangle_object, NO, "triangle_object", "NO");
  make_instances(instances, geometry, NO, scene);
  const auto colors = rows<float, 3>(object_color), emissions = rows<float, 3>(object_emission);
  require_finite(colors, "object_color");
  require_finite(emissions, "object_emission");
  if (surfaces.triangle_material) {
    scene.surfaces = make_surfaces(surfaces, NT);
  } else {  // one material per object
    for (std::int64_t o = 0; o < NO; ++o) scene.surfaces.materials.push_back({colors[o], emissions[o]});
    scene.surfaces.triangle_material = scene.triangle_object;
    scene.surfaces.corner_normals = corner_rows<3>(surfaces.corner_normals, NT, "corner_normals");
    scene.surfaces.corner_uvs = corner_rows<2>(surfaces.corner_uvs, NT, "corner_uvs");
    if (surfaces.material_color || surfaces.material_emission || surfaces.material_color_texture ||
        surfaces.material_emission_texture || surfaces.material_one_sided || surfaces.material_scattering ||
        !surfaces.textures.empty())
      throw nb::value_error("material arrays and textures need triangle_material (the material of each triangle)");
  }

  check<double>(light_lifts, "light_lifts", {-1, 4}, "(K,4)");
  const std::int64_t K = light_lifts.shape(0);
  check<std::int32_t>(light_of_lift, "light_of_lift", {K}, "(K,) with K = len(light_lifts)");
  check<float>(light_radiance, "light_radiance", {-1, 3}, "(NL,3)");
  scene.light_radiance = rows<float, 3>(light_radiance);
  require_finite(scene.light_radiance, "light_radiance");
  scene.light_of_lift = indices(light_of_lift, light_radiance.shape(0), "light_of_lift", "NL");
  scene.light_lifts = rows<double, 4>(light_lifts);
  for (std::size_t i = 0; i < scene.light_lifts.size(); ++i)
    if (!finite4(scene.light_lifts[i]) || !normalise_point(geometry, scene.light_lifts[i]))
      throw nb::value_error(("light_lifts row " + std::to_string(i) + " is not a point of " +
                             geometry).c_str());
  return scene;
}

// Spot cones (with each spot light's axis at each of its lifts) and the emitters.
void make_lights(const LightArrays& given, const std::string& geometry, const Array& light_lifts,
                 SceneData& scene) {
  const std::int64_t NL = scene.light_radiance.size(), K = scene.light_lifts.size();
  if (given.light_cone || given.light_axis) {
    if (!given.light_cone || !given.light_axis) throw nb::value_error("light_cone and light_axis go together");
    check<double>(*given.light_cone, "light_cone", {NL, 2}, "(NL,2) with NL = len(light_radiance)");
    check<double>(*given.light_axis, "light_axis", {K, 4}, "(K,4) with K = len(light_lifts)");
    for (const auto& c : rows<double, 2>(*given.light_cone)) {
      if (!(c[0] >= -1.0 && c[0] <= 1.0) || !(c[1] > 0.0))
        throw nb::value_error("light_cone rows must be (cos of the half angle in [-1, 1], smoothness > 0)");
      scene.light_cone.push_back({c[0], c[1]});
    }
    const auto lifts = rows<double, 4>(light_lifts), axes = rows<double, 4>(*given.light_axis);
    for (std::int64_t k = 0; k < K; ++k) {
      Vec4 X = lifts[k], V = axes[k];
      if (scene.light_cone[scene.light_of_lift[k]].active() && !normalise_direction(geometry, X, V))
        throw nb::value_error(("light_axis row " + std::to_string(k) + " is no direction at its lift").c_str());
      scene.light_axis.push_back(V);
    }
  }
  const bool any = given.emitter_triangles || given.emitter_radiance || given.emitter_one_sided ||
                   given.emitter_group || given.emitter_copies || given.emitter_copy_group;
  if (!any) return;
  if (!given.emitter_triangles || !given.emitter_radiance || !given.emitter_one_sided ||
      !given.emitter_group || !given.emitter_copies || !given.emitter_copy_group)
    throw nb::value_error("emitter_triangles, emitter_radiance, emitter_one_sided, emitter_group, "
                          "emitter_copies and emitter_copy_group go together");
  Emitters& e = scene.emitters;
  check<double>(*given.emitter_triangles, "emitter_triangles", {-1, 3, 3}, "(E,3,3)");
  const std::int64_t E = given.emitter_triangles->shape(0);
  check<float>(*given.emitter_radiance, "emitter_radiance", {E, 3}, "(E,3) with E = len(emitter_triangles)");
  check<std::int32_t>(*given.emitter_one_sided, "emitter_one_sided", {E}, "(E,) with E = len(emitter_triangles)");
  check<std::int32_t>(*given.emitter_group, "emitter_group", {E}, "(E,) with E = len(emitter_triangles)");
  check<double>(*given.emitter_copies, "emitter_copies", {-1, 4, 4}, "(C,4,4)");
  const std::int64_t C = given.emitter_copies->shape(0);
  check<std::int32_t>(*given.emitter_copy_group, "emitter_copy_group", {C}, "(C,) with C = len(emitter_copies)");
  const Array& t = *given.emitter_triangles;
  const auto* tp = static_cast<const double*>(t.data());
  for (std::int64_t i = 0; i < E; ++i) {
    std::array<Vec3, 3> tri;
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a) tri[k][a] = tp[i * t.stride(0) + k * t.stride(1) + a * t.stride(2)];
    for (const Vec3& x : tri)
      if (!std::isfinite(x[0] + x[1] + x[2]))
        throw nb::value_error(("emitter_triangles row " + std::to_string(i) + " contains NaN or inf").c_str());
    if (!(norm3(cross3(sub3(tri[1], tri[0]), sub3(tri[2], tri[0]))) > 0.0))
      throw nb::value_error(("emitter_triangles row " + std::to_string(i) + " has no area").c_str());
    e.triangles.push_back(tri);
  }
  e.radiance = rows<float, 3>(*given.emitter_radiance);
  require_finite(e.radiance, "emitter_radiance");
  for (const Rgb& r : e.radiance)
    if (r[0] < 0.0f || r[1] < 0.0f || r[2] < 0.0f) throw nb::value_error("emitter_radiance must be >= 0");
  for (std::int32_t one : indices(*given.emitter_one_sided, 2, "emitter_one_sided", "2 (0: both sides, 1: front)"))
    e.one_sided.push_back(std::uint8_t(one));
  const std::int64_t groups = C;  // every group has a copy, so there are at most C
  e.group = indices(*given.emitter_group, groups, "emitter_group", "C");
  e.copy_group = indices(*given.emitter_copy_group, std::max<std::int64_t>(groups, 1), "emitter_copy_group", "C");
  const Array& m = *given.emitter_copies;
  const auto* mp = static_cast<const double*>(m.data());
  for (std::int64_t c = 0; c < C; ++c) {
    Mat4 M;
    for (int r = 0; r < 4; ++r)
      for (int k = 0; k < 4; ++k) M[4 * r + k] = mp[c * m.stride(0) + r * m.stride(1) + k * m.stride(2)];
    e.copies.push_back(M);
  }
  require_finite(e.copies, "emitter_copies");
}

// A numpy array that owns `data` (allocated with new[]).
template <class T>
nb::object to_numpy(std::unique_ptr<T[]> data, std::initializer_list<std::size_t> shape) {
  T* raw = data.get();
  nb::capsule owner(raw, [](void* p) noexcept { delete[] static_cast<T*>(p); });
  data.release();
  return nb::cast(nb::ndarray<nb::numpy, T>(raw, shape, owner));
}

void check_rays(const Array& a, const Array& b, const char* a_name, const char* b_name,
                std::int64_t width, const char* what) {
  const std::string shape = width == 4 ? "(N,4)" : "(N,3)";
  check<double>(a, a_name, {-1, width}, shape.c_str());
  check<double>(b, b_name, {std::int64_t(a.shape(0)), width},
                (shape + " with N = len(" + a_name + ")").c_str());
  const Strided2<double> va = view2<double>(a), vb = view2<double>(b);
  for (std::size_t i = 0; i < a.shape(0); ++i)
    for (std::int64_t j = 0; j < width; ++j)
      if (!std::isfinite(va(i, j)) || !std::isfinite(vb(i, j)))
        throw nb::value_error((std::string(what) + " " + std::to_string(i) + " has a non-finite " +
                               (width == 4 ? "origin or direction" : "start or end")).c_str());
}

nb::dict trace(TracerHandle& handle, const Array& origins, const Array& directions, double max_distance,
               int max_crossings, bool shade, nb::object progress, bool record_segments,
               double tolerance, double tolerance_per_distance, bool skip_empty, double fog,
               int light_samples, std::uint64_t seed, int bounces, const std::string& emitter_sampling) {
  if (light_samples < 1) throw nb::value_error("light_samples must be >= 1");
  const char* const sampling_names[] = {"mis", "light", "bounce"};
  const auto sampling = std::find(std::begin(sampling_names), std::end(sampling_names), emitter_sampling);
  if (sampling == std::end(sampling_names))
    throw nb::value_error(("emitter_sampling must be 'mis', 'light' or 'bounce', got '" + emitter_sampling + "'").c_str());
  if (bounces < 0) throw nb::value_error("bounces must be >= 0 (0: direct light only)");
  check_rays(origins, directions, "origins", "directions", 4, "ray");
  if (!(fog > 0.0)) throw nb::value_error("fog must be a positive distance (inf: none)");
  if (std::isnan(max_distance) || max_distance < 0.0)
    throw nb::value_error("max_distance must be >= 0 (inf allowed)");
  if (max_crossings < 0) throw nb::value_error("max_crossings must be >= 0");
  if (!(tolerance > 0.0) || !std::isfinite(tolerance))
    throw nb::value_error("tolerance must be a positive finite number (chart units)");
  if (!(tolerance_per_distance >= 0.0) || !std::isfinite(tolerance_per_distance))
    throw nb::value_error("tolerance_per_distance must be a finite number >= 0");
  const std::size_t n = origins.shape(0);

  std::unique_ptr<float[]> color(new float[3 * n]), normal(new float[3 * n]);
  std::unique_ptr<double[]> depth(new double[n]), position(new double[3 * n]),
      distance(new double[n]), error(new double[n]), end(new double[3 * n]);
  std::unique_ptr<std::int32_t[]> object(new std::int32_t[n]), crossings(new std::int32_t[n]),
      chords(new std::int32_t[n]);
  std::unique_ptr<std::uint8_t[]> stop(new std::uint8_t[n]);
  const TraceOutputs out{color.get(), depth.get(),    position.get(), normal.get(),
                         object.get(), crossings.get(), stop.get(),   distance.get(),
                         chords.get(), error.get(), end.get()};
  const TraceOptions options{max_distance, max_crossings, shade, record_segments, tolerance,
                             tolerance_per_distance, skip_empty, fog, light_samples, seed, bounces,
                             EmitterSampling(sampling - std::begin(sampling_names))};

  // The callback runs on this thread with the GIL re-acquired; its exception is kept until the
  // workers have stopped.
  std::exception_ptr callback_error;
  Tracer::Poll poll;
  if (!progress.is_none())
    poll = [&](std::size_t done) {
      nb::gil_scoped_acquire gil;
      try {
        const nb::object result = progress(done, n);
        if (result.is_none()) return true;
        const int truth = PyObject_IsTrue(result.ptr());
        if (truth < 0) throw nb::python_error();
        return truth == 1;
      } catch (...) {
        callback_error = std::current_exception();
        return false;
      }
    };

  TraceStats stats;
  {
    nb::gil_scoped_release release;
    stats = handle.tracer->trace(n, view2<double>(origins), view2<double>(directions), options, out,
                                 poll);
  }
  if (callback_error) std::rethrow_exception(callback_error);

  nb::dict result;
  result["color"] = to_numpy(std::move(color), {n, 3});
  result["depth"] = to_numpy(std::move(depth), {n});
  result["position"] = to_numpy(std::move(position), {n, 3});
  result["normal"] = to_numpy(std::move(normal), {n, 3});
  result["object"] = to_numpy(std::move(object), {n});
  result["crossings"] = to_numpy(std::move(crossings), {n});
  result["stop"] = to_numpy(std::move(stop), {n});
  result["distance"] = to_numpy(std::move(distance), {n});
  result["ray_chords"] = to_numpy(std::move(chords), {n});
  result["error"] = to_numpy(std::move(error), {n});
  result["end"] = to_numpy(std::move(end), {n, 3});
  std::unique_ptr<std::int64_t[]> total(new std::int64_t[1]{std::int64_t(stats.chords)});
  result["chords"] = to_numpy(std::move(total), {});
  std::unique_ptr<std::int64_t[]> failures(new std::int64_t[1]{std::int64_t(stats.light_failures)});
  result["light_failures"] = to_numpy(std::move(failures), {});
  std::unique_ptr<std::int64_t[]> paths(new std::int64_t[1]{std::int64_t(stats.light_paths)});
  result["light_paths"] = to_numpy(std::move(paths), {});
  std::unique_ptr<double[]> energy(new double[1]{stats.light_energy});
  result["light_energy"] = to_numpy(std::move(energy), {});
  std::unique_ptr<std::int64_t[]> emitter_paths(new std::int64_t[1]{std::int64_t(stats.emitter_paths)});
  result["emitter_paths"] = to_numpy(std::move(emitter_paths), {});
  std::unique_ptr<double[]> emitter_energy(new double[1]{stats.emitter_energy});
  result["emitter_energy"] = to_numpy(std::move(emitter_energy), {});
  std::unique_ptr<std::int64_t[]> bounce_paths(new std::int64_t[1]{std::int64_t(stats.bounce_paths)});
  result["bounce_paths"] = to_numpy(std::move(bounce_paths), {});
  std::unique_ptr<std::int64_t[]> emitter_hits(new std::int64_t[1]{std::int64_t(stats.emitter_hits)});
  result["emitter_hits"] = to_numpy(std::move(emitter_hits), {});
  if (record_segments) {
    std::size_t s = 0;
    for (const auto& chunk : stats.segments) s += chunk.size() / 6;
    std::unique_ptr<double[]> starts(new double[3 * s]), ends(new double[3 * s]);
    std::size_t i = 0;
    for (const auto& chunk : stats.segments)
      for (std::size_t j = 0; j < chunk.size(); j += 6, ++i)
        for (int a = 0; a < 3; ++a) {
          starts[3 * i + a] = chunk[j + a];
          ends[3 * i + a] = chunk[j + 3 + a];
        }
    result["segment_starts"] = to_numpy(std::move(starts), {s, 3});
    result["segment_ends"] = to_numpy(std::move(ends), {s, 3});
  }
  return result;
}

nb::tuple query_segments(TracerHandle& handle, const Array& starts, const Array& ends) {
  check_rays(starts, ends, "starts", "ends", 3, "segment");
  const std::size_t n = starts.shape(0);
  std::unique_ptr<float[]> t(new float[n]);
  std::unique_ptr<std::int32_t[]> prim(new std::int32_t[n]), instance(new std::int32_t[n]);
  {
    nb::gil_scoped_release release;
    handle.tracer->query_segments(n, view2<double>(starts), view2<double>(ends), t.get(), prim.get(),
                                  instance.get());
  }
  return nb::make_tuple(to_numpy(std::move(t), {n}), to_numpy(std::move(prim), {n}),
                        to_numpy(std::move(instance), {n}));
}

const char* const kTracerDoc = R"(Ray tracer for inside views of quotient manifolds of Thurston's geometries.

Tracer(geometry, face_covectors, face_maps, vertices, triangles, triangle_object,
       object_color, object_emission, light_lifts, light_of_lift, light_radiance, threads=0,
       corner_normals=None, corner_uvs=None, triangle_material=None, material_color=None,
       material_emission=None, material_color_texture=None, material_emission_texture=None,
       textures=[], mesh_first_triangle=None, instance_mesh=None, instance_transform=None,
       instance_object=None)

geometry: "E3", "S3" (gnomonic chart), "H3" (Klein chart): points are model 4-vectors X whose
chart point is X[:3] / X[3] and geodesics are exact chart lines; "Nil", "Sol": points are (x, 1)
and tangent vectors (v, 0) in the chart, and geodesics are followed in chords within the trace's
tolerance.
face_covectors: float64 (F,4); the fundamental domain is {X : c_f . X <= 0 for all f}.
face_maps: float64 (F,4,4); a ray leaving through face f continues from M_f X (then, for Nil and
Sol, reduced into the domain by the maps of the faces it lies outside of).
vertices: float64 (NV,3) chart coordinates (with instances: the meshes' coordinates);
triangles: int32 (NT,3); triangle_object: int32 (NT,).
object_color, object_emission: float32 (NO,3), each object's one material where triangle_material
is not given. Triangles of emissive materials cast no shadows on the point lights' light (they do
on the emitters').
light_lifts: float64 (K,4) points (copies of the point lights in the universal cover);
light_of_lift: int32 (K,) light index of each lift; light_radiance: float32 (NL,3). Every geodesic
from a shaded point to each lift no longer than light_reach (keyword) is summed (S3 also the long
arc, of length 2 pi - d; S2xR every arc round the sphere, either way and winding; Nil, Sol and SL2
every geodesic of the universal cover, SL2 to the lifts' copies along the fibre by 4 pi too).
geodesic_loop (keyword): the length after which every geodesic returns to its start (S3 with -1 in
the group: pi); light paths longer than it from an opaque surface are shadowed by that surface.
Spot lights (keywords, together): light_cone float64 (NL,2) per light (cos of the cone's half
angle, smoothness 1 / ((1 - cos) blend)), light leaving at angle theta from the axis scaled by
smoothstep((cos theta - cos) * smoothness) as in Cycles (cos -1: no cone); light_axis float64
(K,4) the unit axis (a model tangent vector) at each lift of a light with a cone.
Emitters (keywords, together), sampled as lights at every shaded point (trace's light_samples
points each): emitter_triangles float64 (E,3,3) chart triangles of one copy of each emitter,
emitter_radiance float32 (E,3), emitter_one_sided int32 (E,) (1: emits from the side of its
winding normal only), emitter_group int32 (E,) and emitter_copies float64 (C,4,4) the group
elements (model maps) whose copies of their group (emitter_copy_group int32 (C,)) light, each
along every geodesic as a point light does.
material_one_sided (keyword): int32 (NM,), 1 where a material's emission is seen from the front
only.
material_scattering (keyword): float32 (NM,4) per material roughness, metallic, specular IOR level
and IOR as Blender's Principled BSDF takes them: a Lambert base under a dielectric GGX specular
layer (the level scales its normal reflectance, 0.5: the IOR's own; 0: no layer) and a metallic
GGX lobe coloured by the base colour (Schlick). Without it, or with metallic and level 0: Lambert.
threads: worker threads, 0 for one per hardware thread (ThreadStartError where the system cannot
start them all).
Optional surfaces (keywords):
corner_normals: float32 (NT,3,3) per triangle corner, the chart covector of the surface's normal
(the chart plane's normal for a flat triangle); the shading normal at a hit is the metric normal
of the chart plane through it whose covector interpolates the corners' (barycentric), on the side
of the geometric normal facing the ray. Without it: the geometric normal.
corner_uvs: float32 (NT,3,2) texture coordinates per corner, interpolated likewise.
triangle_material: int32 (NT,) index into material_color, material_emission: float32 (NM,3);
material_color_texture, material_emission_texture: int32 (NM,), -1 or an index into textures, a
list of float32 (H,W,3) or (H,W,4) linear images (rows top-down, v = 0 the bottom row, bilinear,
repeating) that multiply the material's colour or emission at the hit's UV.
Optional instancing (keywords): the triangles are meshes one after the other, each stored and
built once (Embree instancing), and what is seen are their instances.
mesh_first_triangle: int32 (NMESH,), the first triangle of each mesh (from 0, ascending; mesh m
runs to the next one's first); instance_mesh: int32 (NI,) the mesh each instance places;
instance_transform: float64 (NI,3,4) the affine chart map [L | t] of each (x -> L x + t, L
invertible: vertices, and with them triangle planes and corner normals, are in the mesh's own
coordinates; Embree traverses the map in float32, hits are refined in float64 from it);
instance_object: int32 (NI,) added to the triangle_object of the instance's triangles for the
object of a hit. Without them: one mesh of all triangles, placed once by the identity (an
identity map is traversed without an instance level).
All arrays are taken as they are (no conversion); wrong dtypes or shapes raise ValueError.)";

const char* const kTraceDoc = R"(Traces rays through the domain and its face pairings.

origins: float64 (N,4) points; directions: float64 (N,4) unit tangent vectors there.
Rays stop at the first hit, after max_distance of geodesic length, or when they would make
more than max_crossings face crossings. Curved geodesics (Nil, Sol) are followed in chart chords
that stay within tolerance + tolerance_per_distance * d of the traced curve at distance d, which
is the geodesic integrated to 1/20 of that (its separation from the true geodesic, which grows
with the divergence of nearby geodesics, is in `error`); with
skip_empty they step through empty space (no triangle near, by a coarse occupancy grid) to the
next face without any Embree query (False: chords everywhere, for measuring the saving).
light_samples points are sampled on the emitters per shaded point, with random numbers from
`seed` and the ray's index (the same for any thread count).
bounces: bounces after each hit (path tracing: a direction drawn from the BSDF in the metric's
orthonormal frame at the hit, its geodesic traced through the pairings, its hit lit by next-event
estimation; Russian roulette from the 4th bounce on); 0: direct light only.
emitter_sampling: how the emitters' light is gathered where a bounce follows: "mis" (the emitters'
samples and the emission the bounces meet, weighed by the power heuristic along each geodesic),
"light" (the samples alone) or "bounce" (what the bounces meet alone).
progress(done, total) is called about every 0.1 s (and at the start and end); returning False
stops the trace like cancel(). Returns a dict of:
color float32 (N,3), depth float64 (N,) (inf: no hit), position float64 (N,3) chart point of the
hit (NaN: none), normal float32 (N,3) unit chart normal facing the ray (NaN: none), object int32
(N,) (-1: none), crossings int32 (N,), stop uint8 (N,) (0 hit, 1 distance limit, 2 crossing
limit, 3 cancelled), distance float64 (N,) geodesic length travelled, ray_chords int32 (N,)
Embree queries of each ray, error float64 (N,) an upper estimate of the hit position's error
(chart units: the path's distance from the true geodesic over the cosine of incidence; NaN: no
hit), end float64 (N,3) the chart point where the ray stopped (the hit, the point at the distance
or crossing limit, inside the domain; NaN where there is none), chords int64 () Embree queries of primary rays in all, light_failures int64 () light
paths known to be missed (Sol's shooting: seeds that did not converge), light_paths int64 () geodesics to lights summed
at the shaded points, light_energy float64 () their mean radiance times falloff (times fog: light
falls to 1/e over `fog` of its path) summed before cosines and shadows, emitter_paths int64 ()
and emitter_energy float64 () the same for the emitters' samples (their energy: mean radiance
times the emitter's cosine times falloff over the sampling density), bounce_paths int64 ()
geodesics traced for bounces, emitter_hits int64 () bounces that met an emitter and added its
light, and with record_segments segment_starts /
segment_ends float64 (S,3), the chart endpoints of the queries.)";

nb::tuple flow_rows(const std::string& geometry, const Array& points, const Array& velocities,
                        const Array& lengths, double accuracy) {
  if (!has_geometry(geometry)) throw nb::value_error(("unknown geometry '" + geometry + "'").c_str());
  check_rays(points, velocities, "points", "velocities", 3, "row");
  check<double>(lengths, "lengths", {std::int64_t(points.shape(0))}, "(N,) with N = len(points)");
  const std::size_t n = points.shape(0);
  const Strided2<double> p = view2<double>(points), v = view2<double>(velocities);
  const double* t = static_cast<const double*>(lengths.data());
  std::unique_ptr<double[]> xt(new double[3 * n]), vt(new double[3 * n]);
  for (std::size_t i = 0; i < n; ++i) {
    Vec3 x, u;
    if (!thurston::geodesic_flow(geometry, {p(i, 0), p(i, 1), p(i, 2)}, {v(i, 0), v(i, 1), v(i, 2)},
                                 t[i * lengths.stride(0)], accuracy, x, u))
      throw nb::value_error((geometry + " has no marching flow (its geodesics are chart lines)").c_str());
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
  std::unique_ptr<double[]> directions(new double[3 * n]), lengths(new double[n]), falloffs(new double[n]);
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) directions[3 * i + a] = paths[i].direction[a];
    lengths[i] = paths[i].distance;
    falloffs[i] = paths[i].falloff;
  }
  return nb::make_tuple(to_numpy(std::move(directions), {n, 3}), to_numpy(std::move(lengths), {n}),
                        to_numpy(std::move(falloffs), {n}), missed);
}

}  // namespace

NB_MODULE(thurston_core, m) {
  m.doc() = "C++ core of Thurston: the ray tracer through fundamental domains (Embree).";
  m.attr("EMBREE_VERSION") = RTC_VERSION_STRING;
  nb::exception<ThreadStartError>(m, "ThreadStartError", PyExc_RuntimeError);

  m.attr("GEOMETRIES") = geometry_names();
  m.def("geodesic_flow", &flow_rows, nb::arg("geometry"), nb::arg("points").noconvert(),
        nb::arg("velocities").noconvert(), nb::arg("lengths").noconvert(),
        nb::arg("accuracy") = 1e-12,
        "The tracer's geodesic flow of a marching geometry (Nil, Sol): chart points and unit "
        "chart velocities (float64 (N,3)) after arclengths (float64 (N,)), asked for `accuracy` "
        "(chart units). Returns (points, velocities), float64 (N,3) each.");

  nb::class_<ConnectionsHandle>(m, "Connections",
                                "The tracer's light paths of a marching geometry (Nil, Sol, H2xR, S2xR, SL2) "
                                "within a reach: Connections(geometry, reach)(h, l) gives every geodesic from "
                                "the chart point h to the chart point l no longer than the reach, as (directions "
                                "float64 (n,3): unit chart tangents at h, lengths float64 (n,), falloffs float64 "
                                "(n,): the inverse area density of the geodesic sphere along each, missed: how "
                                "many the search could tell it missed).")
      .def(
          "__init__",
          [](ConnectionsHandle* self, const std::string& geometry, double reach) {
            if (!has_geometry(geometry)) throw nb::value_error(("unknown geometry '" + geometry + "'").c_str());
            if (!(reach >= 0.0) || !std::isfinite(reach))
              throw nb::value_error("reach must be a finite distance >= 0");
            std::unique_ptr<Connections> connections = make_connections(geometry, reach);
            if (!connections) throw nb::value_error((geometry + " has no marching flow").c_str());
            new (self) ConnectionsHandle{std::move(connections)};
          },
          nb::arg("geometry"), nb::arg("reach"))
      .def("__call__", &connect_points, nb::arg("h"), nb::arg("l"));

  nb::class_<TracerHandle>(m, "Tracer", kTracerDoc)
      .def(
          "__init__",
          [](TracerHandle* self, const std::string& geometry, const Array& face_covectors,
             const Array& face_maps, const Array& vertices, const Array& triangles,
             const Array& triangle_object, const Array& object_color, const Array& object_emission,
             const Array& light_lifts, const Array& light_of_lift, const Array& light_radiance,
             int threads, OptionalArray corner_normals, OptionalArray corner_uvs,
             OptionalArray triangle_material, OptionalArray material_color,
             OptionalArray material_emission, OptionalArray material_color_texture,
             OptionalArray material_emission_texture, std::vector<Array> textures,
             OptionalArray mesh_first_triangle, OptionalArray instance_mesh,
             OptionalArray instance_transform, OptionalArray instance_object, double light_reach,
             double geodesic_loop, OptionalArray material_one_sided, OptionalArray light_cone,
             OptionalArray light_axis, OptionalArray emitter_triangles, OptionalArray emitter_radiance,
             OptionalArray emitter_one_sided, OptionalArray emitter_group, OptionalArray emitter_copies,
             OptionalArray emitter_copy_group, OptionalArray material_scattering) {
            if (threads < 0) throw nb::value_error("threads must be >= 0 (0: all hardware threads)");
            if (!(light_reach >= 0.0))
              throw nb::value_error("light_reach must be a distance >= 0 (inf: every lift)");
            if (!(geodesic_loop > 0.0)) throw nb::value_error("geodesic_loop must be > 0 (inf: none)");
            const SurfaceArrays surfaces{corner_normals, corner_uvs, triangle_material,
                                         material_color, material_emission, material_color_texture,
                                         material_emission_texture, material_one_sided,
                                         material_scattering, std::move(textures)};
            const InstanceArrays instances{mesh_first_triangle, instance_mesh, instance_transform,
                                           instance_object};
            SceneData scene = make_scene(geometry, face_covectors, face_maps, vertices, triangles,
                                         triangle_object, object_color, object_emission,
                                         light_lifts, light_of_lift, light_radiance, surfaces,
                                         instances);
            make_lights({light_cone, light_axis, emitter_triangles, emitter_radiance, emitter_one_sided,
                         emitter_group, emitter_copies, emitter_copy_group},
                        geometry, light_lifts, scene);
            scene.light_reach = light_reach;
            scene.geodesic_loop = geodesic_loop;
            new (self) TracerHandle{make_tracer(geometry, std::move(scene), unsigned(threads)), geometry};
          },
          nb::sig("def __init__(self, geometry: str, face_covectors: numpy.ndarray, "
                  "face_maps: numpy.ndarray, vertices: numpy.ndarray, triangles: numpy.ndarray, "
                  "triangle_object: numpy.ndarray, object_color: numpy.ndarray, "
                  "object_emission: numpy.ndarray, light_lifts: numpy.ndarray, "
                  "light_of_lift: numpy.ndarray, light_radiance: numpy.ndarray, "
                  "threads: int = 0, corner_normals: numpy.ndarray | None = None, "
                  "corner_uvs: numpy.ndarray | None = None, "
                  "triangle_material: numpy.ndarray | None = None, "
                  "material_color: numpy.ndarray | None = None, "
                  "material_emission: numpy.ndarray | None = None, "
                  "material_color_texture: numpy.ndarray | None = None, "
                  "material_emission_texture: numpy.ndarray | None = None, "
                  "textures: list[numpy.ndarray] = [], "
                  "mesh_first_triangle: numpy.ndarray | None = None, "
                  "instance_mesh: numpy.ndarray | None = None, "
                  "instance_transform: numpy.ndarray | None = None, "
                  "instance_object: numpy.ndarray | None = None, "
                  "light_reach: float = float('inf'), geodesic_loop: float = float('inf'), "
                  "material_one_sided: numpy.ndarray | None = None, "
                  "light_cone: numpy.ndarray | None = None, light_axis: numpy.ndarray | None = None, "
                  "emitter_triangles: numpy.ndarray | None = None, "
                  "emitter_radiance: numpy.ndarray | None = None, "
                  "emitter_one_sided: numpy.ndarray | None = None, "
                  "emitter_group: numpy.ndarray | None = None, "
                  "emitter_copies: numpy.ndarray | None = None, "
                  "emitter_copy_group: numpy.ndarray | None = None, "
                  "material_scattering: numpy.ndarray | None = None) -> None"),
          nb::arg("geometry"), nb::arg("face_covectors").noconvert(),
          nb::arg("face_maps").noconvert(), nb::arg("vertices").noconvert(),
          nb::arg("triangles").noconvert(), nb::arg("triangle_object").noconvert(),
          nb::arg("object_color").noconvert(), nb::arg("object_emission").noconvert(),
          nb::arg("light_lifts").noconvert(), nb::arg("light_of_lift").noconvert(),
          nb::arg("light_radiance").noconvert(), nb::arg("threads") = 0,
          nb::arg("corner_normals").noconvert().none() = nb::none(),
          nb::arg("corner_uvs").noconvert().none() = nb::none(),
          nb::arg("triangle_material").noconvert().none() = nb::none(),
          nb::arg("material_color").noconvert().none() = nb::none(),
          nb::arg("material_emission").noconvert().none() = nb::none(),
          nb::arg("material_color_texture").noconvert().none() = nb::none(),
          nb::arg("material_emission_texture").noconvert().none() = nb::none(),
          nb::arg("textures") = std::vector<Array>(),
          nb::arg("mesh_first_triangle").noconvert().none() = nb::none(),
          nb::arg("instance_mesh").noconvert().none() = nb::none(),
          nb::arg("instance_transform").noconvert().none() = nb::none(),
          nb::arg("instance_object").noconvert().none() = nb::none(),
          nb::arg("light_reach") = kInf, nb::arg("geodesic_loop") = kInf,
          nb::arg("material_one_sided").noconvert().none() = nb::none(),
          nb::arg("light_cone").noconvert().none() = nb::none(),
          nb::arg("light_axis").noconvert().none() = nb::none(),
          nb::arg("emitter_triangles").noconvert().none() = nb::none(),
          nb::arg("emitter_radiance").noconvert().none() = nb::none(),
          nb::arg("emitter_one_sided").noconvert().none() = nb::none(),
          nb::arg("emitter_group").noconvert().none() = nb::none(),
          nb::arg("emitter_copies").noconvert().none() = nb::none(),
          nb::arg("emitter_copy_group").noconvert().none() = nb::none(),
          nb::arg("material_scattering").noconvert().none() = nb::none())
      .def("trace", &trace,
           nb::sig("def trace(self, origins: numpy.ndarray, directions: numpy.ndarray, "
                   "max_distance: float, max_crossings: int, shade: bool = True, "
                   "progress: collections.abc.Callable[[int, int], bool | None] | None = None, "
                   "record_segments: bool = False, tolerance: float = 1e-3, "
                   "tolerance_per_distance: float = 0.0, skip_empty: bool = True, "
                   "fog: float = float('inf'), light_samples: int = 1, seed: int = 0, "
                   "bounces: int = 0, emitter_sampling: str = 'mis') -> "
                   "dict[str, numpy.ndarray]"),
           nb::arg("origins").noconvert(), nb::arg("directions").noconvert(),
           nb::arg("max_distance"), nb::arg("max_crossings"), nb::arg("shade") = true,
           nb::arg("progress").none() = nb::none(), nb::arg("record_segments") = false,
           nb::arg("tolerance") = 1e-3, nb::arg("tolerance_per_distance") = 0.0,
           nb::arg("skip_empty") = true, nb::arg("fog") = kInf, nb::arg("light_samples") = 1,
           nb::arg("seed") = 0, nb::arg("bounces") = 0, nb::arg("emitter_sampling") = "mis", kTraceDoc)
      .def("cancel", [](TracerHandle& t) { t.tracer->cancel(); },
           "Stops a running trace(); callable from any Python thread.")
      .def("query_segments", &query_segments,
           nb::sig("def query_segments(self, starts: numpy.ndarray, ends: numpy.ndarray) -> "
                   "tuple[numpy.ndarray, numpy.ndarray, numpy.ndarray]"),
           nb::arg("starts").noconvert(),
           nb::arg("ends").noconvert(),
           "Bare Embree first hit of the chart "
           "segments (float64 (N,3) each) on the same BVH and threads: chord parameter t float32 "
           "(N,) in [0, 1] (inf: none), the mesh triangle prim int32 (N,) and its instance int32 "
           "(N,) (-1: none).")
      .def_prop_ro("geometry", [](const TracerHandle& t) { return t.geometry; })
      .def_prop_ro("light_reach", [](const TracerHandle& t) { return t.tracer->light_reach(); },
                   "Light paths longer than this are not summed (E3, S3, H3, H2xR, S2xR).")
      .def_prop_ro("num_light_lifts", [](const TracerHandle& t) { return t.tracer->num_light_lifts(); })
      .def_prop_ro("light_power", [](const TracerHandle& t) { return t.tracer->light_power(); },
                   "The sum over lights of their radiance's mean over RGB.")
      .def_prop_ro("num_emitter_triangles", [](const TracerHandle& t) { return t.tracer->num_emitter_triangles(); })
      .def_prop_ro("num_emitter_copies", [](const TracerHandle& t) { return t.tracer->num_emitter_copies(); })
      .def_prop_ro("num_unmatched_emitters", [](const TracerHandle& t) { return t.tracer->num_unmatched_emitters(); },
                   "Emissive triangles (per instance) not found among the emitters' copies: bounces "
                   "that meet them add nothing (their light comes from the emitters' samples).")
      .def_prop_ro("num_threads", [](const TracerHandle& t) { return t.tracer->num_threads(); })
      .def_prop_ro("num_triangles", [](const TracerHandle& t) { return t.tracer->num_triangles(); },
                   "The meshes' own triangles (each stored once).")
      .def_prop_ro("num_instances", [](const TracerHandle& t) { return t.tracer->num_instances(); })
      .def_prop_ro("num_instanced_triangles",
                   [](const TracerHandle& t) { return t.tracer->num_instanced_triangles(); },
                   "The triangles the instances place, each instance counting its mesh's.");
}
