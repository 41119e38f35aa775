#include "tracer.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

#if defined(__SSE2__) || defined(_M_X64)
#include <emmintrin.h>  // SSE2: part of the x86-64 baseline
#define THURSTON_SSE2 1
#endif

namespace thurston {
namespace {

constexpr std::size_t kChunk = 1024;                          // rays per unit of work
constexpr std::chrono::milliseconds kPollInterval{100};
constexpr double kH3Reach = 40.0;  // beyond this a Klein chart point is within e^-80 of the sphere
constexpr int kS3Renormalise = 8;

// Y = M X and Yv = M Xv for a column-major M, each row summed left to right like a row-major
// product (the same roundings).
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

RTCRay chord_ray(const Vec3& x0, const Vec3& x1, float tnear) {
  const float org[3] = {float(x0[0]), float(x0[1]), float(x0[2])};
  const float dir[3] = {float(x1[0] - x0[0]), float(x1[1] - x0[1]), float(x1[2] - x0[2])};
  return embree::make_ray(org, dir, tnear, 1.0f);
}

// The outputs of a ray that hit nothing.
void write_miss(const TraceOutputs& out, std::size_t i, Stop stop, int crossings, double distance) {
  for (int a = 0; a < 3; ++a) {
    out.color[3 * i + a] = 0.0f;
    out.position[3 * i + a] = kNaN;
    out.normal[3 * i + a] = float(kNaN);
  }
  out.depth[i] = kInf;
  out.object[i] = -1;
  out.crossings[i] = crossings;
  out.stop[i] = stop;
  out.distance[i] = distance;
}

void check_device(RTCDevice device, const char* what) {
  const RTCError error = rtcGetDeviceError(device);
  if (error != RTC_ERROR_NONE)
    throw std::runtime_error(std::string("Embree failed to ") + what + " (error " +
                             std::to_string(int(error)) + ")");
}

}  // namespace

Tracer::Tracer(SceneData scene, unsigned threads)
    : space_{scene.curvature},
      face_maps_(std::move(scene.face_maps)),
      face_maps_t_(face_maps_.size()),
      vertices_(std::move(scene.vertices)),
      triangles_(std::move(scene.triangles)),
      triangle_object_(std::move(scene.triangle_object)),
      object_color_(std::move(scene.object_color)),
      object_emission_(std::move(scene.object_emission)),
      light_radiance_(std::move(scene.light_radiance)),
      pool_(threads) {
  for (const Vec4& c : scene.face_covectors)
    for (int a = 0; a < 4; ++a) face_components_[a].push_back(c[a]);
  while (face_components_[0].size() % 4 != 0)  // zero covectors: never an exit
    for (int a = 0; a < 4; ++a) face_components_[a].push_back(0.0);
  for (std::size_t e = 0; e < face_maps_.size(); ++e)
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) face_maps_t_[e][4 * c + r] = face_maps_[e][4 * r + c];
  bounds_lo_ = {kInf, kInf, kInf};
  bounds_hi_ = {-kInf, -kInf, -kInf};
  triangle_planes_.reserve(triangles_.size());
  for (const auto& tri : triangles_) {
    const Vec3& p0 = vertices_[tri[0]];
    const Vec3 n = cross3(sub3(vertices_[tri[1]], p0), sub3(vertices_[tri[2]], p0));
    triangle_planes_.push_back({n[0], n[1], n[2], -dot3(n, p0)});
    for (std::uint32_t v : tri)
      for (int a = 0; a < 3; ++a) {
        bounds_lo_[a] = std::min(bounds_lo_[a], vertices_[v][a]);
        bounds_hi_[a] = std::max(bounds_hi_[a], vertices_[v][a]);
      }
  }
  for (int a = 0; a < 3 && !triangles_.empty(); ++a)
    scale_ = std::max({scale_, std::abs(bounds_lo_[a]), std::abs(bounds_hi_[a]),
                       bounds_hi_[a] - bounds_lo_[a]});

  const double margin = 1e-6 * scale_;
  for (int a = 0; a < 3; ++a) {
    // No triangles: an empty range, which no chord meets.
    hit_lo_[a] = triangles_.empty() ? kInf : bounds_lo_[a] - margin;
    hit_hi_[a] = triangles_.empty() ? -kInf : bounds_hi_[a] + margin;
  }

  light_lifts_.resize(light_radiance_.size());
  for (std::size_t k = 0; k < scene.light_lifts.size(); ++k)
    light_lifts_[scene.light_of_lift[k]].push_back(scene.light_lifts[k]);

  device_.reset(rtcNewDevice(nullptr));
  if (!device_) throw std::runtime_error("Embree could not create a device");
  std::vector<std::uint32_t> all(triangles_.size()), casting;
  for (std::uint32_t t = 0; t < all.size(); ++t) {
    all[t] = t;
    const Rgb& e = object_emission_[triangle_object_[t]];
    if (e[0] <= 0.0f && e[1] <= 0.0f && e[2] <= 0.0f) casting.push_back(t);
  }
  scene_ = build_scene(all);
  if (casting.size() == all.size()) {
    occluders_ = scene_.get();
  } else {
    occluder_scene_ = build_scene(casting);
    occluders_ = occluder_scene_.get();
  }
}

Tracer::~Tracer() = default;

// A scene of the given triangles; primitive j of its geometry is triangle_ids[j].
Tracer::SceneHandle Tracer::build_scene(const std::vector<std::uint32_t>& triangle_ids) const {
  RTCDevice device = device_.get();
  SceneHandle scene(rtcNewScene(device));
  check_device(device, "create a scene");
  rtcSetSceneFlags(scene.get(), RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(scene.get(), RTC_BUILD_QUALITY_HIGH);
  if (!triangle_ids.empty()) {
    RTCGeometry geometry = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(
        geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), vertices_.size()));
    auto* indices = static_cast<std::uint32_t*>(
        rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                3 * sizeof(std::uint32_t), triangle_ids.size()));
    if (!vertices || !indices) {
      rtcReleaseGeometry(geometry);
      check_device(device, "allocate geometry buffers");
      throw std::runtime_error("Embree failed to allocate geometry buffers");
    }
    for (std::size_t v = 0; v < vertices_.size(); ++v)
      for (int a = 0; a < 3; ++a) vertices[3 * v + a] = float(vertices_[v][a]);
    for (std::size_t j = 0; j < triangle_ids.size(); ++j)
      for (int a = 0; a < 3; ++a) indices[3 * j + a] = triangles_[triangle_ids[j]][a];
    rtcSetGeometryBuildQuality(geometry, RTC_BUILD_QUALITY_HIGH);
    rtcCommitGeometry(geometry);
    rtcAttachGeometry(scene.get(), geometry);
    rtcReleaseGeometry(geometry);
  }
  rtcCommitScene(scene.get());
  check_device(device, "build the scene");
  return scene;
}

// The face through which the geodesic leaves the domain first (lowest index on ties). In S3 the
// edge of the gnomonic chart's hemisphere X[3] > 0 competes as a pseudo-face (it loses ties): a
// valid domain is left through a face before it, and chords must stop (just) short of it. In S3
// the turn of a usual exit (exact == false) has exact cosine and sine but an estimated t.
Tracer::Exit Tracer::find_exit(const Vec4& P, const Vec4& V) const {
  // Blocks of faces on the stack, each pass a simple loop that the compiler vectorises; the face
  // arrays are padded with zero covectors (never an exit) to a multiple of 4.
  constexpr std::size_t kBlock = 16;
  const std::size_t faces = face_components_[0].size();
  const double *c0 = face_components_[0].data(), *c1 = face_components_[1].data(),
               *c2 = face_components_[2].data(), *c3 = face_components_[3].data();
  double best = kInf, best_a = 0.0, best_b = 0.0;
  int face = -1;
  for (std::size_t begin = 0; begin < faces; begin += kBlock) {
    const std::size_t n = std::min(kBlock, faces - begin);
    double a[kBlock], b[kBlock], key[kBlock];
    for (std::size_t g = 0; g < n; g += 4)
      for (std::size_t j = g; j < g + 4; ++j) {
        const std::size_t f = begin + j;
        a[j] = c0[f] * P[0] + c1[f] * P[1] + c2[f] * P[2] + c3[f] * P[3];
        b[j] = c0[f] * V[0] + c1[f] * V[1] + c2[f] * V[2] + c3[f] * V[3];
      }
    space_.exit_keys(a, b, key, n);
    // The block's least key and its first index, branch-free in 4 lanes (face j in lane j % 4).
    double lane_key[4] = {kInf, kInf, kInf, kInf}, lane_index[4] = {-1.0, -1.0, -1.0, -1.0};
    for (std::size_t g = 0; g < n; g += 4)
      for (std::size_t l = 0; l < 4; ++l) {
        const bool less = key[g + l] < lane_key[l];
        lane_key[l] = less ? key[g + l] : lane_key[l];
        lane_index[l] = less ? double(g + l) : lane_index[l];
      }
    for (std::size_t l = 0; l < 4; ++l) {
      const double j = lane_index[l];
      if (lane_key[l] < best || (lane_key[l] == best && j >= 0.0 && int(begin) + int(j) < face)) {
        best = lane_key[l];
        face = int(begin) + int(j);
        best_a = a[std::size_t(j)];
        best_b = b[std::size_t(j)];
      }
    }
  }
  if (space_.k > 0) {
    if (best == kInf) return find_exit_exact(P, V);  // no usual exit: only the general search
    if (space_.exit_key(-P[3], -V[3]) < best) {
      if (P[3] > 0.0) return {space_.s3_exit_turn(-P[3], -V[3]), kChartEdge, false, -V[3], P[3]};
      return {space_.exit_turn(-P[3], -V[3]), kChartEdge, true};
    }
    if (best == -kInf) return {{0.0, 1.0, 0.0}, face, true};
    return {space_.s3_exit_turn(best_a, best_b), face, false, best_b, -best_a};
  }
  if (face < 0) return {{kInf, 0.0, 0.0}, -1, true};
  if (space_.k < 0 && best_a <= 0.0)  // H3: (c, s) = (b, -a) / sqrt((b - a) (b + a))
    return {space_.exit_turn(best_a, best_b), face, true, best_b, -best_a};
  return {space_.exit_turn(best_a, best_b), face, true};
}

// S3's exit search for the unusual case of no exit in [0, pi): exact turns, keys in [0, 3).
Tracer::Exit Tracer::find_exit_exact(const Vec4& P, const Vec4& V) const {
  const std::size_t faces = face_components_[0].size();
  double best = kInf, best_a = 0.0, best_b = 0.0;
  int face = -1;
  for (std::size_t f = 0; f < faces; ++f) {
    const double a = face_components_[0][f] * P[0] + face_components_[1][f] * P[1] +
                     face_components_[2][f] * P[2] + face_components_[3][f] * P[3];
    const double b = face_components_[0][f] * V[0] + face_components_[1][f] * V[1] +
                     face_components_[2][f] * V[2] + face_components_[3][f] * V[3];
    const double order = space_.exit_order(a, b);
    if (order < best) {
      best = order;
      best_a = a;
      best_b = b;
      face = int(f);
    }
  }
  if (space_.exit_order(-P[3], -V[3]) < best)
    return {space_.exit_turn(-P[3], -V[3]), kChartEdge, true};
  if (face < 0) return {{kInf, 0.0, 0.0}, -1, true};
  return {space_.exit_turn(best_a, best_b), face, true};
}

// E3 only: a chord from x0 longer than this leaves the scene's bounding ball for good.
double Tracer::scene_escape(const Vec3& x0) const {
  if (space_.k != 0) return kInf;
  if (triangles_.empty()) return 0.0;
  Vec3 centre, half;
  for (int a = 0; a < 3; ++a) {
    centre[a] = 0.5 * (bounds_lo_[a] + bounds_hi_[a]);
    half[a] = 0.5 * (bounds_hi_[a] - bounds_lo_[a]);
  }
  const Vec3 d = sub3(x0, centre);
  return (std::sqrt(dot3(d, d)) + std::sqrt(dot3(half, half))) * 1.001;
}

// Whether the chord's bounding box meets the scene's; also keeps non-finite or float-overflowing
// chords away from Embree.
bool Tracer::may_hit(const Segment& seg) const {
  bool ok = true;
  for (int a = 0; a < 3; ++a) {
    const double u = seg.x0[a], v = seg.x1[a];
    ok &= std::abs(u) < 1e30 && std::abs(v) < 1e30;
    ok &= !(std::max(u, v) < hit_lo_[a]) && !(std::min(u, v) > hit_hi_[a]);
  }
  return ok;
}

namespace {

// The geodesic length travelled across a walk's crossings. Exact turns add up as numbers; S3's
// usual turns, whose t is only estimated, multiply as unit complex numbers (cos t, sin t), which
// fixes their sum modulo 2 pi, and the sum of the estimates picks the multiple of 2 pi (it is off by
// at most kFold * kTurnEstimateError, far below pi) and bounds the total from above.
class Odometer {
 public:
  void add_exact(double t) { exact_ += t; }
  void add_turn(const Space::Turn& u) {
    const double c = c_ * u.c - s_ * u.s, s = s_ * u.c + c_ * u.s;
    c_ = c;
    s_ = s;
    estimate_ += u.t;
    if (++turns_ == kFold) fold();
  }
  // An upper bound of the distance after one more estimated turn of `t`.
  double upper_after(double t) const {
    return exact_ + estimate_ + t + (turns_ + 1) * Space::kTurnEstimateError;
  }
  double value() const {
    if (turns_ == 0) return exact_;
    const double theta = std::atan2(s_, c_);
    const double wraps = std::nearbyint((estimate_ - theta) * (0.5 / kPi));
    return exact_ + (theta + 2.0 * kPi * wraps);
  }

 private:
  static constexpr int kFold = 1024;
  void fold() {
    exact_ = value();
    c_ = 1.0;
    s_ = estimate_ = 0.0;
    turns_ = 0;
  }
  double exact_ = 0.0, c_ = 1.0, s_ = 0.0, estimate_ = 0.0;
  int turns_ = 0;
};

}  // namespace

// Follows the geodesic (P, V) for `length` through the domain and its face pairings, calling
// query(segment, tnear) on each chart chord that may meet the scene until it reports a hit. The
// first chord skips its first `first_skip` of chart length (shadow rays leaving a surface).
template <class Query>
Tracer::WalkEnd Tracer::walk(Vec4 P, Vec4 V, double length, int max_crossings,
                             double first_skip, Query&& query) const {
  Odometer odometer;
  int crossings = 0;
  for (bool first = true;; first = false) {
    Exit exit = find_exit(P, V);
    // Whether the walk crosses the exit face within its length: an estimated turn decides from
    // the odometer's bound while that is clear of the length, else from the exact numbers.
    bool crosses;
    double dist = kNaN;  // the distance before this step, where computed
    if (exit.face >= 0 && !exit.exact && odometer.upper_after(exit.turn.t) <= length) {
      crosses = true;
    } else {
      if (!exit.exact) {
        exit.turn.t = std::atan2(exit.turn.s, exit.turn.c);
        exit.exact = true;
      }
      dist = odometer.value();
      // How far the chart can follow the geodesic: S3 to its hemisphere's edge, H3 until the
      // point is indistinguishable from the sphere at infinity.
      const double reach = exit.face == kChartEdge ? exit.turn.t * (1.0 - 1e-6)
                           : space_.k < 0              ? kH3Reach
                                                       : kInf;
      const double limit = std::min(length - dist, reach);
      crosses = exit.face >= 0 && exit.turn.t <= limit;
      // A ray that leaves no face ends in this copy; nothing lies beyond the scene's extent.
      if (!crosses) {
        exit.turn = space_.turn(std::min(limit, scene_escape(Space::chart(P))));
        exit.cu = exit.su = 0.0;
      }
    }
    const Space::Turn& u = exit.turn;
    Vec4 X, Xv;
    space_.advance(P, V, u, X, Xv);
    if (u.t > 0.0) {
      // The chord's end from (cu, su) where known, so that Embree need not wait for the turn.
      const Vec3 x1 = exit.cu != 0.0 || exit.su != 0.0
                          ? Space::chart(lin4(exit.cu, P, exit.su, V))
                          : Space::chart(X);
      const Segment seg{P, V, Space::chart(P), x1, u, exit.exact};
      const Vec3 d = sub3(seg.x1, seg.x0);
      const double tnear = first ? first_skip / std::sqrt(dot3(d, d)) : 0.0;
      if (tnear < 1.0 && may_hit(seg) && query(seg, float(tnear)))
        return {kHit, std::isnan(dist) ? odometer.value() : dist, crossings};
    }
    if (!crosses) return {kDistanceLimit, length, crossings};
    if (exit.exact)
      odometer.add_exact(u.t);
    else
      odometer.add_turn(u);
    if (crossings == max_crossings) return {kCrossingLimit, odometer.value(), crossings};
    ++crossings;
    mat_vec2(face_maps_t_[exit.face], X, Xv, P, V);
    // S3's pairings are rotations and its turns unit complex numbers, so (P, V) stays orthonormal
    // to a few roundings per crossing; the exit points lie on the face planes whatever the scale.
    // Projecting back every kS3Renormalise crossings keeps the drift below 1e-14.
    if ((space_.k <= 0 || crossings % kS3Renormalise == 0) && !space_.renormalise(P, V))
      return {kDistanceLimit, odometer.value(), crossings};
  }
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

TraceStats Tracer::trace(std::size_t count, Strided2<double> origins, Strided2<double> directions,
                         const TraceOptions& options, const TraceOutputs& out, const Poll& poll) {
  const RunLock lock(*this);
  cancel_.store(false);
  const std::size_t chunks = (count + kChunk - 1) / kChunk;
  // Kept by chunk, so that the recording does not depend on the thread count.
  std::vector<std::vector<double>> chunk_segments(options.record_segments ? chunks : 0);
  std::atomic<std::uint64_t> chords{0};
  const std::size_t traced = run_chunks(
      count,
      [&](std::size_t chunk, std::size_t begin, std::size_t end) {
        std::vector<double>* segments = options.record_segments ? &chunk_segments[chunk] : nullptr;
        std::uint64_t local_chords = 0;
        for (std::size_t i = begin; i < end; ++i) {
          const Vec4 o{origins(i, 0), origins(i, 1), origins(i, 2), origins(i, 3)};
          const Vec4 d{directions(i, 0), directions(i, 1), directions(i, 2), directions(i, 3)};
          trace_ray(i, o, d, options, out, segments, local_chords);
        }
        chords.fetch_add(local_chords);
      },
      poll, true);
  for (std::size_t i = traced; i < count; ++i) write_miss(out, i, kCancelled, 0, 0.0);
  return {chords.load(), std::move(chunk_segments)};
}

void Tracer::trace_ray(std::size_t i, const Vec4& origin, const Vec4& direction,
                       const TraceOptions& options, const TraceOutputs& out,
                       std::vector<double>* segments, std::uint64_t& chords) const {
  Vec4 P = origin, V = direction;
  if (!space_.renormalise(P, V)) {  // no point or no direction: the ray goes nowhere
    write_miss(out, i, kDistanceLimit, 0, 0.0);
    return;
  }
  int prim = -1;
  float hit_u = 0.0f;
  Segment hit{};
  const auto query = [&](const Segment& seg, float tnear) {
    ++chords;
    if (segments) segments->insert(segments->end(), {seg.x0[0], seg.x0[1], seg.x0[2],
                                                     seg.x1[0], seg.x1[1], seg.x1[2]});
    prim = embree::intersect(scene_.get(), chord_ray(seg.x0, seg.x1, tnear), hit_u);
    if (prim < 0) return false;
    hit = seg;
    return true;
  };
  const WalkEnd end = walk(P, V, options.max_distance, options.max_crossings, 0.0, query);
  if (end.stop != kHit) {
    write_miss(out, i, end.stop, end.crossings, end.distance);
    return;
  }
  out.stop[i] = kHit;
  out.crossings[i] = end.crossings;

  // Refine Embree's float hit on the triangle's plane in double precision; keep Embree's
  // parameter where the chord grazes the plane and the double solution is meaningless.
  const Vec4& plane = triangle_planes_[prim];
  const Vec3 n{plane[0], plane[1], plane[2]};
  const Vec3 d = sub3(hit.x1, hit.x0);
  double u = hit_u;
  const double denom = dot3(n, d);
  if (std::abs(denom) > 1e-9 * std::sqrt(dot3(n, n) * dot3(d, d))) {
    const double refined = -(dot3(n, hit.x0) + plane[3]) / denom;
    if (refined > -1e-3 && refined < 1.0 + 1e-3) u = refined;
  }
  u = std::clamp(u, 0.0, 1.0);
  const Vec3 xh{hit.x0[0] + u * d[0], hit.x0[1] + u * d[1], hit.x0[2] + u * d[2]};
  const Vec4 H = space_.model(xh);
  const double s = std::clamp(space_.arclength(hit.P, hit.V, H), 0.0, hit.length());
  out.depth[i] = end.distance + s;
  out.distance[i] = out.depth[i];

  // Unit normal at H facing the incoming ray.
  Vec4 on_ray, incoming;
  space_.advance(hit.P, hit.V, space_.turn(s), on_ray, incoming);
  Vec4 N = space_.tangent_part(H, space_.plane_normal(plane));
  if (!space_.normalise(N)) N = scaled(-1.0, incoming);  // degenerate triangle
  if (space_.inner(N, incoming) > 0.0) N = scaled(-1.0, N);
  const Vec3 chart_normal = Space::chart_vector(H, N);

  const std::int32_t object = triangle_object_[prim];
  const Rgb& base = object_color_[object];
  const Rgb& emission = object_emission_[object];
  Rgb light{1.0f, 1.0f, 1.0f};
  if (options.shade) light = illumination(H, N, options.max_crossings);
  for (int a = 0; a < 3; ++a) {
    out.position[3 * i + a] = xh[a];
    out.normal[3 * i + a] = float(chart_normal[a]);
    out.color[3 * i + a] = (options.shade ? emission[a] : 0.0f) + base[a] * light[a];
  }
  out.object[i] = object;
}

// Sum over lights of radiance * cos * falloff * visibility at the surface point H with normal N,
// each light seen at its nearest lift.
Rgb Tracer::illumination(const Vec4& H, const Vec4& N, int max_crossings) const {
  Rgb sum{0.0f, 0.0f, 0.0f};
  for (std::size_t l = 0; l < light_lifts_.size(); ++l) {
    const Vec4* nearest = nullptr;
    double r = kInf;
    for (const Vec4& L : light_lifts_[l]) {
      const double dl = space_.distance(H, L);
      if (dl < r) {
        r = dl;
        nearest = &L;
      }
    }
    if (!nearest) continue;
    Vec4 dir = space_.toward(H, *nearest);
    if (!space_.normalise(dir)) continue;  // light on the surface point (or antipodal in S3)
    const double cosine = space_.inner(N, dir);
    if (!(cosine > 0.0) || !visible(H, dir, r, max_crossings)) continue;
    const double weight = cosine * space_.falloff(r);
    for (int a = 0; a < 3; ++a) sum[a] += float(weight * light_radiance_[l][a]);
  }
  return sum;
}

// Whether the geodesic from the surface point H along dir reaches distance r unobstructed. A
// shadow ray that runs out of crossings found no blocker and counts as visible.
bool Tracer::visible(const Vec4& H, const Vec4& dir, double r, int max_crossings) const {
  const auto query = [&](const Segment& seg, float tnear) {
    return embree::occluded(occluders_, chord_ray(seg.x0, seg.x1, tnear));
  };
  // Embree's float vertices are only good to about 1e-7 of the scene's scale.
  return walk(H, dir, r * (1.0 - 1e-6), max_crossings, 1e-5 * scale_, query).stop != kHit;
}

void Tracer::query_segments(std::size_t count, Strided2<double> starts, Strided2<double> ends,
                            float* t, std::int32_t* prim) {
  const RunLock lock(*this);
  run_chunks(
      count,
      [&](std::size_t, std::size_t begin, std::size_t end) {
        for (std::size_t i = begin; i < end; ++i) {
          const Vec3 x0{starts(i, 0), starts(i, 1), starts(i, 2)};
          const Vec3 x1{ends(i, 0), ends(i, 1), ends(i, 2)};
          float u = 0.0f;
          prim[i] = embree::intersect(scene_.get(), chord_ray(x0, x1, 0.0f), u);
          t[i] = prim[i] < 0 ? std::numeric_limits<float>::infinity() : u;
        }
      },
      nullptr, false);
}

std::size_t Tracer::run_chunks(std::size_t count,
                        const std::function<void(std::size_t, std::size_t, std::size_t)>& fn,
                        const Poll& poll, bool cancellable) {
  const std::size_t chunks = (count + kChunk - 1) / kChunk;
  std::atomic<std::size_t> next{0}, done{0};
  std::atomic<bool> stop{false};
  if (poll && !poll(0)) stop = true;
  const std::function<void()> task = [&] {
    try {
      while (!stop.load() && !(cancellable && cancel_.load())) {
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
  while (!pool_.wait_for(kPollInterval))
    if (poll && !stop.load() && !poll(done.load())) stop = true;
  if (pool_.error()) std::rethrow_exception(pool_.error());
  if (poll && !stop.load()) poll(done.load());  // the final count
  // Chunks are handed out in order and every chunk taken is finished.
  return std::min(count, std::min(next.load(), chunks) * kChunk);
}

}  // namespace thurston
