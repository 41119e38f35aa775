#include "tracer.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
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
  for (std::size_t k = 0; k < scene.light_lifts.size(); ++k)
    light_lifts_[scene.light_of_lift[k]].push_back(scene.light_lifts[k]);

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
  return p;
}

TraceStats Tracer::trace(std::size_t count, Strided2<double> origins, Strided2<double> directions,
                         const TraceOptions& options, const TraceOutputs& out, const Poll& poll) {
  const RunLock lock(*this);
  cancel_.store(false);
  const std::size_t chunks = (count + kChunk - 1) / kChunk;
  // Kept by chunk, so that the recording does not depend on the thread count.
  std::vector<std::vector<double>> chunk_segments(options.record_segments ? chunks : 0);
  std::atomic<std::uint64_t> chords{0}, light_failures{0}, light_paths{0};
  std::vector<double> chunk_energy(chunks, 0.0);  // summed in chunk order: the same for any threads
  const std::size_t traced = run_chunks(
      count,
      [&](std::size_t chunk, std::size_t begin, std::size_t end) {
        std::vector<double>* segments = options.record_segments ? &chunk_segments[chunk] : nullptr;
        TraceStats local;
        trace_range(begin, end, origins, directions, options, out, segments, local);
        chords.fetch_add(local.chords);
        light_failures.fetch_add(local.light_failures);
        light_paths.fetch_add(local.light_paths);
        chunk_energy[chunk] = local.light_energy;
      },
      poll, true);
  for (std::size_t i = traced; i < count; ++i) write_miss(out, i, kCancelled, 0, 0.0, 0);
  TraceStats stats;
  stats.chords = chords.load();
  stats.light_failures = light_failures.load();
  stats.light_paths = light_paths.load();
  for (const double e : chunk_energy) stats.light_energy += e;
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

// The geodesics from H to a light that illumination() sums. Kernels with closed forms
// (kEveryLightPath) give every one within the reach; the others the one to the light's nearest
// copy (false where it was not found), whatever the reach.
template <class Kernel>
bool light_paths(const Kernel& kernel, const Vec4& H, const std::vector<Vec4>& lifts, double reach,
                 typename Kernel::LightHint& hint, std::vector<LightPath>& paths) {
  if constexpr (Kernel::kEveryLightPath) {
    kernel.light_paths(H, lifts, reach, paths);
    return true;
  } else {
    LightPath path;
    if (!kernel.light_path(H, lifts, path, hint)) return false;
    paths.push_back(path);
    return true;
  }
}

template <class Kernel>
class KernelTracer final : public Tracer {
 public:
  KernelTracer(Kernel kernel, SceneData scene, unsigned threads, bool occupancy)
      : Tracer(scene, threads, occupancy), kernel_(kernel) {}

 private:
  using Chord = typename Kernel::Chord;
  // Per chunk: the kernel's hint per light, and the buffer of one point's light paths.
  struct LightHints {
    std::vector<typename Kernel::LightHint> kernel;
    std::vector<LightPath> paths;
  };

  void trace_range(std::size_t begin, std::size_t end, Strided2<double> origins,
                   Strided2<double> directions, const TraceOptions& options,
                   const TraceOutputs& out, std::vector<double>* segments,
                   TraceStats& stats) const override {
    const WalkContext context = this->context(options);
    // rays of a chunk are neighbouring pixels
    LightHints hints{std::vector<typename Kernel::LightHint>(light_lifts_.size()), {}};
    for (std::size_t i = begin; i < end; ++i) {
      const Vec4 o{origins(i, 0), origins(i, 1), origins(i, 2), origins(i, 3)};
      const Vec4 d{directions(i, 0), directions(i, 1), directions(i, 2), directions(i, 3)};
      trace_ray(i, o, d, context, options, out, segments, stats, hints);
    }
  }

  void trace_ray(std::size_t i, const Vec4& origin, const Vec4& direction,
                 const WalkContext& context, const TraceOptions& options, const TraceOutputs& out,
                 std::vector<double>* segments, TraceStats& stats, LightHints& hints) const {
    Vec4 P = origin, V = direction;
    if (!kernel_.start(P, V)) {  // no point or no direction: the ray goes nowhere
      write_miss(out, i, kDistanceLimit, 0, 0.0, 0);
      return;
    }
    int chords = 0;
    embree::FirstHit first;
    Hit h{};
    const auto query = [&](const Chord& chord, float tnear) {
      ++chords;
      if (segments)
        segments->insert(segments->end(), {chord.x0[0], chord.x0[1], chord.x0[2], chord.x1[0],
                                           chord.x1[1], chord.x1[2]});
      first = embree::intersect(scene_.get(), chord_ray(chord.x0, chord.x1, tnear));
      return first.prim >= 0;
    };
    // The triangle's chart plane, from its plane in the mesh and the instance's exact inverse.
    const Placement* placed = nullptr;
    std::size_t prim = 0;
    Vec4 plane{};
    const auto refine = [&](const auto& hit) {
      placed = &instances_[first.instance];
      prim = triangle_of(first);
      plane = placed->from_chart.pull_back(triangle_planes_[prim]);
      h = hit.refine(plane, first.u);
    };
    const WalkEnd end = kernel_.walk(context, P, V, options.max_distance, options.max_crossings, 0.0,
                                     query, refine);
    stats.chords += chords;
    if (end.stop != kHit) {
      write_miss(out, i, end.stop, end.crossings, end.distance, chords, end.end);
      return;
    }
    out.stop[i] = kHit;
    out.crossings[i] = end.crossings;
    out.chords[i] = chords;
    out.depth[i] = end.distance + h.s;
    out.distance[i] = out.depth[i];

    // Unit normal at the hit facing the incoming ray.
    Vec4 N = kernel_.plane_normal(h.X, plane);
    if (!kernel_.normalise(h.X, N)) N = scaled(-1.0, h.V);  // degenerate triangle
    const double incidence = kernel_.dot(h.X, N, h.V);
    if (incidence > 0.0) N = scaled(-1.0, N);
    // A path within `error` of the true geodesic meets the surface within error / cos of it.
    const double path_error = end.error + kRoundingPerCrossing * (1 + end.crossings);
    out.error[i] = path_error / std::max(std::abs(incidence), 1e-3);

    const auto& tri = triangles_[prim];
    const Vec3 in_mesh = placed->from_chart.point(h.x);
    const Vec3 weights =
        Surfaces::barycentric(vertices_[tri[0]], vertices_[tri[1]], vertices_[tri[2]], in_mesh);
    const Vec4 S = shading_normal(prim, weights, *placed, in_mesh, h, N);
    const Vec3 chart_normal = Kernel::chart_vector(h.X, S);

    const std::int32_t object = placed->object + triangle_object_[prim];
    Rgb base, emission;
    surfaces_.look_up(prim, weights, base, emission);
    Rgb light{1.0f, 1.0f, 1.0f};
    if (options.shade) {
      // Shadow rays need the accuracy of the point they shade, which the pixel sees at its depth.
      WalkContext shadows = context;
      shadows.tolerance = context.tolerance_at(out.depth[i]);
      shadows.tolerance_per_distance = 0.0;
      const bool opaque = !surfaces_.materials[surfaces_.triangle_material[prim]].emits();
      light = illumination(shadows, h.X, S, opaque, options.max_crossings, options.light_fog, stats,
                           hints);
      if (context.stopped()) {  // a shadow walk may have been cut short: the light is not known
        write_miss(out, i, kCancelled, 0, 0.0, chords);
        return;
      }
    }
    for (int a = 0; a < 3; ++a) {
      out.position[3 * i + a] = out.end[3 * i + a] = h.x[a];
      out.normal[3 * i + a] = float(chart_normal[a]);
      out.color[3 * i + a] = (options.shade ? emission[a] : 0.0f) + base[a] * light[a];
    }
    out.object[i] = object;
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

  // Sum over lights and over the geodesics from the surface point H (normal N) to each of them of
  // radiance * cos * falloff * fog * visibility, each geodesic with its own shadow ray.
  Rgb illumination(const WalkContext& context, const Vec4& H, const Vec4& N, bool opaque,
                   int max_crossings, double fog, TraceStats& stats, LightHints& hints) const {
    Rgb sum{0.0f, 0.0f, 0.0f};
    std::vector<LightPath>& paths = hints.paths;
    for (std::size_t l = 0; l < light_lifts_.size(); ++l) {
      paths.clear();
      if (!light_paths(kernel_, H, light_lifts_[l], light_reach_, hints.kernel[l], paths)) {
        ++stats.light_failures;
        continue;
      }
      const Rgb& radiance = light_radiance_[l];
      const double mean_radiance = mean_rgb(radiance);
      for (const LightPath& path : paths) {
        const double weight = path.falloff * std::exp(-path.distance / fog);
        ++stats.light_paths;
        stats.light_energy += weight * mean_radiance;
        const double cosine = kernel_.dot(H, N, path.direction);
        if (!(cosine > 0.0) || (opaque && path.distance > geodesic_loop_) ||
            !visible(context, H, path.direction, path.distance, max_crossings))
          continue;
        for (int a = 0; a < 3; ++a) sum[a] += float(cosine * weight * radiance[a]);
      }
    }
    return sum;
  }

  // Whether the geodesic from the surface point H along dir reaches distance r unobstructed. A
  // shadow ray that runs out of crossings found no blocker and counts as visible.
  bool visible(const WalkContext& context, const Vec4& H, const Vec4& dir, double r,
               int max_crossings) const {
    const auto query = [&](const Chord& chord, float tnear) {
      return embree::occluded(occluders_, chord_ray(chord.x0, chord.x1, tnear));
    };
    // Embree's float vertices are only good to about 1e-7 of the scene's scale.
    return kernel_.walk(context, H, dir, r * (1.0 - 1e-6), max_crossings, 1e-5 * scale_, query,
                        [](const auto&) {}).stop != kHit;
  }

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

struct Geometry {
  const char* name;
  int curvature;  // projective kernels; unused by the others
  std::unique_ptr<Tracer> (*make)(int curvature, SceneData scene, unsigned threads);
  bool (*normalise)(int curvature, Vec4& X);
  bool (*flow)(const Vec3& x, const Vec3& v, double t, double accuracy, Vec3& xt, Vec3& vt);
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

const Geometry kGeometries[] = {
    {"E3", 0, make_projective, normalise_projective, nullptr},
    {"S3", 1, make_projective, normalise_projective, nullptr},
    {"H3", -1, make_projective, normalise_projective, nullptr},
    {"Nil", 0, make_marching<NilFlow>, normalise_affine, flow_of<NilFlow>},
    {"Sol", 0, make_marching<SolFlow>, normalise_affine, flow_of<SolFlow>},
    {"H2xR", 0, make_marching<H2xRFlow>, H2xRFlow::normalise_lift, flow_of<H2xRFlow>},
    {"S2xR", 0, make_marching<S2xRFlow>, normalise_affine, flow_of<S2xRFlow>},
    {"SL2", 0, make_marching<SL2Flow>, SL2Flow::normalise_lift, flow_of<SL2Flow>},
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

std::unique_ptr<Tracer> make_tracer(const std::string& geometry, SceneData scene, unsigned threads) {
  const Geometry& g = find(geometry);
  return g.make(g.curvature, std::move(scene), threads);
}

bool geodesic_flow(const std::string& geometry, const Vec3& x, const Vec3& v, double t,
                   double accuracy, Vec3& xt, Vec3& vt) {
  const Geometry& g = find(geometry);
  return g.flow && g.flow(x, v, t, accuracy, xt, vt);
}

}  // namespace thurston
