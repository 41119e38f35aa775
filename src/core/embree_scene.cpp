// The tracer's Embree scene: the chart bounds and occupancy grid of the instances, and the
// two-level Embree scenes (all triangles; those that cast shadows on the point lights).
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "tracer.hpp"

namespace thurston {

namespace {

constexpr int kOccupancyCells = 32;

// Instances whose chart box spans at most this many occupancy cells mark the whole box; larger
// ones mark their triangles' boxes, which keeps large objects' empty inside empty.
constexpr std::size_t kInstanceBoxCells = 27;

bool is_identity(const Affine& a) { return a.m == Affine{}.m; }

// The chart bounding box of the box [lo, hi] mapped by `a`.
void mapped_box(const Affine& a, const Vec3& lo, const Vec3& hi, Vec3& out_lo, Vec3& out_hi) {
  const Vec3 centre = a.point(scaled3(0.5, add3(lo, hi)));
  for (int r = 0; r < 3; ++r) {
    double half = 0.0;
    for (int k = 0; k < 3; ++k) half += 0.5 * std::abs(a.m[4 * r + k]) * (hi[k] - lo[k]);
    out_lo[r] = centre[r] - half;
    out_hi[r] = centre[r] + half;
  }
}

}  // namespace

void Occupancy::start(const Vec3& lo, const Vec3& hi, int cells) {
  cells_ = cells;
  lo_ = lo;
  for (int a = 0; a < 3; ++a) size_[a] = std::max(hi[a] - lo[a], 1e-300) / cells_;
  marked_.assign(std::size_t(cells_) * cells_ * cells_, 0);
}

void Occupancy::mark(const Vec3& lo, const Vec3& hi) {
  const int i0 = cell(lo[0], 0), j0 = cell(lo[1], 1), k0 = cell(lo[2], 2);
  const int i1 = cell(hi[0], 0), j1 = cell(hi[1], 1), k1 = cell(hi[2], 2);
  for (int i = i0; i <= i1; ++i)
    for (int j = j0; j <= j1; ++j)
      for (int k = k0; k <= k1; ++k) marked_[(std::size_t(i) * cells_ + j) * cells_ + k] = 1;
}

std::size_t Occupancy::cells_spanned(const Vec3& lo, const Vec3& hi) const {
  std::size_t n = 1;
  for (int a = 0; a < 3; ++a) n *= std::size_t(cell(hi[a], a) - cell(lo[a], a) + 1);
  return n;
}

void Occupancy::finish() {
  prefix_.assign(std::size_t(cells_ + 1) * (cells_ + 1) * (cells_ + 1), 0);
  for (int i = 1; i <= cells_; ++i)
    for (int j = 1; j <= cells_; ++j)
      for (int k = 1; k <= cells_; ++k)
        prefix_[at(i, j, k)] = marked_[(std::size_t(i - 1) * cells_ + (j - 1)) * cells_ + (k - 1)] +
                               prefix_[at(i - 1, j, k)] + prefix_[at(i, j - 1, k)] +
                               prefix_[at(i, j, k - 1)] - prefix_[at(i - 1, j - 1, k)] -
                               prefix_[at(i - 1, j, k - 1)] - prefix_[at(i, j - 1, k - 1)] +
                               prefix_[at(i - 1, j - 1, k - 1)];
  marked_ = {};
}

int Occupancy::cell(double x, int axis) const {
  const double c = std::floor((x - lo_[axis]) / size_[axis]);
  return int(std::clamp(c, 0.0, double(cells_ - 1)));
}

bool Occupancy::touches(const Vec3& lo, const Vec3& hi) const {
  const int i0 = cell(lo[0], 0), j0 = cell(lo[1], 1), k0 = cell(lo[2], 2);
  const int i1 = cell(hi[0], 0) + 1, j1 = cell(hi[1], 1) + 1, k1 = cell(hi[2], 2) + 1;
  const std::int64_t sum = std::int64_t(prefix_[at(i1, j1, k1)]) - prefix_[at(i0, j1, k1)] -
                           prefix_[at(i1, j0, k1)] - prefix_[at(i1, j1, k0)] +
                           prefix_[at(i0, j0, k1)] + prefix_[at(i0, j1, k0)] +
                           prefix_[at(i1, j0, k0)] - prefix_[at(i0, j0, k0)];
  return sum > 0;
}

void Tracer::bound_instances(bool occupancy) {
  const auto triangle_box = [&](const Affine& a, std::size_t t, Vec3& lo, Vec3& hi) {
    lo = {kInf, kInf, kInf};
    hi = {-kInf, -kInf, -kInf};
    for (std::uint32_t v : triangles_[t]) {
      const Vec3 x = a.point(vertices_[v]);
      for (int k = 0; k < 3; ++k) {
        lo[k] = std::min(lo[k], x[k]);
        hi[k] = std::max(hi[k], x[k]);
      }
    }
  };
  const std::size_t meshes = mesh_first_.size() - 1;
  std::vector<Vec3> mesh_lo(meshes), mesh_hi(meshes);
  for (std::size_t m = 0; m < meshes; ++m) {
    mesh_lo[m] = {kInf, kInf, kInf};
    mesh_hi[m] = {-kInf, -kInf, -kInf};
    for (std::size_t t = mesh_first_[m]; t < mesh_first_[m + 1]; ++t) {
      Vec3 lo, hi;
      triangle_box(Affine{}, t, lo, hi);
      for (int k = 0; k < 3; ++k) {
        mesh_lo[m][k] = std::min(mesh_lo[m][k], lo[k]);
        mesh_hi[m][k] = std::max(mesh_hi[m][k], hi[k]);
      }
    }
  }
  std::vector<std::array<Vec3, 2>> boxes(instances_.size());
  std::vector<std::size_t> placed;  // instances with triangles
  Vec3 lo{kInf, kInf, kInf}, hi{-kInf, -kInf, -kInf};
  for (std::size_t i = 0; i < instances_.size(); ++i) {
    const std::uint32_t m = instances_[i].mesh;
    if (mesh_first_[m] == mesh_first_[m + 1]) continue;
    placed.push_back(i);
    mapped_box(instances_[i].to_chart, mesh_lo[m], mesh_hi[m], boxes[i][0], boxes[i][1]);
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min(lo[k], boxes[i][0][k]);
      hi[k] = std::max(hi[k], boxes[i][1][k]);
    }
  }
  for (int a = 0; a < 3 && !placed.empty(); ++a)
    scale_ = std::max({scale_, std::abs(lo[a]), std::abs(hi[a]), hi[a] - lo[a]});
  const double margin = 1e-6 * scale_;
  for (int a = 0; a < 3; ++a) {
    // No triangles: an empty range, which no chord meets.
    hit_lo_[a] = placed.empty() ? kInf : lo[a] - margin;
    hit_hi_[a] = placed.empty() ? -kInf : hi[a] + margin;
  }
  if (!occupancy || placed.empty()) return;
  occupancy_.start(hit_lo_, hit_hi_, kOccupancyCells);
  for (std::size_t i : placed) {
    const Placement& p = instances_[i];
    if (!is_identity(p.to_chart) &&
        occupancy_.cells_spanned(boxes[i][0], boxes[i][1]) <= kInstanceBoxCells) {
      occupancy_.mark(boxes[i][0], boxes[i][1]);
      continue;
    }
    for (std::size_t t = mesh_first_[p.mesh]; t < mesh_first_[p.mesh + 1]; ++t) {
      Vec3 t_lo, t_hi;
      triangle_box(p.to_chart, t, t_lo, t_hi);
      occupancy_.mark(t_lo, t_hi);
    }
  }
  occupancy_.finish();
}

std::vector<std::uint32_t> Tracer::mesh_triangle_ids(std::size_t mesh, bool casting) const {
  std::vector<std::uint32_t> ids;
  for (std::uint32_t t = mesh_first_[mesh]; t < mesh_first_[mesh + 1]; ++t)
    if (!casting || !surfaces_.materials[surfaces_.triangle_material[t]].emits()) ids.push_back(t);
  return ids;
}

// A triangle geometry of the given triangles (primitive j is triangle_ids[j]) on the shared
// vertex buffer; the caller attaches and releases it.
RTCGeometry Tracer::new_triangles(const std::vector<std::uint32_t>& triangle_ids) const {
  RTCDevice device = device_.get();
  RTCGeometry geometry = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
  rtcSetSharedGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                             float_vertices_.data(), 0, 3 * sizeof(float), vertices_.size());
  auto* indices = static_cast<std::uint32_t*>(
      rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                              3 * sizeof(std::uint32_t), triangle_ids.size()));
  if (!indices) {
    rtcReleaseGeometry(geometry);
    embree::check_device(device, "allocate geometry buffers");
    throw std::runtime_error("Embree failed to allocate geometry buffers");
  }
  for (std::size_t j = 0; j < triangle_ids.size(); ++j)
    for (int a = 0; a < 3; ++a) indices[3 * j + a] = triangles_[triangle_ids[j]][a];
  rtcSetGeometryBuildQuality(geometry, RTC_BUILD_QUALITY_HIGH);
  rtcCommitGeometry(geometry);
  return geometry;
}

Tracer::SceneHandle Tracer::build_top_scene(bool casting) {
  RTCDevice device = device_.get();
  const auto new_scene = [&] {
    SceneHandle scene(rtcNewScene(device));
    embree::check_device(device, "create a scene");
    rtcSetSceneFlags(scene.get(), RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(scene.get(), RTC_BUILD_QUALITY_HIGH);
    return scene;
  };
  const auto attach = [&](RTCScene scene, RTCGeometry geometry, std::size_t id) {
    rtcAttachGeometryByID(scene, geometry, unsigned(id));
    rtcReleaseGeometry(geometry);
  };
  SceneHandle top = new_scene();
  std::vector<SceneHandle>& meshes = mesh_scenes_[casting];
  meshes.resize(mesh_first_.size() - 1);
  for (std::size_t i = 0; i < instances_.size(); ++i) {
    const Placement& p = instances_[i];
    if (mesh_first_[p.mesh] == mesh_first_[p.mesh + 1]) continue;
    if (is_identity(p.to_chart)) {  // no instance level: the flat path is as fast as before
      const std::vector<std::uint32_t> ids = mesh_triangle_ids(p.mesh, casting);
      if (!ids.empty()) attach(top.get(), new_triangles(ids), i);
      continue;
    }
    if (!meshes[p.mesh]) {
      meshes[p.mesh] = new_scene();
      const std::vector<std::uint32_t> ids = mesh_triangle_ids(p.mesh, casting);
      if (!ids.empty()) attach(meshes[p.mesh].get(), new_triangles(ids), 0);
      rtcCommitScene(meshes[p.mesh].get());
      embree::check_device(device, "build a mesh's scene");
    }
    RTCGeometry instance = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(instance, meshes[p.mesh].get());
    float transform[12];  // Embree's: float; hits are refined in double from the exact map
    for (int k = 0; k < 12; ++k) transform[k] = float(p.to_chart.m[k]);
    rtcSetGeometryTransform(instance, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, transform);
    rtcCommitGeometry(instance);
    attach(top.get(), instance, i);
  }
  rtcCommitScene(top.get());
  embree::check_device(device, "build the scene");
  return top;
}

void Tracer::build_scenes() {
  device_.reset(rtcNewDevice(nullptr));
  if (!device_) throw std::runtime_error("Embree could not create a device");
  // Embree reads the last vertex with a 16-byte load: one float of padding.
  float_vertices_.resize(3 * vertices_.size() + 1, 0.0f);
  for (std::size_t v = 0; v < vertices_.size(); ++v)
    for (int a = 0; a < 3; ++a) float_vertices_[3 * v + a] = float(vertices_[v][a]);
  scene_ = build_top_scene(false);
  bool all_cast = true;
  for (std::int32_t m : surfaces_.triangle_material) all_cast &= !surfaces_.materials[m].emits();
  if (all_cast) {
    occluders_ = scene_.get();
  } else {
    occluder_scene_ = build_top_scene(true);
    occluders_ = occluder_scene_.get();
  }
}

}  // namespace thurston
