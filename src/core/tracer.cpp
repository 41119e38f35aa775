#include "tracer.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <optional>
#include <stdexcept>
#include <string>

#include "h2xr.hpp"
#include "march.hpp"
#include "nil.hpp"
#include "projective.hpp"
#include "s2xr.hpp"
#include "sl2.hpp"
#include "sol.hpp"

#if defined(__SSE2__) || defined(_M_X64)
#include <emmintrin.h>  // SSE2: part of the x86-64 baseline
#define THURSTON_SSE2 1
#endif

namespace thurston {

void mat_vec2(const Mat4& Mt, const Vec4& x, const Vec4& xv, Vec4& y, Vec4& yv) {
  const double* m = Mt.data();
#ifndef THURSTON_SSE2
  for (int r = 0; r < 4; ++r) {
    y[r] = m[r] * x[0] + m[4 + r] * x[1] + m[8 + r] * x[2] + m[12 + r] * x[3];
    yv[r] = m[r] * xv[0] + m[4 + r] * xv[1] + m[8 + r] * xv[2] + m[12 + r] * xv[3];
  }
#else
  for (int h = 0; h < 4; h += 2) {
    __m128d s = _mm_mul_pd(_mm_loadu_pd(m + h), _mm_set1_pd(x[0]));
    __m128d t = _mm_mul_pd(_mm_loadu_pd(m + h), _mm_set1_pd(xv[0]));
    for (int c = 1; c < 4; ++c) {
      const __m128d col = _mm_loadu_pd(m + 4 * c + h);
      s = _mm_add_pd(s, _mm_mul_pd(col, _mm_set1_pd(x[c])));
      t = _mm_add_pd(t, _mm_mul_pd(col, _mm_set1_pd(xv[c])));
    }
    _mm_storeu_pd(y.data() + h, s);
    _mm_storeu_pd(yv.data() + h, t);
  }
#endif
}

namespace {

constexpr std::size_t kChunk = 1024;  // rays per unit of work
constexpr std::chrono::milliseconds kPollInterval{100};
constexpr int kOccupancyCells = 32;
// Geodesics leaving a surface skip this much of the scene's scale at their start (chart length),
// so as not to meet their own triangle: Embree's float vertices are only good to about 1e-7 of it.
constexpr double kSelfSkip = 1e-5;
// The rounding a hit position carries per face crossing (chart units), on top of what a kernel's
// walk reports.
constexpr double kRoundingPerCrossing = 1e-14;

RTCRay chord_ray(const Vec3& x0, const Vec3& x1, float tnear) {
  const float org[3] = {float(x0[0]), float(x0[1]), float(x0[2])};
  const float dir[3] = {float(x1[0] - x0[0]), float(x1[1] - x0[1]), float(x1[2] - x0[2])};
  return embree::make_ray(org, dir, tnear, 1.0f);
}

// The outputs of a ray that hit nothing.
void write_miss(const TraceOutputs& out, std::size_t i, Stop stop, int crossings, double distance,
                int chords, const Vec3& end = {kNaN, kNaN, kNaN}) {
  for (int a = 0; a < 3; ++a) {
    out.color[3 * i + a] = 0.0f;
    out.position[3 * i + a] = kNaN;
    out.normal[3 * i + a] = float(kNaN);
    out.end[3 * i + a] = end[a];
  }
  out.depth[i] = kInf;
  out.object[i] = -1;
  out.crossings[i] = crossings;
  out.stop[i] = stop;
  out.distance[i] = distance;
  out.chords[i] = chords;
  out.error[i] = kNaN;
}

void check_device(RTCDevice device, const char* what) {
  const RTCError error = rtcGetDeviceError(device);
  if (error != RTC_ERROR_NONE)
    throw std::runtime_error(std::string("Embree failed to ") + what + " (error " +
                             std::to_string(int(error)) + ")");
}

}  // namespace

// --- occupancy ---------------------------------------------------------------------------------

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
  const std::int64_t sum =
      std::int64_t(prefix_[at(i1, j1, k1)]) - prefix_[at(i0, j1, k1)] - prefix_[at(i1, j0, k1)] -
      prefix_[at(i1, j1, k0)] + prefix_[at(i0, j0, k1)] + prefix_[at(i0, j1, k0)] +
      prefix_[at(i1, j0, k0)] - prefix_[at(i0, j0, k0)];
  return sum > 0;
}

// --- what every tracer shares --------------------------------------------------------------------

Tracer::Tracer(SceneData& scene, unsigned threads, bool occupancy)
    : vertices_(std::move(scene.vertices)),
      triangles_(std::move(scene.triangles)),
      triangle_object_(std::move(scene.triangle_object)),
      mesh_first_(std::move(scene.mesh_first)),
      surfaces_(std::move(scene.surfaces)),
      light_radiance_(std::move(scene.light_radiance)),
      light_cone_(std::move(scene.light_cone)),
      emitters_(std::move(scene.emitters)),
      light_reach_(scene.light_reach),
      geodesic_loop_(scene.geodesic_loop),
      pool_(threads) {
  domain_.faces = scene.face_covectors.size();
  for (const Vec4& c : scene.face_covectors)
    for (int a = 0; a < 4; ++a) domain_.components[a].push_back(c[a]);
  while (domain_.components[0].size() % 4 != 0)  // zero covectors: never an exit
    for (int a = 0; a < 4; ++a) domain_.components[a].push_back(0.0);
  domain_.maps = std::move(scene.face_maps);
  domain_.maps_t.resize(domain_.maps.size());
  for (std::size_t e = 0; e < domain_.maps.size(); ++e)
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) domain_.maps_t[e][4 * c + r] = domain_.maps[e][4 * r + c];

  mesh_first_.push_back(std::uint32_t(triangles_.size()));
  for (const Instance& instance : scene.instances) {
    Placement placement{instance.mesh, instance.object, instance.to_chart, {}};
    if (!instance.to_chart.inverse(placement.from_chart))
      throw std::invalid_argument("an instance's transform is singular");
    instances_.push_back(placement);
  }
  triangle_planes_.reserve(triangles_.size());
  for (const auto& tri : triangles_) {
    const Vec3& p0 = vertices_[tri[0]];
    const Vec3 n = cross3(sub3(vertices_[tri[1]], p0), sub3(vertices_[tri[2]], p0));
    triangle_planes_.push_back({n[0], n[1], n[2], -dot3(n, p0)});
  }
  bound_instances(occupancy);

  light_lifts_.resize(light_radiance_.size());
  light_axes_.resize(light_radiance_.size());
  light_cone_.resize(light_radiance_.size());
  for (std::size_t k = 0; k < scene.light_lifts.size(); ++k) {
    const std::int32_t l = scene.light_of_lift[k];
    light_lifts_[l].push_back(scene.light_lifts[k]);
    if (light_cone_[l].active()) light_axes_[l].push_back(scene.light_axis[k]);
  }
  double area = 0.0;
  for (const auto& t : emitters_.triangles) {
    area += 0.5 * norm3(cross3(sub3(t[1], t[0]), sub3(t[2], t[0])));
    emitter_area_sum_.push_back(area);
  }
  std::int32_t groups = 0;
  for (const std::int32_t g : emitters_.group) groups = std::max(groups, g + 1);
  emitter_copies_.resize(groups);
  for (std::size_t c = 0; c < emitters_.copies.size(); ++c)
    emitter_copies_[emitters_.copy_group[c]].push_back(emitters_.copies[c]);

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

Tracer::~Tracer() = default;

std::size_t Tracer::num_instanced_triangles() const {
  std::size_t n = 0;
  for (const Placement& p : instances_) n += mesh_first_[p.mesh + 1] - mesh_first_[p.mesh];
  return n;
}

namespace {

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
    if (!is_identity(p.to_chart) && occupancy_.cells_spanned(boxes[i][0], boxes[i][1]) <= kInstanceBoxCells) {
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
    check_device(device, "allocate geometry buffers");
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
    check_device(device, "create a scene");
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
      check_device(device, "build a mesh's scene");
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
  check_device(device, "build the scene");
  return top;
}

// One run at a time on the pool; a progress callback calling back into its own tracer would
// wait on itself forever, so that is an error instead.
Tracer::RunLock::RunLock(Tracer& tracer) : tracer_(tracer) {
  if (tracer.runner_.load() == std::this_thread::get_id())
    throw std::runtime_error("a Tracer cannot be used from its own progress callback");
  tracer.run_mutex_.lock();
  tracer.runner_.store(std::this_thread::get_id());
}

Tracer::RunLock::~RunLock() {
  tracer_.runner_.store(std::thread::id());
  tracer_.run_mutex_.unlock();
}

std::size_t Tracer::num_light_lifts() const {
  std::size_t n = 0;
  for (const auto& lifts : light_lifts_) n += lifts.size();
  return n;
}

double Tracer::light_power() const {
  double p = 0.0;
  for (const Rgb& radiance : light_radiance_) p += mean_rgb(radiance);
  for (std::size_t t = 0; t < emitters_.triangles.size(); ++t) {
    const double area = emitter_area_sum_[t] - (t ? emitter_area_sum_[t - 1] : 0.0);
    p += mean_rgb(emitters_.radiance[t]) * area / (4.0 * kPi);
  }
  return p;
}

std::size_t Tracer::pick_emitter(double u) const {
  const double target = u * emitter_area_sum_.back();
  const auto it = std::upper_bound(emitter_area_sum_.begin(), emitter_area_sum_.end(), target);
  return std::min(std::size_t(it - emitter_area_sum_.begin()), emitter_area_sum_.size() - 1);
}

TraceStats Tracer::trace(std::size_t count, Strided2<double> origins, Strided2<double> directions,
                         const TraceOptions& options, const TraceOutputs& out, const Poll& poll) {
  const RunLock lock(*this);
  cancel_.store(false);
  const std::size_t chunks = (count + kChunk - 1) / kChunk;
  // Kept by chunk, so that the recording does not depend on the thread count.
  std::vector<std::vector<double>> chunk_segments(options.record_segments ? chunks : 0);
  std::atomic<std::uint64_t> chords{0}, light_failures{0}, light_paths{0}, emitter_paths{0},
      bounce_paths{0}, emitter_hits{0};
  // summed in chunk order: the same for any threads
  std::vector<double> chunk_energy(chunks, 0.0), chunk_emitter_energy(chunks, 0.0);
  const std::size_t traced = run_chunks(
      count,
      [&](std::size_t chunk, std::size_t begin, std::size_t end) {
        std::vector<double>* segments = options.record_segments ? &chunk_segments[chunk] : nullptr;
        TraceStats local;
        trace_range(begin, end, origins, directions, options, out, segments, local);
        chords.fetch_add(local.chords);
        light_failures.fetch_add(local.light_failures);
        light_paths.fetch_add(local.light_paths);
        emitter_paths.fetch_add(local.emitter_paths);
        bounce_paths.fetch_add(local.bounce_paths);
        emitter_hits.fetch_add(local.emitter_hits);
        chunk_energy[chunk] = local.light_energy;
        chunk_emitter_energy[chunk] = local.emitter_energy;
      },
      poll, true);
  for (std::size_t i = traced; i < count; ++i) write_miss(out, i, kCancelled, 0, 0.0, 0);
  TraceStats stats;
  stats.chords = chords.load();
  stats.light_failures = light_failures.load();
  stats.light_paths = light_paths.load();
  stats.emitter_paths = emitter_paths.load();
  stats.bounce_paths = bounce_paths.load();
  stats.emitter_hits = emitter_hits.load();
  for (const double e : chunk_energy) stats.light_energy += e;
  for (const double e : chunk_emitter_energy) stats.emitter_energy += e;
  stats.segments = std::move(chunk_segments);
  return stats;
}

void Tracer::query_segments(std::size_t count, Strided2<double> starts, Strided2<double> ends,
                            float* t, std::int32_t* prim, std::int32_t* instance) {
  const RunLock lock(*this);
  run_chunks(
      count,
      [&](std::size_t, std::size_t begin, std::size_t end) {
        for (std::size_t i = begin; i < end; ++i) {
          const Vec3 x0{starts(i, 0), starts(i, 1), starts(i, 2)};
          const Vec3 x1{ends(i, 0), ends(i, 1), ends(i, 2)};
          const embree::FirstHit hit = embree::intersect(scene_.get(), chord_ray(x0, x1, 0.0f));
          const bool found = hit.prim >= 0;
          prim[i] = found ? std::int32_t(triangle_of(hit)) : -1;
          instance[i] = found ? std::int32_t(hit.instance) : -1;
          t[i] = found ? hit.u : std::numeric_limits<float>::infinity();
        }
      },
      nullptr, false);
}

std::size_t Tracer::run_chunks(std::size_t count,
                               const std::function<void(std::size_t, std::size_t, std::size_t)>& fn,
                               const Poll& poll, bool cancellable) {
  const std::size_t chunks = (count + kChunk - 1) / kChunk;
  std::atomic<std::size_t> next{0}, done{0};
  std::atomic<bool>& stop = run_stop_;
  stop = poll && !poll(0);
  const std::function<void()> task = [&] {
    try {
      while (!stop.load()) {
        const std::size_t chunk = next.fetch_add(1);
        if (chunk >= chunks) break;
        const std::size_t begin = chunk * kChunk, end = std::min(count, begin + kChunk);
        fn(chunk, begin, end);
        done.fetch_add(end - begin);
      }
    } catch (...) {
      stop = true;  // let the other workers finish early too
      throw;
    }
  };
  pool_.start(task);
  while (!pool_.wait_for(kPollInterval)) {
    if (cancellable && cancel_.load()) stop = true;
    if (poll && !stop.load() && !poll(done.load())) stop = true;
  }
  if (pool_.error()) std::rethrow_exception(pool_.error());
  if (poll && !stop.load()) poll(done.load());  // the final count
  // Chunks are handed out in order and every chunk taken is finished.
  return std::min(count, std::min(next.load(), chunks) * kChunk);
}

// --- the walk, generic over the kernel -----------------------------------------------------------

namespace {

// The random numbers of one ray: splitmix64 from the trace's seed and the ray's index, so that a
// ray's samples depend on neither the threads nor the chunks.
class Random {
 public:
  Random(std::uint64_t seed, std::uint64_t ray) : state_(mix(seed * 0x9E3779B97F4A7C15ull + ray)) {}
  double uniform() { return double(mix(state_ += 0x9E3779B97F4A7C15ull) >> 11) * 0x1.0p-53; }

 private:
  static std::uint64_t mix(std::uint64_t z) {
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  std::uint64_t state_;
};

template <class Kernel>
class KernelTracer final : public Tracer {
 public:
  KernelTracer(Kernel kernel, SceneData scene, unsigned threads, bool occupancy)
      : Tracer(scene, threads, occupancy), kernel_(kernel) {
    // (only where there is light to connect: Sol's table takes a tenth of a second)
    if (!light_lifts_.empty() || !emitters_.triangles.empty()) kernel_.prepare_light_paths(light_reach_);
    match_emitters();
  }

 private:
  using Chord = typename Kernel::Chord;
  // Per chunk, reused from point to point: the buffers of one point's light paths and of an
  // emitter sample's copies (points and their unit normals).
  struct LightBuffers {
    std::vector<LightPath> paths;
    std::vector<Vec4> lifts, normals;
  };

  void trace_range(std::size_t begin, std::size_t end, Strided2<double> origins,
                   Strided2<double> directions, const TraceOptions& options,
                   const TraceOutputs& out, std::vector<double>* segments,
                   TraceStats& stats) const override {
    const WalkContext context = this->context(options);
    LightBuffers buffers;
    for (std::size_t i = begin; i < end; ++i) {
      const Vec4 o{origins(i, 0), origins(i, 1), origins(i, 2), origins(i, 3)};
      const Vec4 d{directions(i, 0), directions(i, 1), directions(i, 2), directions(i, 3)};
      Random random(options.seed, i);
      trace_ray(i, o, d, context, options, out, segments, stats, buffers, random);
    }
  }

  void trace_ray(std::size_t i, const Vec4& origin, const Vec4& direction,
                 const WalkContext& context, const TraceOptions& options, const TraceOutputs& out,
                 std::vector<double>* segments, TraceStats& stats, LightBuffers& buffers,
                 Random& random) const {
    Vec4 P = origin, V = direction;
    if (!kernel_.start(P, V)) {  // no point or no direction: the ray goes nowhere
      write_miss(out, i, kDistanceLimit, 0, 0.0, 0);
      return;
    }
    const Found found = first_hit(context, P, V, options.max_distance, options.max_crossings, 0.0, segments);
    const WalkEnd& end = found.end;
    const Hit& h = found.hit;
    stats.chords += found.chords;
    if (end.stop != kHit) {
      write_miss(out, i, end.stop, end.crossings, end.distance, found.chords, end.end);
      return;
    }
    out.stop[i] = kHit;
    out.crossings[i] = end.crossings;
    out.chords[i] = found.chords;
    out.depth[i] = end.distance + h.s;
    out.distance[i] = out.depth[i];

    const Surface surface = surface_at(found);
    // A path within `error` of the true geodesic meets the surface within error / cos of it.
    const double path_error = end.error + kRoundingPerCrossing * (1 + end.crossings);
    out.error[i] = path_error / std::max(std::abs(surface.incidence), 1e-3);
    const Vec3 chart_normal = Kernel::chart_vector(h.X, surface.S);

    Rgb albedo = surface.base, light{1.0f, 1.0f, 1.0f}, glossy{0.0f, 0.0f, 0.0f};
    Rgb bounced{0.0f, 0.0f, 0.0f};
    if (options.shade) {
      // Shadow rays need the accuracy of the point they shade, which the pixel sees at its depth;
      // so do the bounces, which are light arriving there.
      WalkContext shadows = context;
      shadows.tolerance = context.tolerance_at(out.depth[i]);
      shadows.tolerance_per_distance = 0.0;
      const Vertex vertex = vertex_at(h.X, surface, 0, options);
      const Reflected direct = illumination(shadows, vertex, options, stats, buffers, random);
      albedo = diffuse_albedo(vertex);
      light = direct.diffuse;
      glossy = direct.specular;
      if (vertex.bounce_follows && !context.stopped())
        bounced = bounce(shadows, vertex, options, stats, buffers, random);
      if (context.stopped()) {  // a shadow or bounce walk may have been cut short: the light is not known
        write_miss(out, i, kCancelled, 0, 0.0, found.chords);
        return;
      }
    }
    for (int a = 0; a < 3; ++a) {
      out.position[3 * i + a] = out.end[3 * i + a] = h.x[a];
      out.normal[3 * i + a] = float(chart_normal[a]);
      out.color[3 * i + a] = (options.shade ? surface.emission[a] : 0.0f) + albedo[a] * light[a] +
                             glossy[a] + bounced[a];
    }
    out.object[i] = surface.object;
  }

  // The first hit of the geodesic (P, V) within `length`: how the walk ended, the hit refined onto
  // the true curve, its instance, mesh triangle and chart plane, and the Embree queries made.
  struct Found {
    WalkEnd end;
    Hit hit{};
    const Placement* placed = nullptr;
    std::size_t prim = 0;
    Vec4 plane{};
    int chords = 0;
  };
  Found first_hit(const WalkContext& context, const Vec4& P, const Vec4& V, double length,
                  int max_crossings, double first_skip, std::vector<double>* segments) const {
    Found f;
    embree::FirstHit first;
    const auto query = [&](const Chord& chord, float tnear) {
      ++f.chords;
      if (segments)
        segments->insert(segments->end(), {chord.x0[0], chord.x0[1], chord.x0[2], chord.x1[0],
                                           chord.x1[1], chord.x1[2]});
      first = embree::intersect(scene_.get(), chord_ray(chord.x0, chord.x1, tnear));
      return first.prim >= 0;
    };
    // The triangle's chart plane, from its plane in the mesh and the instance's exact inverse.
    const auto locate = [&](const embree::FirstHit& found) {
      f.placed = &instances_[found.instance];
      f.prim = triangle_of(found);
      f.plane = f.placed->from_chart.pull_back(triangle_planes_[f.prim]);
    };
    const auto refine = [&](const auto& hit) {
      locate(first);
      f.hit = hit.refine(f.plane, first.u);
      if constexpr (Kernel::kChordsBend) {
        // The chord's triangle need not be the curve's: where the curve meets its plane outside
        // it, the curve met a neighbour, or none. Look again along the curve, a few chord margins
        // either way of that point, then of where the chord met the triangle, and refine on what
        // is found there; where nothing is, the curve passes the scene by within the chord's
        // margin (a silhouette the chord moved) and the hit is the curve's point where the chord
        // met the triangle, not where the curve meets the triangle's plane, which at grazing
        // angles lies far from the triangle.
        const auto& chord = hit.chord();
        double met = std::clamp(double(first.u), 0.0, 1.0) * chord.length;
        for (int again = 0; again < 4 && outside_triangle(f.prim, *f.placed, f.hit.x); ++again) {
          const double speed = std::max(norm3(head3(f.hit.V)), 1e-300);
          const double reach = 4.0 * chord.margin / speed + 1e-9 * chord.length;
          embree::FirstHit near;
          double t0 = 0.0, t1 = 0.0;
          for (const double centre : {f.hit.s, met}) {
            t0 = std::max(0.0, centre - reach);
            t1 = std::min(chord.length, centre + reach);
            Vec3 a, b;
            hit.curve_chord(t0, t1, a, b);
            near = embree::intersect(scene_.get(), chord_ray(a, b, 0.0f));
            if (near.prim >= 0) break;
          }
          if (near.prim < 0) {
            f.hit = hit.at(met);
            break;
          }
          first = near;
          locate(first);
          f.hit = hit.refine_between(f.plane, t0, t1, near.u);
          met = t0 + std::clamp(double(near.u), 0.0, 1.0) * (t1 - t0);
        }
      }
    };
    f.end = kernel_.walk(context, P, V, length, max_crossings, first_skip, query, refine);
    return f;
  }

  // A hit's surface as shading sees it: the unit geometric and shading normals, both facing the
  // ray, the metric cosine of incidence (of the winding normal), the material and its base colour
  // and emission there (none from the back of a one-sided emitter), the object, the ray's tangent
  // there and the hit's barycentric weights on its triangle.
  struct Surface {
    Vec4 N, S, V;
    double incidence;
    const Material* material;
    Rgb base, emission;
    std::int32_t object;
    Vec3 weights;
  };
  Surface surface_at(const Found& f) const {
    const Hit& h = f.hit;
    Surface s;
    s.V = h.V;
    s.N = kernel_.plane_normal(h.X, f.plane);
    if (!kernel_.normalise(h.X, s.N)) s.N = scaled(-1.0, h.V);  // degenerate triangle
    s.incidence = kernel_.dot(h.X, s.N, h.V);
    const bool front = s.incidence < 0.0;  // the ray meets the side the winding normal points to
    if (s.incidence > 0.0) s.N = scaled(-1.0, s.N);
    const auto& tri = triangles_[f.prim];
    const Vec3 in_mesh = f.placed->from_chart.point(h.x);
    s.weights = Surfaces::barycentric(vertices_[tri[0]], vertices_[tri[1]], vertices_[tri[2]], in_mesh);
    s.S = shading_normal(f.prim, s.weights, *f.placed, in_mesh, h, s.N);
    s.object = f.placed->object + triangle_object_[f.prim];
    surfaces_.look_up(f.prim, s.weights, s.base, s.emission);
    s.material = &surfaces_.materials[surfaces_.triangle_material[f.prim]];
    if (s.material->one_sided && !front) s.emission = {0.0f, 0.0f, 0.0f};
    return s;
  }

  // An orthonormal frame of the metric at X about the unit normal S: S and the two chart axes
  // least along S, made orthonormal to S and to each other. Directions in it (local coordinates,
  // z along S) are where the BSDF is written.
  struct Frame {
    Vec4 T1, T2, S;
  };
  Frame frame_at(const Vec4& X, const Vec4& S) const {
    const Vec3 n = Kernel::chart_vector(X, S);
    std::array<int, 3> axes{0, 1, 2};
    std::sort(axes.begin(), axes.end(), [&](int a, int b) { return std::abs(n[a]) < std::abs(n[b]); });
    const auto axis_tangent = [&](int a) {
      Vec3 e{0.0, 0.0, 0.0};
      e[a] = 1.0;
      return kernel_.chart_tangent(X, e);
    };
    Frame frame{axis_tangent(axes[0]), axis_tangent(axes[1]), S};
    frame.T1 = lin4(1.0, frame.T1, -kernel_.dot(X, frame.T1, S), S);
    kernel_.normalise(X, frame.T1);
    frame.T2 = lin4(1.0, frame.T2, -kernel_.dot(X, frame.T2, S), S);
    frame.T2 = lin4(1.0, frame.T2, -kernel_.dot(X, frame.T2, frame.T1), frame.T1);
    kernel_.normalise(X, frame.T2);
    return frame;
  }
  Vec3 local(const Vec4& X, const Frame& frame, const Vec4& V) const {
    return {kernel_.dot(X, V, frame.T1), kernel_.dot(X, V, frame.T2), kernel_.dot(X, V, frame.S)};
  }
  static Vec4 world(const Frame& frame, const Vec3& v) {
    return lin4(1.0, lin4(v[0], frame.T1, v[1], frame.T2), v[2], frame.S);
  }

  // A point that scatters light: where (X), its unit geometric and shading normals N and S (facing
  // the ray that met it), whether it is opaque (emitters are not), its base colour, and whether a
  // bounce will leave it (then the emitters' samples there are weighed against the bounce's
  // density: multiple importance sampling). Glossy materials have their BSDF, in `frame`;
  // Lambert's (base / pi) needs neither. A vertex `depth` bounces from the camera is left by a
  // bounce below the bounce limit; at the limit, one that gathers emission only where the
  // emitters' light is gathered by bounces alone, or by MIS at a glossy vertex (whose highlights of
  // emitters the samples on them find poorly), so that direct light only stays as it was on
  // Lambert surfaces.
  struct Vertex {
    Vec4 X, N, S;
    bool opaque, bounce_follows;
    Rgb base;
    Frame frame{};
    std::optional<Bsdf> bsdf;
  };
  Vertex vertex_at(const Vec4& X, const Surface& s, int depth, const TraceOptions& options) const {
    Vertex v{X, s.N, s.S, !s.material->emits(), depth < options.bounces, s.base, {}, std::nullopt};
    const Principled& scattering = s.material->scattering;
    if (scattering.glossy()) {
      v.frame = frame_at(X, s.S);
      v.bsdf.emplace(scattering, Color{s.base[0], s.base[1], s.base[2]}, local(X, v.frame, scaled(-1.0, s.V)));
    }
    v.bounce_follows |= depth == options.bounces && !emitters_.triangles.empty() &&
                        (options.emitter_sampling == EmitterSampling::kBounces ||
                         (options.emitter_sampling == EmitterSampling::kMis && v.bsdf));
    return v;
  }
  // What the Lambert part of a vertex's BSDF reflects (of the light summed by illumination's
  // `diffuse`): the base colour, dimmed under a glossy material's specular layer.
  static Rgb diffuse_albedo(const Vertex& v) {
    if (!v.bsdf) return v.base;
    return {float(v.bsdf->diffuse[0]), float(v.bsdf->diffuse[1]), float(v.bsdf->diffuse[2])};
  }
  // The density (solid angle) with which a bounce leaves the vertex along V: zero below its
  // geometric surface (such bounces are absorbed).
  double bounce_density(const Vertex& v, const Vec4& V) const {
    if (!(kernel_.dot(v.X, v.N, V) > 0.0)) return 0.0;
    if (v.bsdf) return v.bsdf->density(local(v.X, v.frame, V));
    return std::max(kernel_.dot(v.X, v.S, V), 0.0) / kPi;
  }
  // Multiple importance sampling's power heuristic: the weight of the technique of density a
  // against b (each density times its number of samples).
  static double power_weight(double a, double b) { return a * a / (a * a + b * b); }

  // Russian roulette from this bounce on: a path goes on with probability its throughput's largest
  // channel (at most kSurvival), and its throughput is divided by that.
  static constexpr int kRouletteFrom = 4;
  static constexpr double kSurvival = 0.95;

  // The light that options.bounces bounces bring to the camera ray's hit (vertex `v`). Each bounce
  // leaves in a direction drawn from the vertex's BSDF (Lambert: cosine-weighted about the shading
  // normal, whose density cos / pi cancels the BRDF's, so the throughput takes the albedo; glossy:
  // a mixture of that and GGX's visible normals, the throughput f cos / density), its geodesic
  // traced as camera rays are, with the fog along it; its hit adds the throughput times the
  // emission met there (weighed against the emitters' samples of that geodesic, MIS) and times
  // the light its next-event estimate reflects. A bounce beyond the limit (vertex_at) gathers
  // emission only.
  Rgb bounce(const WalkContext& context, Vertex v, const TraceOptions& options, TraceStats& stats,
             LightBuffers& buffers, Random& random) const {
    Color throughput{1.0, 1.0, 1.0};
    Rgb sum{0.0f, 0.0f, 0.0f};
    for (int b = 1; v.bounce_follows; ++b) {
      Vec4 V;
      double density;
      if (v.bsdf) {
        const double u0 = random.uniform(), u1 = random.uniform(), u2 = random.uniform();
        const Vec3 wi = v.bsdf->sample(u0, u1, u2);
        density = v.bsdf->density(wi);
        if (!(density > 0.0)) break;
        const Color f = v.bsdf->specular(wi);
        for (int a = 0; a < 3; ++a) throughput[a] *= (v.bsdf->diffuse[a] / kPi + f[a]) * wi[2] / density;
        V = world(v.frame, wi);
      } else {
        V = cosine_direction(v.X, v.S, random);
        density = bounce_density(v, V);
        for (int a = 0; a < 3; ++a) throughput[a] *= v.base[a];
      }
      if (b >= kRouletteFrom) {
        const double survive =
            std::min(kSurvival, std::max({throughput[0], throughput[1], throughput[2]}));
        if (!(random.uniform() < survive)) break;
        for (double& t : throughput) t /= survive;
      }
      // Shading normals can send a bounce below the surface: absorbed.
      if (!(kernel_.dot(v.X, v.N, V) > 0.0) || !kernel_.normalise(v.X, V)) break;
      ++stats.bounce_paths;
      const Found f = first_hit(context, v.X, V, options.max_distance, options.max_crossings,
                                kSelfSkip * scale_, nullptr);
      if (f.end.stop != kHit || context.stopped()) break;
      const Surface s = surface_at(f);
      const double length = f.end.distance + f.hit.s;
      const double fog = std::exp(-length / options.light_fog);
      for (double& t : throughput) t *= fog;
      if (s.material->emits() && options.emitter_sampling != EmitterSampling::kLightSamples) {
        const double weight = emission_weight(v, V, density, length, f, s, options, buffers);
        stats.emitter_hits += weight > 0.0;
        for (int a = 0; a < 3; ++a) sum[a] += float(throughput[a] * s.emission[a] * weight);
      }
      if (b > options.bounces) break;
      Vertex next = vertex_at(f.hit.X, s, b, options);
      const Reflected light = illumination(context, next, options, stats, buffers, random);
      const Rgb albedo = diffuse_albedo(next);
      for (int a = 0; a < 3; ++a)
        sum[a] += float(throughput[a] * (double(albedo[a]) * light.diffuse[a] + light.specular[a]));
      if (!(std::max({throughput[0], throughput[1], throughput[2]}) > 0.0)) break;
      v = std::move(next);
    }
    return sum;
  }

  // A unit direction at X about the unit normal S with density cos / pi over its hemisphere, in
  // the metric's orthonormal frame at X (frame_at).
  Vec4 cosine_direction(const Vec4& X, const Vec4& S, Random& random) const {
    const double u1 = random.uniform(), u2 = random.uniform();
    return world(frame_at(X, S), cosine_hemisphere(u1, u2));
  }

  // The unit shading normal at the hit: the metric normal of the chart plane through the hit
  // whose covector interpolates the corner normals, on the side of the geometric normal N (which
  // faces the ray); N itself where the triangle has no corner normals. The covectors are the
  // mesh's, pulled back to the chart by the instance (the inverse transpose of its linear part).
  Vec4 shading_normal(std::size_t prim, const Vec3& weights, const Placement& placed,
                      const Vec3& in_mesh, const Hit& h, const Vec4& N) const {
    Vec3 n;
    if (!surfaces_.normal_covector(prim, weights, n)) return N;
    Vec4 S = kernel_.plane_normal(h.X, placed.from_chart.pull_back({n[0], n[1], n[2], -dot3(n, in_mesh)}));
    if (!kernel_.normalise(h.X, S)) return N;
    return kernel_.dot(h.X, S, N) < 0.0 ? scaled(-1.0, S) : S;
  }

  // The light a vertex reflects towards its viewer, in two parts: `diffuse`, the sum of
  // radiance * cos * falloff * fog * cone (* the MIS weight) over the lights and the geodesics to
  // them (irradiance / pi, which the Lambert albedo multiplies), and `specular`, the same sum each
  // term times pi times the specular BRDF (glossy materials).
  struct Reflected {
    Rgb diffuse{0.0f, 0.0f, 0.0f}, specular{0.0f, 0.0f, 0.0f};
  };

  // Sum over lights and over the geodesics from the vertex to each of them, each geodesic with its
  // own shadow ray; then the emitters' light, from options.light_samples points sampled on them.
  Reflected illumination(const WalkContext& context, const Vertex& v, const TraceOptions& options,
                         TraceStats& stats, LightBuffers& buffers, Random& random) const {
    Reflected sum;
    const Vec4& H = v.X;
    std::vector<LightPath>& paths = buffers.paths;
    for (std::size_t l = 0; l < light_lifts_.size(); ++l) {
      paths.clear();
      stats.light_failures += kernel_.light_paths(H, light_lifts_[l], light_reach_, paths);
      const Rgb& radiance = light_radiance_[l];
      const SpotCone& cone = light_cone_[l];
      const double mean_radiance = mean_rgb(radiance);
      for (const LightPath& path : paths) {
        double weight = path.falloff * std::exp(-path.distance / options.light_fog);
        if (cone.active())
          weight *= cone.attenuation(kernel_.dot(light_lifts_[l][path.lift], light_axes_[l][path.lift],
                                                 kernel_.arrival(H, path)));
        ++stats.light_paths;
        stats.light_energy += weight * mean_radiance;
        const double cosine = kernel_.dot(H, v.S, path.direction);
        if (!(cosine > 0.0) || !(weight > 0.0) || (v.opaque && path.distance > geodesic_loop_) ||
            shadow(context, occluders_, H, path.direction, path.distance * (1.0 - 1e-6),
                   options.max_crossings) == kHit)
          continue;
        reflect(sum, v, path.direction, cosine * weight, radiance);
      }
    }
    if (!emitters_.triangles.empty() && options.emitter_sampling != EmitterSampling::kBounces)
      for (int s = 0; s < options.light_samples; ++s)
        sample_emitters(context, v, options, stats, buffers, random, sum);
    return sum;
  }
  // Adds one geodesic's light (term: everything but the BSDF and the radiance) to the sums.
  void reflect(Reflected& sum, const Vertex& v, const Vec4& direction, double term, const Rgb& radiance) const {
    for (int a = 0; a < 3; ++a) sum.diffuse[a] += float(term * radiance[a]);
    if (!v.bsdf) return;
    const Color f = v.bsdf->specular(local(v.X, v.frame, direction));
    for (int a = 0; a < 3; ++a) sum.specular[a] += float(kPi * f[a] * term * radiance[a]);
  }

  // A point y of emitter triangle t as the emitters' samples light with it: its point of the
  // geometry and unit normal (of the triangle's winding), the metric's area per chart area of the
  // triangle there, and in buffers its copies (points and normals), one per group element of the
  // emitter's copies. False where the triangle has no normal there.
  bool emitter_point(std::size_t t, const Vec3& y, LightBuffers& buffers, double& area_density) const {
    const std::array<Vec3, 3>& p = emitters_.triangles[t];
    const Vec3 e1 = sub3(p[1], p[0]), e2 = sub3(p[2], p[0]), n = cross3(e1, e2);
    const Vec4 Y = kernel_.chart_point(y);
    Vec4 normal = kernel_.plane_normal(Y, {n[0], n[1], n[2], -dot3(n, p[0])});
    if (!kernel_.normalise(Y, normal)) return false;
    const Vec4 a = kernel_.chart_tangent(Y, e1), b = kernel_.chart_tangent(Y, e2);
    const double ab = kernel_.dot(Y, a, b);
    area_density = std::sqrt(std::max(kernel_.dot(Y, a, a) * kernel_.dot(Y, b, b) - ab * ab, 0.0)) / norm3(n);
    std::vector<Vec4>&lifts = buffers.lifts, &normals = buffers.normals;
    lifts.clear();
    normals.clear();
    for (const Mat4& M : emitter_copies_[emitters_.group[t]]) {
      Vec4 X = Y, U = normal;
      kernel_.move(M, X, U);
      lifts.push_back(X);
      normals.push_back(U);
    }
    return true;
  }
  // The emitters' samples' density (solid angle, all light_samples of them together) of the
  // geodesic `path` to a point of emitter triangle t of area density `area_density`, reached at
  // cos' = emitted: a point is drawn with density 1 / (A_chart area_density) per area, and an area
  // dA at the far end of the geodesic is cos' falloff dA of solid angle at its start.
  double emitter_density(double area_density, double emitted, const LightPath& path,
                         const TraceOptions& options) const {
    return options.light_samples / (emitter_area_sum_.back() * area_density * emitted * path.falloff);
  }
  // Whether an emitter's copy shines towards the far end of a geodesic that arrives there with
  // tangent `arrival` (towards its start): cos' at the copy, from its front only where one-sided.
  double emitted_cosine(std::size_t t, const Vec4& lift, const Vec4& normal, const Vec4& arrival) const {
    const double towards = kernel_.dot(lift, normal, arrival);
    return emitters_.one_sided[t] ? towards : std::abs(towards);
  }

  // One point y sampled on the emitters (a triangle with probability its share of their chart
  // area, y uniform on it in the chart) lights the vertex along the geodesics to its copies as a
  // point light of radiance Le cos' / pi per unit area would: the estimate of
  // (1 / pi) integral Le cos cos' falloff dA is Le cos cos' falloff dA/dA_chart A_chart / pi, over
  // light_samples (cos' at the emitter's copy, towards the vertex: one-sided emitters light only
  // their front, the others both sides). The shadow rays meet every triangle, emitters too (so that
  // a closed emitter's far side is hidden by its near side), and stop just short of the sample.
  // Where a bounce leaves the vertex and could meet the same point along the same geodesic, the
  // two estimates are weighed by the power heuristic.
  void sample_emitters(const WalkContext& context, const Vertex& v, const TraceOptions& options,
                       TraceStats& stats, LightBuffers& buffers, Random& random, Reflected& sum) const {
    const Vec4& H = v.X;
    const std::size_t t = pick_emitter(random.uniform());
    const std::array<Vec3, 3>& p = emitters_.triangles[t];
    const double root = std::sqrt(random.uniform()), u = random.uniform();
    const Vec3 y = add3(p[0], add3(scaled3(root * (1.0 - u), sub3(p[1], p[0])), scaled3(root * u, sub3(p[2], p[0]))));
    double area_density;
    if (!emitter_point(t, y, buffers, area_density)) return;
    const double scale = area_density * emitter_area_sum_.back() / (kPi * options.light_samples);
    std::vector<LightPath>& paths = buffers.paths;
    paths.clear();
    stats.light_failures += kernel_.light_paths(H, buffers.lifts, light_reach_, paths);
    const Rgb& radiance = emitters_.radiance[t];
    const double mean_radiance = mean_rgb(radiance);
    const bool weighed = v.bounce_follows && options.emitter_sampling == EmitterSampling::kMis;
    for (const LightPath& path : paths) {
      const double emitted =
          emitted_cosine(t, buffers.lifts[path.lift], buffers.normals[path.lift], kernel_.arrival(H, path));
      const double weight = path.falloff * std::exp(-path.distance / options.light_fog) * scale;
      ++stats.emitter_paths;
      stats.emitter_energy += weight * std::max(emitted, 0.0) * mean_radiance;
      const double cosine = kernel_.dot(H, v.S, path.direction);
      const double short_of = path.distance * (1.0 - 1e-6) - kSelfSkip * scale_;
      if (!(cosine > 0.0) || !(emitted > 0.0) || (v.opaque && path.distance > geodesic_loop_))
        continue;
      const Stop stop = shadow(context, scene_.get(), H, path.direction, short_of, options.max_crossings);
      if (stop == kHit) continue;
      double mis = 1.0;
      // a bounce meets the point along this geodesic if it is drawn and its walk gets there
      if (weighed && stop != kCrossingLimit && path.distance <= options.max_distance)
        mis = power_weight(emitter_density(area_density, emitted, path, options), bounce_density(v, path.direction));
      reflect(sum, v, path.direction, cosine * emitted * weight * mis, radiance);
    }
  }

  // The MIS weight of the emission that a bounce from vertex v along V (drawn with `density`) met
  // at the end of a geodesic of `length` (hit f, surface s): the emitters' samples light the same
  // point along this geodesic where it is one of those they sum (within the reach, and found by
  // the light search: Sol's may miss one near a caustic), so the two are weighed by the power
  // heuristic; 1 where they do not (an emitter beyond the reach lights through bounces alone), 0
  // for a triangle not found among the emitters' copies (their samples alone count it).
  double emission_weight(const Vertex& v, const Vec4& V, double density, double length, const Found& f,
                         const Surface& s, const TraceOptions& options, LightBuffers& buffers) const {
    if (options.emitter_sampling == EmitterSampling::kBounces) return 1.0;
    const auto match = emitter_of_.find(emitter_key(std::size_t(f.placed - instances_.data()), f.prim));
    if (match == emitter_of_.end()) return 0.0;
    const std::size_t t = std::size_t(match->second);
    // The hit's point on the emitter triangle it is a copy of: its barycentric weights carried over
    // in homogeneous coordinates (the chart's in affine charts; the model's, which the projective
    // isometries keep, in the projective ones).
    const std::array<Vec3, 3>& p = emitters_.triangles[t];
    const auto& tri = triangles_[f.prim];
    std::array<double, 3> w;
    double total = 0.0;
    for (int k = 0; k < 3; ++k) {
      const Vec4 Q = kernel_.chart_point(f.placed->to_chart.point(vertices_[tri[k]]));
      w[k] = s.weights[k] * kernel_.chart_point(p[k])[3] / Q[3];
      total += w[k];
    }
    const Vec3 y = add3(scaled3(w[0] / total, p[0]), add3(scaled3(w[1] / total, p[1]), scaled3(w[2] / total, p[2])));
    double area_density;
    if (!emitter_point(t, y, buffers, area_density)) return 1.0;
    std::vector<LightPath>& paths = buffers.paths;
    paths.clear();
    kernel_.light_paths(v.X, buffers.lifts, light_reach_, paths);  // a geodesic missed: not among them
    // the emitters' samples' geodesic along V of this length, if they have it
    const LightPath* same = nullptr;
    double best = 1.0 - kSameDirection;
    for (const LightPath& path : paths) {
      const double along = kernel_.dot(v.X, path.direction, V);
      if (along > best && std::abs(path.distance - length) <= kSameLength * (1.0 + length)) {
        best = along;
        same = &path;
      }
    }
    if (!same || (v.opaque && same->distance > geodesic_loop_)) return 1.0;
    const double emitted =
        emitted_cosine(t, buffers.lifts[same->lift], buffers.normals[same->lift], kernel_.arrival(v.X, *same));
    if (!(emitted > 0.0)) return 1.0;
    return power_weight(density, emitter_density(area_density, emitted, *same, options));
  }
  // A bounce's geodesic and a light sample's are the same where their directions agree to this
  // (1 - cos) and their lengths to this relative tolerance: far looser than the walk's errors, far
  // tighter than two geodesics between the same points differ but at focal points.
  static constexpr double kSameDirection = 1e-4, kSameLength = 1e-3;

  // How the geodesic from the surface point H along dir ends within distance r among the
  // triangles of `blockers`: kHit where one blocks it; a shadow ray that runs out of crossings
  // found no blocker (kCrossingLimit: visible).
  Stop shadow(const WalkContext& context, RTCScene blockers, const Vec4& H, const Vec4& dir,
              double r, int max_crossings) const {
    const auto query = [&](const Chord& chord, float tnear) {
      return embree::occluded(blockers, chord_ray(chord.x0, chord.x1, tnear));
    };
    return kernel_.walk(context, H, dir, r, max_crossings, kSelfSkip * scale_, query,
                        [](const auto&) {}).stop;
  }

  // Finds, for every emissive triangle the walk can meet (each instance's), the emitter triangle
  // it is a copy of: its corners' points equal to those of a group element's copy of the emitter
  // triangle (the emitters' copies hold every copy near the domain). Both are compared as the
  // kernel's move() leaves points (SL2~'s chart reads its fibre angle back in (-2 pi, 2 pi]).
  void match_emitters() {
    if (emitters_.triangles.empty()) return;
    const auto moved = [&](const Mat4& M, const std::array<Vec3, 3>& p) {
      std::array<Vec4, 3> X;
      for (int k = 0; k < 3; ++k) {
        X[k] = kernel_.chart_point(p[k]);
        Vec4 U = kernel_.chart_tangent(X[k], sub3(p[(k + 1) % 3], p[k]));
        kernel_.move(M, X[k], U);
      }
      return X;
    };
    const Mat4 identity{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    struct Seen {
      std::array<Vec4, 3> corners;
      std::uint64_t key;
    };
    std::vector<Seen> seen;
    for (std::size_t i = 0; i < instances_.size(); ++i) {
      const Placement& placed = instances_[i];
      for (std::size_t t = mesh_first_[placed.mesh]; t < mesh_first_[placed.mesh + 1]; ++t) {
        if (!surfaces_.materials[surfaces_.triangle_material[t]].emits()) continue;
        std::array<Vec3, 3> p;
        for (int k = 0; k < 3; ++k) p[k] = placed.to_chart.point(vertices_[triangles_[t][k]]);
        seen.push_back({moved(identity, p), emitter_key(i, t)});
      }
    }
    std::sort(seen.begin(), seen.end(), [](const Seen& a, const Seen& b) { return a.corners[0][0] < b.corners[0][0]; });
    const auto size = [](const Vec4& a) {
      return 1.0 + std::max({std::abs(a[0]), std::abs(a[1]), std::abs(a[2]), std::abs(a[3])});
    };
    const auto close = [&](const Vec4& a, const Vec4& b) {
      for (int c = 0; c < 4; ++c)
        if (!(std::abs(a[c] - b[c]) <= kSamePoint * size(a))) return false;
      return true;
    };
    std::vector<std::vector<std::size_t>> of_group(emitter_copies_.size());
    for (std::size_t t = 0; t < emitters_.triangles.size(); ++t) of_group[emitters_.group[t]].push_back(t);
    for (std::size_t g = 0; g < of_group.size(); ++g)
      for (const Mat4& M : emitter_copies_[g])
        for (const std::size_t t : of_group[g]) {
          const std::array<Vec4, 3> lifted = moved(M, emitters_.triangles[t]);
          const double x = lifted[0][0], margin = 2.0 * kSamePoint * size(lifted[0]);
          auto it = std::lower_bound(seen.begin(), seen.end(), x - margin,
                                     [](const Seen& s, double value) { return s.corners[0][0] < value; });
          for (; it != seen.end() && it->corners[0][0] <= x + margin; ++it)
            if (close(it->corners[0], lifted[0]) && close(it->corners[1], lifted[1]) &&
                close(it->corners[2], lifted[2]))
              emitter_of_.emplace(it->key, std::int32_t(t));
        }
    unmatched_emitters_ = seen.size() - emitter_of_.size();
  }
  // Corners of a seen triangle and of an emitter's copy are the same point within this (relative
  // to the points' size): both come from the same vertices through a few float64 maps.
  static constexpr double kSamePoint = 1e-7;

  Kernel kernel_;
};

// Light lifts: E3 w = 1, S3 unit, H3 the upper sheet.
bool normalise_projective(int k, Vec4& X) {
  double s;
  if (k == 0) {
    s = 1.0 / X[3];
  } else if (k > 0) {
    s = 1.0 / std::sqrt(dot4(X, X));
  } else {
    const double q = -ProjectiveKernel{k}.inner(X, X);
    if (!(q > 0.0)) return false;
    s = std::copysign(1.0 / std::sqrt(q), X[3]);
  }
  X = scaled(s, X);
  return finite4(X);
}

// Chart points (x, 1): the marching geometries' model.
bool normalise_affine(int, Vec4& X) {
  if (!(X[3] != 0.0)) return false;
  X = scaled(1.0 / X[3], X);
  X[3] = 1.0;
  return finite4(X);
}

template <class Flow>
bool start_marching(int, Vec4& X, Vec4& V) {
  return MarchingKernel<Flow>().start(X, V);
}

bool start_projective(int k, Vec4& X, Vec4& V) { return ProjectiveKernel{k}.start(X, V); }

struct Geometry {
  const char* name;
  int curvature;  // projective kernels; unused by the others
  std::unique_ptr<Tracer> (*make)(int curvature, SceneData scene, unsigned threads);
  bool (*normalise)(int curvature, Vec4& X);
  bool (*start)(int curvature, Vec4& X, Vec4& V);
  bool (*flow)(const Vec3& x, const Vec3& v, double t, double accuracy, Vec3& xt, Vec3& vt);
  std::unique_ptr<Connections> (*connections)(double reach);
};

std::unique_ptr<Tracer> make_projective(int k, SceneData scene, unsigned threads) {
  return std::make_unique<KernelTracer<ProjectiveKernel>>(ProjectiveKernel{k}, std::move(scene),
                                                          threads, false);
}

template <class Flow>
std::unique_ptr<Tracer> make_marching(int, SceneData scene, unsigned threads) {
  return std::make_unique<KernelTracer<MarchingKernel<Flow>>>(MarchingKernel<Flow>(),
                                                              std::move(scene), threads, true);
}

template <class Flow>
bool flow_of(const Vec3& x, const Vec3& v, double t, double accuracy, Vec3& xt, Vec3& vt) {
  double error;
  Flow().flow(x, v, t, accuracy, xt, vt, error);
  return true;
}

// A marching kernel prepared for a reach, as Connections.
template <class Flow>
class MarchingConnections final : public Connections {
 public:
  explicit MarchingConnections(double reach) : reach_(reach) { kernel_.prepare_light_paths(reach); }
  int connect(const Vec3& h, const Vec3& l, std::vector<LightPath>& paths) const override {
    return kernel_.light_paths(point4(h), {point4(l)}, reach_, paths);
  }

 private:
  MarchingKernel<Flow> kernel_;
  double reach_;
};

template <class Flow>
std::unique_ptr<Connections> connections_of(double reach) {
  return std::make_unique<MarchingConnections<Flow>>(reach);
}

const Geometry kGeometries[] = {
    {"E3", 0, make_projective, normalise_projective, start_projective, nullptr, nullptr},
    {"S3", 1, make_projective, normalise_projective, start_projective, nullptr, nullptr},
    {"H3", -1, make_projective, normalise_projective, start_projective, nullptr, nullptr},
    {"Nil", 0, make_marching<NilFlow>, normalise_affine, start_marching<NilFlow>, flow_of<NilFlow>,
     connections_of<NilFlow>},
    {"Sol", 0, make_marching<SolFlow>, normalise_affine, start_marching<SolFlow>, flow_of<SolFlow>,
     connections_of<SolFlow>},
    {"H2xR", 0, make_marching<H2xRFlow>, H2xRFlow::normalise_lift, start_marching<H2xRFlow>,
     flow_of<H2xRFlow>, connections_of<H2xRFlow>},
    {"S2xR", 0, make_marching<S2xRFlow>, normalise_affine, start_marching<S2xRFlow>,
     flow_of<S2xRFlow>, connections_of<S2xRFlow>},
    {"SL2", 0, make_marching<SL2Flow>, SL2Flow::normalise_lift, start_marching<SL2Flow>,
     flow_of<SL2Flow>, connections_of<SL2Flow>},
};

const Geometry& find(const std::string& name) {
  for (const Geometry& g : kGeometries)
    if (name == g.name) return g;
  throw std::invalid_argument("unknown geometry " + name);
}

}  // namespace

std::vector<std::string> geometry_names() {
  std::vector<std::string> names;
  for (const Geometry& g : kGeometries) names.push_back(g.name);
  return names;
}

bool has_geometry(const std::string& name) {
  for (const Geometry& g : kGeometries)
    if (name == g.name) return true;
  return false;
}

bool normalise_point(const std::string& geometry, Vec4& X) {
  const Geometry& g = find(geometry);
  return g.normalise(g.curvature, X);
}

bool normalise_direction(const std::string& geometry, Vec4& X, Vec4& V) {
  const Geometry& g = find(geometry);
  return g.start(g.curvature, X, V);
}

std::unique_ptr<Tracer> make_tracer(const std::string& geometry, SceneData scene, unsigned threads) {
  const Geometry& g = find(geometry);
  return g.make(g.curvature, std::move(scene), threads);
}

bool geodesic_flow(const std::string& geometry, const Vec3& x, const Vec3& v, double t,
                   double accuracy, Vec3& xt, Vec3& vt) {
  const Geometry& g = find(geometry);
  return g.flow && g.flow(x, v, t, accuracy, xt, vt);
}

std::unique_ptr<Connections> make_connections(const std::string& geometry, double reach) {
  const Geometry& g = find(geometry);
  return g.connections ? g.connections(reach) : nullptr;
}

}  // namespace thurston
