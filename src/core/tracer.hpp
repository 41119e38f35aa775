// Ray tracer for inside views of quotient manifolds: rays walk through a convex fundamental domain,
// jump across faces by the face pairings, and meet the scene (triangles in the chart) through
// Embree queries of chart chords. How a ray walks is the geometry's kernel (kernel.hpp); the walk
// and the light over it are kernel_tracer.hpp and integrator.hpp, a geometry's kernel is chosen by
// name in registry.hpp; this file is the part every geometry shares: runs on the thread pool
// (tracer.cpp) and the Embree scene (embree_scene.cpp).
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "embree.hpp"
#include "kernel.hpp"
#include "scene.hpp"
#include "surface.hpp"
#include "thread_pool.hpp"

namespace thurston {

// Read-only strided 2-D view (strides in elements), so that rays need not be copied.
template <class T>
struct Strided2 {
  const T* data;
  std::int64_t row_stride, col_stride;
  T operator()(std::size_t i, std::size_t j) const {
    return data[static_cast<std::int64_t>(i) * row_stride +
                static_cast<std::int64_t>(j) * col_stride];
  }
};

// How the emissive meshes' light reaches the shaded points: next-event estimates and bounces that
// meet them, combined by multiple importance sampling (kMis); the next-event estimates alone
// (kLightSamples: what a bounce meets is not added); or the bounces alone (kBounces: no samples on
// the emitters). The last two are for measuring the first.
enum class EmitterSampling : std::uint8_t { kMis = 0, kLightSamples = 1, kBounces = 2 };

// Rays per unit of work, and the block of ray ids whose rays learn shadow-walk visibility together
// (TraceOptions::ray_ids): a tile of an image that holds whole blocks is traced as the image is.
constexpr std::size_t kRayBlock = 1024;

struct TraceOptions {
  double max_distance;
  int max_crossings;
  bool shade;
  bool record_segments;
  double tolerance;               // chord deviation at distance 0 (chart units) ...
  double tolerance_per_distance;  // ... and its growth per unit of distance
  bool skip_empty;                // empty-space steps and the occupancy grid (WalkContext)
  double light_fog;    // distance over which light falls to 1/e along its path (inf: none)
  int light_samples;   // points sampled on the emitters per shaded point
  std::uint64_t seed;  // of the samples' random numbers (a ray's depend on it and its index)
  int bounces;         // bounces after the camera ray's hit (0: direct light only)
  EmitterSampling emitter_sampling = EmitterSampling::kMis;
  // Shadow walks per shaded point for direct light (integrator.hpp, choose_light_paths): the
  // strongest geodesics to the lights' copies and the emitters' samples always, the rest sampled
  // in proportion to their unshadowed light; 0: every geodesic (the exact sum).
  int light_budget = 0;
  // Texels per cube-face edge of each point light's visibility map (visibility_map.hpp; 0: none):
  // a point light's geodesics are looked up in it instead of walked, and walked too with
  // probability map_check, which measures the map's error (TraceStats; integrator.hpp,
  // map_visibility).
  int visibility_map = 0;
  double map_check = 0.0;
  // Per ray, increasing: the index its random numbers are drawn for and the block of kChunk ids
  // whose rays learn shadow-walk visibility together (a subset of a larger trace's rays, a tile of
  // an image, keeps both); null: its position.
  const std::int64_t* ray_ids = nullptr;
};

// Caller-allocated per-ray outputs (N rows each).
struct TraceOutputs {
  float* color;      // (N,3)
  double* depth;     // (N,)
  double* position;  // (N,3)
  float* normal;     // (N,3)
  std::int32_t* object;
  std::int32_t* crossings;
  std::uint8_t* stop;
  double* distance;      // geodesic length travelled: depth on a hit, max_distance at the limit
  std::int32_t* chords;  // Embree queries of the ray
  double* error;         // bound of the hit's distance from the true geodesic (chart units)
  double* end;           // (N,3) chart point where the ray stopped: the hit, or the end of its walk
  float* albedo;         // (N,3) the hit's diffuse albedo (base colour, textures, under a glossy
                         // layer dimmed as shading has it); 0 for a miss
  float* carried_normal;  // (N,3) the hit's shading normal carried back along the ray to its
                          // origin (chart image there, unit in the chart); 0 for a miss

  // The outputs of ray i that hit nothing.
  void write_miss(std::size_t i, Stop stop, int crossings, double distance, int chords,
                  const Vec3& end_point = {kNaN, kNaN, kNaN}) const {
    for (int a = 0; a < 3; ++a) {
      color[3 * i + a] = 0.0f;
      position[3 * i + a] = kNaN;
      normal[3 * i + a] = float(kNaN);
      end[3 * i + a] = end_point[a];
      albedo[3 * i + a] = carried_normal[3 * i + a] = 0.0f;
    }
    depth[i] = kInf;
    object[i] = -1;
    this->crossings[i] = crossings;
    this->stop[i] = stop;
    this->distance[i] = distance;
    this->chords[i] = chords;
    error[i] = kNaN;
  }
};

struct TraceStats {
  std::uint64_t chords = 0;
  std::uint64_t light_failures = 0;  // light paths known to be missed (Sol's shooting)
  // geodesics to lights that arrive at a shaded point's front (of its shading normal), summed
  std::uint64_t light_paths = 0;
  // Sum over shaded points of the mean radiance times falloff (and fog) along those paths, before
  // cosines and shadows: what the reach lets in, against which the part left out is told.
  double light_energy = 0.0;
  // The same for the emitters' samples: geodesics to sampled points' copies, and their mean
  // radiance times cos' (at the emitter) times falloff (and fog) over the sampling density.
  std::uint64_t emitter_paths = 0;
  double emitter_energy = 0.0;
  std::uint64_t shadow_walks = 0;    // shadow walks traced for direct light (the sampled paths)
  std::uint64_t shadowed_walks = 0;  // of them, those that met a blocker
  std::uint64_t bounce_paths = 0;    // geodesics traced for bounces (path tracing)
  // Point lights' geodesics looked up in their visibility maps, those of them walked as checks,
  // and the texels traced; the checks' unshadowed light (mean radiance times the rest of the
  // term) and of it the part the map answered wrongly (|walk's visibility - map's|).
  std::uint64_t map_lookups = 0, map_checks = 0, map_texels = 0;
  double map_checked_light = 0.0, map_error_light = 0.0;
  std::uint64_t emitter_hits = 0;  // bounces that met an emitter (its light weighted by MIS)
  // Recorded chords by chunk of rays, in ray order: 6 doubles each, start xyz and end xyz.
  std::vector<std::vector<double>> segments;

  // Adds another's counts (not its energies or segments, which are summed in chunk order).
  void add_counts(const TraceStats& o) {
    chords += o.chords;
    light_failures += o.light_failures;
    light_paths += o.light_paths;
    emitter_paths += o.emitter_paths;
    shadow_walks += o.shadow_walks;
    shadowed_walks += o.shadowed_walks;
    bounce_paths += o.bounce_paths;
    emitter_hits += o.emitter_hits;
    map_lookups += o.map_lookups;
    map_checks += o.map_checks;
    map_texels += o.map_texels;
    map_checked_light += o.map_checked_light;
    map_error_light += o.map_error_light;
  }
};

// What every tracer shares: Embree scenes, the thread pool, runs, cancel and progress.
class Tracer {
 public:
  // Called on the tracing thread about every 0.1 s with the number of finished rays; returning
  // false stops the workers.
  using Poll = std::function<bool(std::size_t done)>;

  virtual ~Tracer();
  Tracer(const Tracer&) = delete;
  Tracer& operator=(const Tracer&) = delete;

  unsigned num_threads() const { return pool_.size(); }
  std::size_t num_triangles() const { return triangles_.size(); }  // the meshes' own
  std::size_t num_instances() const { return instances_.size(); }
  std::size_t num_instanced_triangles() const;  // what the instances place in all
  double light_reach() const { return light_reach_; }
  std::size_t num_light_lifts() const;
  // The sum over lights of their radiance's mean over RGB, and over the emitters of
  // mean radiance * chart area / 4 pi (a far emitter of radiance Le and area A lights as a point
  // light of power Le A / 4 pi, averaged over its orientations).
  double light_power() const;
  std::size_t num_emitter_triangles() const { return emitters_.triangles.size(); }
  std::size_t num_emitter_copies() const { return emitters_.copies.size(); }
  // Emissive triangles the walk can meet (per instance) that were not found among the emitters'
  // copies: a bounce meeting one adds no light (their light comes from the emitters' samples).
  std::size_t num_unmatched_emitters() const { return unmatched_emitters_; }

  TraceStats trace(std::size_t count, Strided2<double> origins, Strided2<double> directions,
                   const TraceOptions& options, const TraceOutputs& out, const Poll& poll);
  void cancel() { cancel_.store(true); }

  // Bare Embree first hit on chart segments: chord parameter in [0, 1] (inf if none), the
  // mesh triangle hit and its instance.
  void query_segments(std::size_t count, Strided2<double> starts, Strided2<double> ends, float* t,
                      std::int32_t* prim, std::int32_t* instance);

 protected:
  Tracer(SceneData& scene, unsigned threads, bool occupancy);  // takes the scene's vectors

  // Readies what a trace with these options shares across its rays (the visibility maps).
  virtual void prepare(const TraceOptions& options) = 0;
  // Traces rays [begin, end) into `out`; what the kernel does per ray.
  virtual void trace_range(std::size_t begin, std::size_t end, Strided2<double> origins,
                           Strided2<double> directions, const TraceOptions& options,
                           const TraceOutputs& out, std::vector<double>* segments,
                           TraceStats& stats) const = 0;

  WalkContext context(const TraceOptions& options) const {
    return {domain_,
            hit_lo_,
            hit_hi_,
            occupancy_,
            options.tolerance,
            options.tolerance_per_distance,
            options.skip_empty,
            run_stop_};
  }

  // An instance as the walk uses it: besides the placement, the inverse map, which pulls chart
  // planes and points back to the mesh's coordinates in double precision.
  struct Placement {
    std::uint32_t mesh;
    std::int32_t object;
    Affine to_chart, from_chart;
  };
  // The mesh triangle of an Embree hit.
  std::size_t triangle_of(const embree::FirstHit& hit) const {
    return mesh_first_[instances_[hit.instance].mesh] + std::size_t(hit.prim);
  }
  // Whether the chart point x lies outside the triangle (its barycentric weights, in the mesh's
  // coordinates, below -1e-9).
  bool outside_triangle(std::size_t prim, const Placement& placed, const Vec3& x) const {
    const auto& tri = triangles_[prim];
    const Vec3 w = Surfaces::barycentric(vertices_[tri[0]], vertices_[tri[1]], vertices_[tri[2]],
                                         placed.from_chart.point(x));
    return std::min({w[0], w[1], w[2]}) < -1e-9;
  }

  Domain domain_;
  std::vector<Vec3> vertices_;
  std::vector<std::array<std::uint32_t, 3>> triangles_;
  std::vector<Vec4> triangle_planes_;  // plane covectors (n, -n . p0) in the mesh's coordinates
  std::vector<std::int32_t> triangle_object_;
  std::vector<std::uint32_t> mesh_first_;  // meshes + 1 entries: mesh m is [first[m], first[m + 1])
  std::vector<Placement> instances_;
  Surfaces surfaces_;
  std::vector<std::vector<Vec4>> light_lifts_;  // per light
  std::vector<Rgb> light_radiance_;
  std::vector<SpotCone> light_cone_;             // per light
  std::vector<std::vector<Vec4>> light_axes_;    // per light and lift, where it has a cone
  std::vector<std::vector<Mat4>> light_copies_;  // per light and lift, where given
  // The emitters: their triangles, a cumulative table of their chart areas (a triangle is picked
  // with probability its share), and each group's copies.
  Emitters emitters_;
  std::vector<double> emitter_area_sum_;
  std::vector<std::vector<Mat4>> emitter_copies_;
  std::size_t pick_emitter(double u) const;
  // The emitter triangle (index into emitters_) that each emissive triangle the walk can meet is
  // a copy of, by instance << 32 | mesh triangle: a bounce that meets it weighs its light against
  // the emitters' samples of the same point.
  std::unordered_map<std::uint64_t, std::int32_t> emitter_of_;
  std::size_t unmatched_emitters_ = 0;
  static std::uint64_t emitter_key(std::size_t instance, std::size_t triangle) {
    return (std::uint64_t(instance) << 32) | std::uint64_t(triangle);
  }
  double light_reach_;
  double geodesic_loop_;
  double scale_ = 0.0;        // largest extent or coordinate magnitude of the scene
  Vec3 hit_lo_{}, hit_hi_{};  // the scene's bounds widened by a margin (empty: none)
  Occupancy occupancy_;

  struct EmbreeDeleter {
    void operator()(RTCDevice d) const { rtcReleaseDevice(d); }
    void operator()(RTCScene s) const { rtcReleaseScene(s); }
  };
  using DeviceHandle = std::unique_ptr<RTCDeviceTy, EmbreeDeleter>;
  using SceneHandle = std::unique_ptr<RTCSceneTy, EmbreeDeleter>;
  std::vector<float> float_vertices_;  // Embree's shared vertex buffer of every geometry (padded)
  DeviceHandle device_;
  SceneHandle scene_;
  SceneHandle occluder_scene_;  // without emissive objects, so that lamps do not shadow their light
  RTCScene occluders_ = nullptr;

 private:
  // The chart bounds of the instances, the occupancy grid (marching kernels) and the scale.
  void bound_instances(bool occupancy);
  // The Embree device, the shared vertex buffer and the scenes of all triangles and of the
  // occluders.
  void build_scenes();
  // The two-level Embree scene of the instances: top-level geometry i is instance i (the mesh's
  // triangles attached directly where its map is the identity, else an instance of the mesh's
  // own scene); casting: only the triangles whose material does not emit.
  SceneHandle build_top_scene(bool casting);
  RTCGeometry new_triangles(const std::vector<std::uint32_t>& triangle_ids) const;
  std::vector<std::uint32_t> mesh_triangle_ids(std::size_t mesh, bool casting) const;
  std::vector<SceneHandle> mesh_scenes_[2];  // by casting, per mesh: built where instanced

  // Runs fn(chunk, begin, end) over the chunks [starts[k], starts[k + 1]) on the pool, polling
  // from this thread; returns how many items (a prefix) were done before a stop.
  std::size_t run_chunks(const std::vector<std::size_t>& starts,
                         const std::function<void(std::size_t, std::size_t, std::size_t)>& fn,
                         const Poll& poll, bool cancellable);

  ThreadPool pool_;
  struct RunLock {
    explicit RunLock(Tracer& tracer);
    ~RunLock();
    Tracer& tracer_;
  };
  std::mutex run_mutex_;
  std::atomic<std::thread::id> runner_{};
  std::atomic<bool> cancel_{false};
  // Set to stop the run in progress (cancel, a progress callback's false, a worker's exception);
  // the workers look at it between chunks and the walks on every step.
  std::atomic<bool> run_stop_{false};
};

}  // namespace thurston
