// Ray tracer for inside views of quotient manifolds: rays walk through a convex fundamental domain
// in a projective chart, jump across faces by the face pairings, and meet the scene (triangles in
// the chart) through Embree queries of straight chart chords, which are exact geodesic segments.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "embree.hpp"
#include "geometry.hpp"
#include "thread_pool.hpp"

namespace thurston {

using Rgb = std::array<float, 3>;
using Mat4 = std::array<double, 16>;  // row-major

// Validated scene description; see the Python docstring of Tracer for the meaning of each field.
struct SceneData {
  int curvature = 0;
  std::vector<Vec4> face_covectors;
  std::vector<Mat4> face_maps;
  std::vector<Vec3> vertices;  // chart coordinates
  std::vector<std::array<std::uint32_t, 3>> triangles;
  std::vector<std::int32_t> triangle_object;
  std::vector<Rgb> object_color;
  std::vector<Rgb> object_emission;
  std::vector<Vec4> light_lifts;  // normalised model points
  std::vector<std::int32_t> light_of_lift;
  std::vector<Rgb> light_radiance;
};

// Read-only strided 2-D view (strides in elements), so that rays need not be copied.
template <class T>
struct Strided2 {
  const T* data;
  std::int64_t row_stride, col_stride;
  T operator()(std::size_t i, std::size_t j) const {
    return data[static_cast<std::int64_t>(i) * row_stride + static_cast<std::int64_t>(j) * col_stride];
  }
};

enum Stop : std::uint8_t { kHit = 0, kDistanceLimit = 1, kCrossingLimit = 2, kCancelled = 3 };

struct TraceOptions {
  double max_distance;
  int max_crossings;
  bool shade;
  bool record_segments;
};

// Caller-allocated per-ray outputs (N rows each).
struct TraceOutputs {
  float* color;       // (N,3)
  double* depth;      // (N,)
  double* position;   // (N,3)
  float* normal;      // (N,3)
  std::int32_t* object;
  std::int32_t* crossings;
  std::uint8_t* stop;
  double* distance;   // geodesic length travelled: depth on a hit, max_distance at the limit
};

struct TraceStats {
  std::uint64_t chords = 0;
  // Recorded chords by chunk of rays, in ray order: 6 doubles each, start xyz and end xyz.
  std::vector<std::vector<double>> segments;
};

class Tracer {
 public:
  // Called on the tracing thread about every 0.1 s with the number of finished rays; returning
  // false stops the workers.
  using Poll = std::function<bool(std::size_t done)>;

  Tracer(SceneData scene, unsigned threads);
  ~Tracer();
  Tracer(const Tracer&) = delete;
  Tracer& operator=(const Tracer&) = delete;

  unsigned num_threads() const { return pool_.size(); }
  std::size_t num_triangles() const { return triangles_.size(); }

  TraceStats trace(std::size_t count, Strided2<double> origins, Strided2<double> directions,
                   const TraceOptions& options, const TraceOutputs& out, const Poll& poll);
  void cancel() { cancel_.store(true); }

  // Bare Embree first hit on chart segments: chord parameter in [0, 1] (inf if none), triangle.
  void query_segments(std::size_t count, Strided2<double> starts, Strided2<double> ends, float* t,
                      std::int32_t* prim);

 private:
  static constexpr int kChartEdge = -2;
  struct Exit {
    Space::Turn turn;
    int face;    // a face, -1 if none lies ahead, or kChartEdge
    bool exact;  // whether turn.t is exact (else an estimate: S3's usual exits)
    // Where nonzero, (cu, su) = (c, s) / r for some r > 0, known before the turn's square root:
    // cu P + su V has the exit point's chart image.
    double cu = 0.0, su = 0.0;
  };
  struct Segment {
    Vec4 P, V;   // start point and unit velocity
    Vec3 x0, x1; // chart endpoints
    Space::Turn turn;  // to x1
    bool exact;        // whether turn.t is exact
    double length() const { return exact ? turn.t : std::atan2(turn.s, turn.c); }
  };
  struct WalkEnd {
    Stop stop;
    double distance;
    int crossings;
  };
  struct EmbreeDeleter {
    void operator()(RTCDevice d) const { rtcReleaseDevice(d); }
    void operator()(RTCScene s) const { rtcReleaseScene(s); }
  };
  using DeviceHandle = std::unique_ptr<RTCDeviceTy, EmbreeDeleter>;
  using SceneHandle = std::unique_ptr<RTCSceneTy, EmbreeDeleter>;

  SceneHandle build_scene(const std::vector<std::uint32_t>& triangle_ids) const;

  Exit find_exit(const Vec4& P, const Vec4& V) const;
  Exit find_exit_exact(const Vec4& P, const Vec4& V) const;
  double scene_escape(const Vec3& x0) const;
  bool may_hit(const Segment& seg) const;
  template <class Query>
  WalkEnd walk(Vec4 P, Vec4 V, double length, int max_crossings, double first_skip,
               Query&& query) const;

  void trace_ray(std::size_t i, const Vec4& origin, const Vec4& direction,
                 const TraceOptions& options, const TraceOutputs& out,
                 std::vector<double>* segments, std::uint64_t& chords) const;
  Rgb illumination(const Vec4& H, const Vec4& N, int max_crossings) const;
  bool visible(const Vec4& H, const Vec4& dir, double r, int max_crossings) const;

  // Runs fn(chunk, begin, end) over [0, count) in chunks on the pool, polling from this thread;
  // returns how many items (a prefix) were done before a stop.
  std::size_t run_chunks(std::size_t count, const std::function<void(std::size_t, std::size_t, std::size_t)>& fn,
                  const Poll& poll, bool cancellable);

  Space space_;
  std::array<std::vector<double>, 4> face_components_;  // covectors by component, for SIMD
  std::vector<Mat4> face_maps_;
  std::vector<Mat4> face_maps_t_;  // the same, column-major, for SIMD
  std::vector<Vec3> vertices_;
  std::vector<std::array<std::uint32_t, 3>> triangles_;
  std::vector<Vec4> triangle_planes_;  // chart plane covectors (n, -n . p0)
  std::vector<std::int32_t> triangle_object_;
  std::vector<Rgb> object_color_;
  std::vector<Rgb> object_emission_;
  std::vector<std::vector<Vec4>> light_lifts_;  // per light
  std::vector<Rgb> light_radiance_;
  Vec3 bounds_lo_{}, bounds_hi_{};  // of the scene's chart coordinates
  double scale_ = 0.0;              // largest extent or coordinate magnitude of the scene
  Vec3 hit_lo_{}, hit_hi_{};        // the bounds widened by may_hit's margin (empty: none)

  DeviceHandle device_;
  SceneHandle scene_;
  SceneHandle occluder_scene_;  // without emissive objects, so that lamps do not shadow their light
  RTCScene occluders_ = nullptr;

  ThreadPool pool_;
  struct RunLock {
    explicit RunLock(Tracer& tracer);
    ~RunLock();
    Tracer& tracer_;
  };
  std::mutex run_mutex_;
  std::atomic<std::thread::id> runner_{};
  std::atomic<bool> cancel_{false};
};

}  // namespace thurston
