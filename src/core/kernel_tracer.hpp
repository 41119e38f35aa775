// The walk and the light, generic over the geometry's kernel (kernel.hpp): KernelTracer<Kernel> is
// the tracer of one geometry. This file holds a ray's walk to its first hit and the surface met
// there; integrator.hpp the light gathered at that hit (direct light, bounces, multiple importance
// sampling). Included by registry.cpp only, which instantiates it per kernel: the unnamed
// namespace keeps each instantiation in that one translation unit, inlined as one whole.
#pragma once

#include <algorithm>
#include <cmath>
#include <optional>
#include <unordered_map>
#include <vector>

#include "bsdf.hpp"
#include "embree.hpp"
#include "kernel.hpp"
#include "scene.hpp"
#include "surface.hpp"
#include "tracer.hpp"
#include "visibility_map.hpp"

namespace thurston {
namespace {

// Geodesics leaving a surface skip this much of the scene's scale at their start (chart length),
// so as not to meet their own triangle: Embree's float vertices are only good to about 1e-7 of it.
constexpr double kSelfSkip = 1e-5;
// The rounding a hit position carries per face crossing (chart units), on top of what a kernel's
// walk reports.
constexpr double kRoundingPerCrossing = 1e-14;

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
    if (!light_lifts_.empty() || !emitters_.triangles.empty())
      kernel_.prepare_light_paths(light_reach_);
    match_emitters();
    // the visibility slots: kArcsPerCopy per copy of each light, then of each emitters' group
    for (const auto& lifts : light_lifts_) {
      light_slots_.push_back(slots_);
      slots_ += kArcsPerCopy * lifts.size();
    }
    for (const auto& copies : emitter_copies_) {
      emitter_slots_.push_back(slots_);
      slots_ += kArcsPerCopy * copies.size();
    }
    frame_lights();
  }

 private:
  using Chord = typename Kernel::Chord;
  // Per chunk, reused from point to point: the buffers of one point's light paths and of an
  // emitter sample's copies (points and their unit normals).
  struct LightBuffers;
  // One geodesic from a shaded point to a light (a point light's copy, or a copy of a point
  // sampled on the emitters) before its shadow walk: `term`, what it brings unshadowed but for the
  // BSDF and the radiance (cos falloff fog, times the cone, or cos' over the sampling density);
  // the emitters' samples' density along it where a bounce may meet the same point (MIS; 0: not
  // weighed); set by choose_light_paths where it samples: `strength`, its unshadowed share of the
  // colour (the selection's weight), and `weight`, 1 / the probability that it is traced (0: not
  // traced; 1 in the exact sum).
  struct Candidate {
    LightPath path;
    const Rgb* radiance;
    double term, strength, sample_density;
    bool emitter;
    std::int32_t slot;  // its visibility slot (-1: none)
    double weight = 1.0;
    // A visibility map's check (map_visibility): the map's answer, the lit share (-1: no check).
    double map_answer = -1.0;
    bool check() const { return map_answer >= 0.0; }
  };
  // A shaded point's candidates for shadow walks, and what the chunk has learnt of their
  // visibility: per slot (a copy of a light, the k-th geodesic to it), a running average of
  // whether the walks from the chunk's previous camera hits were unshadowed (1 until one is
  // traced). The chunk's rays are neighbouring pixels, whose shadows mostly agree.
  struct LightBuffers {
    std::vector<LightPath> paths;
    std::vector<Vec4> lifts, normals;
    std::vector<Candidate> candidates, checks;
    std::vector<std::uint32_t> order;
    std::vector<std::uint8_t> arcs;  // per copy: the geodesics to it met so far
    std::vector<float> visible;      // per visibility slot
  };
  // Slots per copy of a light: its first geodesics (S3's two arcs, the branches of Nil, Sol and
  // SL2~); further ones share the last.
  static constexpr std::size_t kArcsPerCopy = 4;
  // How fast a slot's visibility follows the walks (the weight of the newest), and the least
  // visibility a slot is sampled with (so that a light path learnt shadowed is still traced now
  // and then: the estimate stays unbiased, its weight bounded).
  static constexpr float kVisibilityRate = 0.3f, kLeastVisibility = 0.5f;
  std::vector<std::size_t> light_slots_, emitter_slots_;  // the first slot per light / group
  std::size_t slots_ = 0;
  // The slot of the geodesic to copy `lift` of a light or group whose first slot is `first`,
  // counting the geodesics to each copy in `arcs` (cleared per light or sample).
  static std::int32_t visibility_slot(std::size_t first, std::int32_t lift,
                                      std::vector<std::uint8_t>& arcs) {
    std::uint8_t& k = arcs[std::size_t(lift)];
    const std::size_t arc = std::min<std::size_t>(k, kArcsPerCopy - 1);
    k = std::uint8_t(std::min<std::size_t>(k + 1, kArcsPerCopy));
    return std::int32_t(first + kArcsPerCopy * std::size_t(lift) + arc);
  }

  // The point lights' visibility maps (null: none) and, per light and lift, the light's frame
  // there: the frame at the light's own lift (its copy in the domain), carried by the lift's group
  // element. A light has a map where its copies are given and one of them is the identity.
  std::vector<std::unique_ptr<VisibilityMap>> maps_;
  std::vector<std::int32_t> map_origin_;  // per light: its own lift (-1: none)
  std::vector<std::vector<std::array<Vec4, 3>>> light_frames_;
  // What the maps' texels were traced with: a trace with other options starts them afresh.
  struct MapKey {
    int texels;
    double tolerance, tolerance_per_distance;
    int max_crossings;
    bool skip_empty;
    bool operator==(const MapKey& o) const {
      return texels == o.texels && tolerance == o.tolerance &&
             tolerance_per_distance == o.tolerance_per_distance &&
             max_crossings == o.max_crossings && skip_empty == o.skip_empty;
    }
  };
  MapKey map_key_{};
  // How far the maps' texels are walked: the light reach, or the geodesic loop where shorter (an
  // opaque point's paths end there); longer paths are walked, not looked up.
  double map_length_ = 0.0;

  void frame_lights() {
    const std::size_t lights = light_lifts_.size();
    maps_.resize(lights);
    map_origin_.assign(lights, -1);
    light_frames_.resize(lights);
    for (std::size_t l = 0; l < lights; ++l) {
      const auto& copies = light_copies_[l];
      for (std::size_t k = 0; k < copies.size() && map_origin_[l] < 0; ++k) {
        bool identity = true;
        for (int e = 0; e < 16; ++e)
          identity &= std::abs(copies[k][e] - (e % 5 == 0 ? 1.0 : 0.0)) <= 1e-12;
        if (identity) map_origin_[l] = std::int32_t(k);
      }
      if (map_origin_[l] < 0) continue;
      const Vec4& L = light_lifts_[l][std::size_t(map_origin_[l])];
      Vec4 S = kernel_.chart_tangent(L, {0.0, 0.0, 1.0});
      if (!kernel_.normalise(L, S)) {
        map_origin_[l] = -1;
        continue;
      }
      const Frame f = frame_at(L, S);
      for (const Mat4& M : copies) {
        std::array<Vec4, 3> moved;
        const Vec4 E[3] = {f.T1, f.T2, f.S};
        for (int a = 0; a < 3; ++a) {
          Vec4 X = L;
          moved[a] = E[a];
          kernel_.move(M, X, moved[a]);
        }
        light_frames_[l].push_back(moved);
      }
    }
  }

  void prepare(const TraceOptions& options) override {
    if (!options.shade) return;  // unshaded rays (a render's centre pass and re-trace) need no maps
    const MapKey key{options.visibility_map, options.tolerance, options.tolerance_per_distance,
                     options.max_crossings, options.skip_empty};
    if (key == map_key_) return;
    map_key_ = key;
    const double longest = std::min(light_reach_, geodesic_loop_);
    map_length_ = std::isfinite(longest) ? longest * (1.0 + 1e-9) : options.max_distance;
    for (std::size_t l = 0; l < maps_.size(); ++l)
      maps_[l] = options.visibility_map > 0 && map_origin_[l] >= 0
                     ? std::make_unique<VisibilityMap>(options.visibility_map)
                     : nullptr;
  }

  void trace_range(std::size_t begin, std::size_t end, Strided2<double> origins,
                   Strided2<double> directions, const TraceOptions& options,
                   const TraceOutputs& out, std::vector<double>* segments,
                   TraceStats& stats) const override {
    const WalkContext context = this->context(options);
    LightBuffers buffers;
    if (options.light_budget > 0) buffers.visible.assign(slots_, 1.0f);
    for (std::size_t i = begin; i < end; ++i) {
      const Vec4 o{origins(i, 0), origins(i, 1), origins(i, 2), origins(i, 3)};
      const Vec4 d{directions(i, 0), directions(i, 1), directions(i, 2), directions(i, 3)};
      Random random(options.seed, options.ray_ids ? std::uint64_t(options.ray_ids[i]) : i);
      trace_ray(i, o, d, context, options, out, segments, stats, buffers, random);
    }
  }

  void trace_ray(std::size_t i, const Vec4& origin, const Vec4& direction,
                 const WalkContext& context, const TraceOptions& options, const TraceOutputs& out,
                 std::vector<double>* segments, TraceStats& stats, LightBuffers& buffers,
                 Random& random) const {
    Vec4 P = origin, V = direction;
    if (!kernel_.start(P, V)) {  // no point or no direction: the ray goes nowhere
      out.write_miss(i, kDistanceLimit, 0, 0.0, 0);
      return;
    }
    // The ray's frame about its direction, carried along to tell the normal in it (carried_back).
    const Frame start = frame_at(P, V);
    Vec4 carried[2] = {start.T1, start.T2};
    const Found found = first_hit(context, P, V, options.max_distance, options.max_crossings, 0.0,
                                  segments, carried);
    const WalkEnd& end = found.end;
    const Hit& h = found.hit;
    stats.chords += found.chords;
    if (end.stop != kHit) {
      out.write_miss(i, end.stop, end.crossings, end.distance, found.chords, end.end);
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
      if (context.stopped()) {  // a shadow or bounce walk may have been cut short: the light is not
                                // known
        out.write_miss(i, kCancelled, 0, 0.0, found.chords);
        return;
      }
    }
    const Vec3 back = carried_back(P, V, start, h, surface.S, carried);
    for (int a = 0; a < 3; ++a) {
      out.albedo[3 * i + a] = albedo[a];
      out.carried_normal[3 * i + a] = float(back[a]);
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
  // `carried`: two tangent vectors at P that the walk carries along (or none).
  Found first_hit(const WalkContext& context, const Vec4& P, const Vec4& V, double length,
                  int max_crossings, double first_skip, std::vector<double>* segments,
                  Vec4* carried = nullptr, RTCScene among = nullptr) const {
    Found f;
    RTCScene scene = among ? among : scene_.get();
    embree::FirstHit first;
    const auto query = [&](const Chord& chord, float tnear) {
      ++f.chords;
      if (segments)
        segments->insert(segments->end(), {chord.x0[0], chord.x0[1], chord.x0[2], chord.x1[0],
                                           chord.x1[1], chord.x1[2]});
      first = embree::intersect(scene, embree::chord_ray(chord.x0, chord.x1, tnear));
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
            near = embree::intersect(scene, embree::chord_ray(a, b, 0.0f));
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
    f.end = kernel_.walk(context, P, V, length, max_crossings, first_skip, query, refine, carried);
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
    s.weights =
        Surfaces::barycentric(vertices_[tri[0]], vertices_[tri[1]], vertices_[tri[2]], in_mesh);
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
    std::sort(axes.begin(), axes.end(),
              [&](int a, int b) { return std::abs(n[a]) < std::abs(n[b]); });
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

  // The unit normal S at the hit h carried back to the ray's start (P, V) with `start` (frame_at(P,
  // V)), whose T1 and T2 the walk carried to the hit (`carried`): its component along the ray is
  // kept, and its part across the ray has its components in the carried pair, made orthonormal
  // about the ray's tangent at the hit. Returned as its chart image at P. Exact parallel transport
  // for the projective kernel (vectors normal to a geodesic's plane in the model are parallel along
  // it; the face maps are linear); for the marching kernels the pair keeps its chart components
  // between face maps, an approximation of the turn about the ray.
  Vec3 carried_back(const Vec4& P, const Vec4& V, const Frame& start, const Hit& h, const Vec4& S,
                    const Vec4* carried) const {
    const double along = kernel_.dot(h.X, S, h.V);
    Vec4 E1 = lin4(1.0, carried[0], -kernel_.dot(h.X, carried[0], h.V), h.V);
    if (!kernel_.normalise(h.X, E1)) return Kernel::chart_vector(P, scaled(along, V));
    Vec4 E2 = lin4(1.0, carried[1], -kernel_.dot(h.X, carried[1], h.V), h.V);
    E2 = lin4(1.0, E2, -kernel_.dot(h.X, E2, E1), E1);
    if (!kernel_.normalise(h.X, E2)) return Kernel::chart_vector(P, scaled(along, V));
    const Vec4 back = lin4(1.0, lin4(along, V, kernel_.dot(h.X, S, E1), start.T1),
                           kernel_.dot(h.X, S, E2), start.T2);
    return Kernel::chart_vector(P, back);
  }

  // --- the light at a hit: direct light, path tracing, MIS (defined in integrator.hpp) ---

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
    bool camera_hit;  // the camera ray's (its light paths' visibility is learnt chunk-wide)
    Rgb base;
    Frame frame{};
    std::optional<Bsdf> bsdf;
  };
  Vertex vertex_at(const Vec4& X, const Surface& s, int depth, const TraceOptions& options) const;
  static Rgb diffuse_albedo(const Vertex& v);
  double bounce_density(const Vertex& v, const Vec4& V) const;
  // Multiple importance sampling's power heuristic: the weight of the technique of density a
  // against b (each density times its number of samples).
  static double power_weight(double a, double b) { return a * a / (a * a + b * b); }

  // Russian roulette from this bounce on: a path goes on with probability its throughput's largest
  // channel (at most kSurvival), and its throughput is divided by that.
  static constexpr int kRouletteFrom = 4;
  static constexpr double kSurvival = 0.95;

  Rgb bounce(const WalkContext& context, Vertex v, const TraceOptions& options, TraceStats& stats,
             LightBuffers& buffers, Random& random) const;

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
    Vec4 S = kernel_.plane_normal(
        h.X, placed.from_chart.pull_back({n[0], n[1], n[2], -dot3(n, in_mesh)}));
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

  Reflected illumination(const WalkContext& context, const Vertex& v, const TraceOptions& options,
                         TraceStats& stats, LightBuffers& buffers, Random& random) const;
  bool map_visibility(const Vertex& v, std::size_t light, Candidate& c, Reflected& sum,
                      const TraceOptions& options, TraceStats& stats, LightBuffers& buffers,
                      Random& random) const;
  double map_reach(std::size_t light, const Vec3& u, const TraceOptions& options) const;
  void reflect(Reflected& sum, const Vertex& v, const Vec4& direction, double term,
               const Rgb& radiance) const;

  bool emitter_point(std::size_t t, const Vec3& y, LightBuffers& buffers,
                     double& area_density) const;
  double emitter_density(double area_density, double emitted, const LightPath& path,
                         const TraceOptions& options) const;
  double emitted_cosine(std::size_t t, const Vec4& lift, const Vec4& normal,
                        const Vec4& arrival) const;

  void sample_emitters(const Vertex& v, const TraceOptions& options, TraceStats& stats,
                       LightBuffers& buffers, Random& random) const;
  void choose_light_paths(const Vertex& v, LightBuffers& buffers, int budget, Random& random) const;

  double emission_weight(const Vertex& v, const Vec4& V, double density, double length,
                         const Found& f, const Surface& s, const TraceOptions& options,
                         LightBuffers& buffers) const;
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
      return embree::occluded(blockers, embree::chord_ray(chord.x0, chord.x1, tnear));
    };
    return kernel_
        .walk(context, H, dir, r, max_crossings, kSelfSkip * scale_, query, [](const auto&) {})
        .stop;
  }

  void match_emitters();
  // Corners of a seen triangle and of an emitter's copy are the same point within this (relative
  // to the points' size): both come from the same vertices through a few float64 maps.
  static constexpr double kSamePoint = 1e-7;

  Kernel kernel_;
};

}  // namespace
}  // namespace thurston
