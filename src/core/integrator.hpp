// The light at a hit, for KernelTracer<Kernel> (kernel_tracer.hpp): direct light from the point
// lights and from samples on the emitters (next-event estimation), the bounces of path tracing,
// the multiple importance sampling that weighs the two, and the matching of the emissive triangles
// the walk meets to the emitters sampled. Included by registry.cpp only (see kernel_tracer.hpp).
#pragma once

#include <algorithm>
#include <cmath>
#include <optional>
#include <vector>

#include "kernel_tracer.hpp"

namespace thurston {
namespace {

template <class Kernel>
inline typename KernelTracer<Kernel>::Vertex KernelTracer<Kernel>::vertex_at(
    const Vec4& X, const Surface& s, int depth, const TraceOptions& options) const {
  Vertex v{X,          s.N,    s.S, !s.material->emits(), depth < options.bounces,
           depth == 0, s.base, {},  std::nullopt};
  const Principled& scattering = s.material->scattering;
  if (scattering.glossy()) {
    v.frame = frame_at(X, s.S);
    v.bsdf.emplace(scattering, Color{s.base[0], s.base[1], s.base[2]},
                   local(X, v.frame, scaled(-1.0, s.V)));
  }
  v.bounce_follows |= depth == options.bounces && !emitters_.triangles.empty() &&
                      (options.emitter_sampling == EmitterSampling::kBounces ||
                       (options.emitter_sampling == EmitterSampling::kMis && v.bsdf));
  return v;
}

// What the Lambert part of a vertex's BSDF reflects (of the light summed by illumination's
// `diffuse`): the base colour, dimmed under a glossy material's specular layer.
template <class Kernel>
inline Rgb KernelTracer<Kernel>::diffuse_albedo(const Vertex& v) {
  if (!v.bsdf) return v.base;
  return {float(v.bsdf->diffuse[0]), float(v.bsdf->diffuse[1]), float(v.bsdf->diffuse[2])};
}

// The density (solid angle) with which a bounce leaves the vertex along V: zero below its
// geometric surface (such bounces are absorbed).
template <class Kernel>
inline double KernelTracer<Kernel>::bounce_density(const Vertex& v, const Vec4& V) const {
  if (!(kernel_.dot(v.X, v.N, V) > 0.0)) return 0.0;
  if (v.bsdf) return v.bsdf->density(local(v.X, v.frame, V));
  return std::max(kernel_.dot(v.X, v.S, V), 0.0) / kPi;
}

// The light that options.bounces bounces bring to the camera ray's hit (vertex `v`). Each bounce
// leaves in a direction drawn from the vertex's BSDF (Lambert: cosine-weighted about the shading
// normal, whose density cos / pi cancels the BRDF's, so the throughput takes the albedo; glossy:
// a mixture of that and GGX's visible normals, the throughput f cos / density), its geodesic
// traced as camera rays are, with the fog along it; its hit adds the throughput times the
// emission met there (weighed against the emitters' samples of that geodesic, MIS) and times
// the light its next-event estimate reflects. A bounce beyond the limit (vertex_at) gathers
// emission only.
template <class Kernel>
inline Rgb KernelTracer<Kernel>::bounce(const WalkContext& context, Vertex v,
                                        const TraceOptions& options, TraceStats& stats,
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
      for (int a = 0; a < 3; ++a)
        throughput[a] *= (v.bsdf->diffuse[a] / kPi + f[a]) * wi[2] / density;
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
    // A bounce past the limit only gathers the emission it meets, in the next-event estimates'
    // stead: as far as they reach (the light reach), so that the light a direct-light render
    // gathers is the reach's whatever the material (a glossy layer's bounce to the distance limit
    // met far copies that the estimates leave out: speckles that never cleared).
    const double reach =
        b > options.bounces ? std::min(options.max_distance, light_reach_) : options.max_distance;
    const Found f =
        first_hit(context, v.X, V, reach, options.max_crossings, kSelfSkip * scale_, nullptr);
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

// The direct light at a vertex: every geodesic to every copy of the point lights, and to the
// copies of options.light_samples points sampled on the emitters, gathered as candidates; then
// the shadow walks of those choose_light_paths picks (all of them for the exact sum), each chosen
// one's light weighted by 1 / its probability.
template <class Kernel>
inline typename KernelTracer<Kernel>::Reflected KernelTracer<Kernel>::illumination(
    const WalkContext& context, const Vertex& v, const TraceOptions& options, TraceStats& stats,
    LightBuffers& buffers, Random& random) const {
  const Vec4& H = v.X;
  std::vector<Candidate>& candidates = buffers.candidates;
  candidates.clear();
  buffers.checks.clear();
  Reflected sum;
  std::vector<LightPath>& paths = buffers.paths;
  const bool learn = v.camera_hit && !buffers.visible.empty();
  // an opaque point's paths beyond the geodesic loop pass through it again: not even sought
  const double reach = v.opaque ? std::min(light_reach_, geodesic_loop_) : light_reach_;
  const bool fogged = std::isfinite(options.light_fog);
  for (std::size_t l = 0; l < light_lifts_.size(); ++l) {
    paths.clear();
    stats.light_failures += kernel_.light_paths(H, light_lifts_[l], reach, paths, v.S);
    if (learn) buffers.arcs.assign(light_lifts_[l].size(), 0);
    const Rgb& radiance = light_radiance_[l];
    const SpotCone& cone = light_cone_[l];
    const double mean_radiance = mean_rgb(radiance);
    for (const LightPath& path : paths) {
      const double cosine = kernel_.dot(H, v.S, path.direction);
      if (!(cosine > 0.0)) continue;  // (those a kernel leaves out)
      double weight = path.falloff;
      if (fogged) weight *= std::exp(-path.distance / options.light_fog);
      if (cone.active())
        weight *= cone.attenuation(kernel_.dot(
            light_lifts_[l][path.lift], light_axes_[l][path.lift], kernel_.arrival(H, path)));
      ++stats.light_paths;
      stats.light_energy += weight * mean_radiance;
      if (!(weight > 0.0) || (v.opaque && path.distance > geodesic_loop_)) continue;
      Candidate c{path,
                  &radiance,
                  cosine * weight,
                  0.0,
                  0.0,
                  false,
                  learn ? visibility_slot(light_slots_[l], path.lift, buffers.arcs) : -1};
      if (!map_visibility(v, l, c, sum, options, stats, buffers, random)) candidates.push_back(c);
    }
  }
  if (!emitters_.triangles.empty() && options.emitter_sampling != EmitterSampling::kBounces)
    for (int s = 0; s < options.light_samples; ++s)
      sample_emitters(v, options, stats, buffers, random);
  choose_light_paths(v, buffers, options.light_budget, random);
  candidates.insert(candidates.end(), buffers.checks.begin(), buffers.checks.end());
  for (const Candidate& c : candidates) {
    if (!(c.weight > 0.0) && !c.check()) continue;  // not drawn
    ++stats.shadow_walks;
    // Point lights are hidden by the occluders; an emitter's sample by every triangle, emitters
    // too (so that a closed emitter's far side is hidden by its near side), up to just short of it.
    const Stop stop = c.emitter ? shadow(context, scene_.get(), H, c.path.direction,
                                         c.path.distance * (1.0 - 1e-6) - kSelfSkip * scale_,
                                         options.max_crossings)
                                : shadow(context, occluders_, H, c.path.direction,
                                         c.path.distance * (1.0 - 1e-6), options.max_crossings);
    if (c.slot >= 0) {
      float& seen = buffers.visible[std::size_t(c.slot)];
      seen += kVisibilityRate * ((stop == kHit ? 0.0f : 1.0f) - seen);
    }
    if (c.check()) {  // the map's error on this geodesic: what the walk finds less its answer
      ++stats.map_checks;
      const double error = (stop != kHit ? 1.0 : 0.0) - c.map_answer;
      stats.map_checked_light += c.term * mean_rgb(*c.radiance);
      stats.map_error_light += std::abs(error) * c.term * mean_rgb(*c.radiance);
      continue;
    }
    if (stop == kHit) {
      ++stats.shadowed_walks;
      continue;
    }
    double mis = 1.0;
    // a bounce meets the emitter's point along this geodesic if it is drawn and its walk gets there
    if (c.sample_density > 0.0 && stop != kCrossingLimit && c.path.distance <= options.max_distance)
      mis = power_weight(c.sample_density, bounce_density(v, c.path.direction));
    reflect(sum, v, c.path.direction, c.term * c.weight * mis, *c.radiance);
  }
  return sum;
}

// Where light `light` has a visibility map (visibility_map.hpp), answers candidate c (one of its
// geodesics, unshadowed light c.term) from the map and returns true; false where it has none, or
// where c is longer than the map's walks (then c is walked). The four texels about the geodesic's
// direction at the light each say lit where the first occluder along theirs lies beyond the
// shaded point, less a margin for the texel's offset on the surface (the geodesics' spread over a
// texel, 1 / sqrt(falloff) per radian, times the surface's slope seen from the light, at most 3:
// the least bias measured, a wider margin letting light through occluders just in front, a
// narrower shadowing lit surfaces; tests/render/test_visibility_map.py); the answer m is their
// bilinear mean (percentage-closer filtering: a shadow's edge is
// resolved to the texels, softened across one), and m c.term is added to `sum`. With probability
// options.map_check c is also walked, as a check (buffers.checks): how far the walk's visibility
// is from m, times c's light, is the map's error there (TraceStats), not added to the light.
template <class Kernel>
inline bool KernelTracer<Kernel>::map_visibility(const Vertex& v, std::size_t light, Candidate& c,
                                                 Reflected& sum, const TraceOptions& options,
                                                 TraceStats& stats, LightBuffers& buffers,
                                                 Random& random) const {
  const VisibilityMap* map = maps_[light].get();
  const double d = c.path.distance;
  if (!map || !(c.term > 0.0) || d > map_length_) return false;
  const std::size_t lift = std::size_t(c.path.lift);
  const Vec4& X = light_lifts_[light][lift];
  const std::array<Vec4, 3>& frame = light_frames_[light][lift];
  const Vec4 leaving = kernel_.leaving(v.X, X, c.path);
  const Vec3 u{kernel_.dot(X, frame[0], leaving), kernel_.dot(X, frame[1], leaving),
               kernel_.dot(X, frame[2], leaving)};
  const VisibilityMap::Footprint near = map->footprint(u);
  const double incidence = std::abs(kernel_.dot(v.X, v.N, c.path.direction));
  const double slope = std::min(
      std::sqrt(std::max(1.0 - incidence * incidence, 0.0)) / std::max(incidence, 1e-12), 3.0);
  const double margin = map->spacing() / std::sqrt(c.path.falloff) * slope + 1e-6 * (1.0 + d) +
                        2.0 * kSelfSkip * scale_;
  double m = 0.0;
  for (int k = 0; k < 4; ++k) {
    bool traced;
    const double reach = map->reach(
        near.texel[k], [&](const Vec3& w) { return map_reach(light, w, options); }, traced);
    stats.map_texels += traced;
    if (std::isnan(reach)) return false;  // cancelled: the walk will say so
    if (reach >= d - margin) m += near.weight[k];
  }
  ++stats.map_lookups;
  if (m > 0.0) reflect(sum, v, c.path.direction, c.term * m, *c.radiance);
  if (options.map_check > 0.0 && random.uniform() < options.map_check) {
    c.map_answer = m;
    buffers.checks.push_back(c);
  }
  return true;
}

// The distance from light `light` to the first occluder along the geodesic leaving it in the unit
// direction u of its frame (inf: none within the light reach; NaN: the walk was cancelled).
template <class Kernel>
inline double KernelTracer<Kernel>::map_reach(std::size_t light, const Vec3& u,
                                              const TraceOptions& options) const {
  Vec4 P = light_lifts_[light][std::size_t(map_origin_[light])];
  const std::array<Vec4, 3>& E = light_frames_[light][std::size_t(map_origin_[light])];
  Vec4 V = lin4(1.0, lin4(u[0], E[0], u[1], E[1]), u[2], E[2]);
  if (!kernel_.start(P, V)) return kInf;
  const Found f = first_hit(this->context(options), P, V, map_length_, options.max_crossings, 0.0,
                            nullptr, nullptr, occluders_);
  if (f.end.stop == kCancelled) return kNaN;
  return f.end.stop == kHit ? f.end.distance + f.hit.s : kInf;
}

// Picks the candidates whose shadow walks are traced, with at most `budget` walks (0: all of
// them, each of weight 1: the exact sum). A candidate's weight for the choice is its strength (the
// mean over RGB of the colour it adds unshadowed: the BSDF's diffuse part and its specular part)
// times the visibility its slot has learnt (at least kLeastVisibility; 1 without a slot). Each is
// traced with probability q = min(1, budget' weight / rest): the strongest always (q = 1; budget'
// and rest are what is left of the budget and of the weights after them), the others by one comb
// of budget' evenly spaced teeth, with a random offset, over their weights laid end to end
// (stratified: exactly budget' are traced, each with its own probability q). A traced one's light
// is weighted by 1 / q, so that the sum stays unbiased (q depends on earlier pixels' walks, never
// on its own); a candidate of strength 0 adds nothing and is never traced.
template <class Kernel>
inline void KernelTracer<Kernel>::choose_light_paths(const Vertex& v, LightBuffers& buffers,
                                                     int budget, Random& random) const {
  std::vector<Candidate>& candidates = buffers.candidates;
  if (budget <= 0 || candidates.size() <= std::size_t(budget)) return;
  std::vector<std::uint32_t>& order = buffers.order;
  order.resize(candidates.size());
  const Rgb albedo = diffuse_albedo(v);
  double rest = 0.0;
  for (std::uint32_t i = 0; i < order.size(); ++i) {
    Candidate& c = candidates[i];
    double colour = 0.0;
    for (int a = 0; a < 3; ++a) colour += double(albedo[a]) * (*c.radiance)[a];
    if (v.bsdf) {
      const Color f = v.bsdf->specular(local(v.X, v.frame, c.path.direction));
      for (int a = 0; a < 3; ++a) colour += kPi * f[a] * (*c.radiance)[a];
    }
    c.strength = c.term * colour / 3.0;
    if (c.slot >= 0) c.strength *= std::max(buffers.visible[std::size_t(c.slot)], kLeastVisibility);
    order[i] = i;
    rest += c.strength;
  }
  std::sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) {
    return candidates[a].strength > candidates[b].strength;
  });
  std::size_t k = 0;
  int left = budget;
  for (; k < order.size() && left > 0; ++k, --left) {
    const double strength = candidates[order[k]].strength;
    if (!(left * strength >= rest)) break;
    rest -= strength;  // weight 1: traced always
  }
  if (left == 0 || !(rest > 0.0)) {
    for (; k < order.size(); ++k) candidates[order[k]].weight = 0.0;
    return;
  }
  const double step = rest / left, offset = random.uniform() * step;
  double below = 0.0;  // the weights laid before this candidate
  for (; k < order.size(); ++k) {
    Candidate& c = candidates[order[k]];
    const double above = below + c.strength;
    // a tooth offset + j step in [below, above)
    const bool traced = std::floor((above - offset) / step) > std::floor((below - offset) / step);
    c.weight = traced ? step / c.strength : 0.0;
    below = above;
  }
}

// Adds one geodesic's light (term: everything but the BSDF and the radiance) to the sums.
template <class Kernel>
inline void KernelTracer<Kernel>::reflect(Reflected& sum, const Vertex& v, const Vec4& direction,
                                          double term, const Rgb& radiance) const {
  for (int a = 0; a < 3; ++a) sum.diffuse[a] += float(term * radiance[a]);
  if (!v.bsdf) return;
  const Color f = v.bsdf->specular(local(v.X, v.frame, direction));
  for (int a = 0; a < 3; ++a) sum.specular[a] += float(kPi * f[a] * term * radiance[a]);
}

// A point y of emitter triangle t as the emitters' samples light with it: its point of the
// geometry and unit normal (of the triangle's winding), the metric's area per chart area of the
// triangle there, and in buffers its copies (points and normals), one per group element of the
// emitter's copies. False where the triangle has no normal there.
template <class Kernel>
inline bool KernelTracer<Kernel>::emitter_point(std::size_t t, const Vec3& y, LightBuffers& buffers,
                                                double& area_density) const {
  const std::array<Vec3, 3>& p = emitters_.triangles[t];
  const Vec3 e1 = sub3(p[1], p[0]), e2 = sub3(p[2], p[0]), n = cross3(e1, e2);
  const Vec4 Y = kernel_.chart_point(y);
  Vec4 normal = kernel_.plane_normal(Y, {n[0], n[1], n[2], -dot3(n, p[0])});
  if (!kernel_.normalise(Y, normal)) return false;
  const Vec4 a = kernel_.chart_tangent(Y, e1), b = kernel_.chart_tangent(Y, e2);
  const double ab = kernel_.dot(Y, a, b);
  area_density =
      std::sqrt(std::max(kernel_.dot(Y, a, a) * kernel_.dot(Y, b, b) - ab * ab, 0.0)) / norm3(n);
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
template <class Kernel>
inline double KernelTracer<Kernel>::emitter_density(double area_density, double emitted,
                                                    const LightPath& path,
                                                    const TraceOptions& options) const {
  return options.light_samples / (emitter_area_sum_.back() * area_density * emitted * path.falloff);
}

// Whether an emitter's copy shines towards the far end of a geodesic that arrives there with
// tangent `arrival` (towards its start): cos' at the copy, from its front only where one-sided.
template <class Kernel>
inline double KernelTracer<Kernel>::emitted_cosine(std::size_t t, const Vec4& lift,
                                                   const Vec4& normal, const Vec4& arrival) const {
  const double towards = kernel_.dot(lift, normal, arrival);
  return emitters_.one_sided[t] ? towards : std::abs(towards);
}

// One point y sampled on the emitters (a triangle with probability its share of their chart
// area, y uniform on it in the chart) lights the vertex along the geodesics to its copies as a
// point light of radiance Le cos' / pi per unit area would: the estimate of
// (1 / pi) integral Le cos cos' falloff dA is Le cos cos' falloff dA/dA_chart A_chart / pi, over
// light_samples (cos' at the emitter's copy, towards the vertex: one-sided emitters light only
// their front, the others both sides). Each geodesic becomes a candidate for illumination's
// shadow walks; where a bounce leaves the vertex and could meet the same point along the same
// geodesic, the two estimates are weighed by the power heuristic (the samples' density kept).
template <class Kernel>
inline void KernelTracer<Kernel>::sample_emitters(const Vertex& v, const TraceOptions& options,
                                                  TraceStats& stats, LightBuffers& buffers,
                                                  Random& random) const {
  const Vec4& H = v.X;
  const std::size_t t = pick_emitter(random.uniform());
  const std::array<Vec3, 3>& p = emitters_.triangles[t];
  const double root = std::sqrt(random.uniform()), u = random.uniform();
  const Vec3 y = add3(
      p[0], add3(scaled3(root * (1.0 - u), sub3(p[1], p[0])), scaled3(root * u, sub3(p[2], p[0]))));
  double area_density;
  if (!emitter_point(t, y, buffers, area_density)) return;
  const double scale = area_density * emitter_area_sum_.back() / (kPi * options.light_samples);
  std::vector<LightPath>& paths = buffers.paths;
  paths.clear();
  stats.light_failures += kernel_.light_paths(H, buffers.lifts, light_reach_, paths, v.S);
  const Rgb& radiance = emitters_.radiance[t];
  const double mean_radiance = mean_rgb(radiance);
  const bool weighed = v.bounce_follows && options.emitter_sampling == EmitterSampling::kMis;
  const bool learn = v.camera_hit && !buffers.visible.empty();
  if (learn) buffers.arcs.assign(buffers.lifts.size(), 0);
  for (const LightPath& path : paths) {
    const double emitted = emitted_cosine(t, buffers.lifts[path.lift], buffers.normals[path.lift],
                                          kernel_.arrival(H, path));
    const double weight = path.falloff * std::exp(-path.distance / options.light_fog) * scale;
    const double cosine = kernel_.dot(H, v.S, path.direction);
    if (!(cosine > 0.0)) continue;  // (those a kernel leaves out)
    ++stats.emitter_paths;
    stats.emitter_energy += weight * std::max(emitted, 0.0) * mean_radiance;
    if (!(emitted > 0.0) || (v.opaque && path.distance > geodesic_loop_)) continue;
    buffers.candidates.push_back(
        {path, &radiance, cosine * emitted * weight, 0.0,
         weighed ? emitter_density(area_density, emitted, path, options) : 0.0, true,
         learn ? visibility_slot(emitter_slots_[emitters_.group[t]], path.lift, buffers.arcs)
               : -1});
  }
}

// The MIS weight of the emission that a bounce from vertex v along V (drawn with `density`) met
// at the end of a geodesic of `length` (hit f, surface s): the emitters' samples light the same
// point along this geodesic where it is one of those they sum (within the reach, and found by
// the light search: Sol's may miss one near a caustic), so the two are weighed by the power
// heuristic; 1 where they do not (an emitter beyond the reach lights through bounces alone), 0
// for a triangle not found among the emitters' copies (their samples alone count it).
template <class Kernel>
inline double KernelTracer<Kernel>::emission_weight(const Vertex& v, const Vec4& V, double density,
                                                    double length, const Found& f, const Surface& s,
                                                    const TraceOptions& options,
                                                    LightBuffers& buffers) const {
  if (options.emitter_sampling == EmitterSampling::kBounces) return 1.0;
  const auto match =
      emitter_of_.find(emitter_key(std::size_t(f.placed - instances_.data()), f.prim));
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
  const Vec3 y = add3(scaled3(w[0] / total, p[0]),
                      add3(scaled3(w[1] / total, p[1]), scaled3(w[2] / total, p[2])));
  double area_density;
  if (!emitter_point(t, y, buffers, area_density)) return 1.0;
  std::vector<LightPath>& paths = buffers.paths;
  paths.clear();
  kernel_.light_paths(v.X, buffers.lifts, light_reach_,
                      paths);  // a geodesic missed: not among them
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
  const double emitted = emitted_cosine(t, buffers.lifts[same->lift], buffers.normals[same->lift],
                                        kernel_.arrival(v.X, *same));
  if (!(emitted > 0.0)) return 1.0;
  return power_weight(density, emitter_density(area_density, emitted, *same, options));
}

// Finds, for every emissive triangle the walk can meet (each instance's), the emitter triangle
// it is a copy of: its corners' points equal to those of a group element's copy of the emitter
// triangle (the emitters' copies hold every copy near the domain). Both are compared as the
// kernel's move() leaves points (SL2~'s chart reads its fibre angle back in (-2 pi, 2 pi]).
template <class Kernel>
inline void KernelTracer<Kernel>::match_emitters() {
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
  std::sort(seen.begin(), seen.end(),
            [](const Seen& a, const Seen& b) { return a.corners[0][0] < b.corners[0][0]; });
  const auto size = [](const Vec4& a) {
    return 1.0 + std::max({std::abs(a[0]), std::abs(a[1]), std::abs(a[2]), std::abs(a[3])});
  };
  const auto close = [&](const Vec4& a, const Vec4& b) {
    for (int c = 0; c < 4; ++c)
      if (!(std::abs(a[c] - b[c]) <= kSamePoint * size(a))) return false;
    return true;
  };
  std::vector<std::vector<std::size_t>> of_group(emitter_copies_.size());
  for (std::size_t t = 0; t < emitters_.triangles.size(); ++t)
    of_group[emitters_.group[t]].push_back(t);
  for (std::size_t g = 0; g < of_group.size(); ++g)
    for (const Mat4& M : emitter_copies_[g])
      for (const std::size_t t : of_group[g]) {
        const std::array<Vec4, 3> lifted = moved(M, emitters_.triangles[t]);
        const double x = lifted[0][0], margin = 2.0 * kSamePoint * size(lifted[0]);
        auto it =
            std::lower_bound(seen.begin(), seen.end(), x - margin,
                             [](const Seen& s, double value) { return s.corners[0][0] < value; });
        for (; it != seen.end() && it->corners[0][0] <= x + margin; ++it)
          if (close(it->corners[0], lifted[0]) && close(it->corners[1], lifted[1]) &&
              close(it->corners[2], lifted[2]))
            emitter_of_.emplace(it->key, std::int32_t(t));
      }
  unmatched_emitters_ = seen.size() - emitter_of_.size();
}

}  // namespace
}  // namespace thurston
