// The Python Tracer: a compiled scene's tracer, its trace() with numpy outputs and the GIL released
// around the walk, cancel() and the bare Embree query.
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>

#include <algorithm>
#include <exception>
#include <iterator>
#include <limits>
#include <string>
#include <type_traits>
#include <utility>

#include "bind.hpp"
#include "registry.hpp"
#include "scene_record.hpp"

namespace thurston::bindings {

namespace {

// The Python Tracer: the geometry's tracer behind one handle.
struct TracerHandle {
  std::unique_ptr<Tracer> tracer;
  std::string geometry;
};

// A visibility map's texels per cube-face edge at most (6 * 4096^2 floats: 400 MB per light).
constexpr int kMaxMapTexels = 4096;

nb::dict trace(TracerHandle& handle, const Array& origins, const Array& directions,
               double max_distance, int max_crossings, bool shade, nb::object progress,
               bool record_segments, double tolerance, double tolerance_per_distance,
               bool skip_empty, double fog, int light_samples, std::uint64_t seed, int bounces,
               const std::string& emitter_sampling, int light_budget, const OptionalArray& ray_ids,
               int visibility_map, double map_check) {
  if (visibility_map < 0 || visibility_map > kMaxMapTexels)
    throw nb::value_error(("visibility_map must be texels per cube-face edge from 0 (none) to " +
                           std::to_string(kMaxMapTexels))
                              .c_str());
  if (!(map_check >= 0.0 && map_check <= 1.0))
    throw nb::value_error("map_check must be a probability in [0, 1]");
  if (light_budget < 0)
    throw nb::value_error("light_budget must be >= 0 (0: every geodesic to every light)");
  if (light_samples < 1) throw nb::value_error("light_samples must be >= 1");
  const char* const sampling_names[] = {"mis", "light", "bounce"};
  const auto sampling =
      std::find(std::begin(sampling_names), std::end(sampling_names), emitter_sampling);
  if (sampling == std::end(sampling_names))
    throw nb::value_error(
        ("emitter_sampling must be 'mis', 'light' or 'bounce', got '" + emitter_sampling + "'")
            .c_str());
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
  std::vector<std::int64_t> ids;
  if (ray_ids) {
    check<std::int64_t>(*ray_ids, "ray_ids", {std::int64_t(n)}, "(N,) like the rays");
    const Strided2<std::int64_t> v = view2<std::int64_t>(*ray_ids);
    ids.resize(n);
    for (std::size_t i = 0; i < n; ++i) ids[i] = v(i, 0);
  }

  std::unique_ptr<float[]> color(new float[3 * n]), normal(new float[3 * n]),
      albedo(new float[3 * n]), carried_normal(new float[3 * n]);
  std::unique_ptr<double[]> depth(new double[n]), position(new double[3 * n]),
      distance(new double[n]), error(new double[n]), end(new double[3 * n]);
  std::unique_ptr<std::int32_t[]> object(new std::int32_t[n]), crossings(new std::int32_t[n]),
      chords(new std::int32_t[n]);
  std::unique_ptr<std::uint8_t[]> stop(new std::uint8_t[n]);
  const TraceOutputs out{color.get(),         depth.get(),     position.get(), normal.get(),
                         object.get(),        crossings.get(), stop.get(),     distance.get(),
                         chords.get(),        error.get(),     end.get(),      albedo.get(),
                         carried_normal.get()};
  const TraceOptions options{max_distance,  max_crossings,
                             shade,         record_segments,
                             tolerance,     tolerance_per_distance,
                             skip_empty,    fog,
                             light_samples, seed,
                             bounces,       EmitterSampling(sampling - std::begin(sampling_names)),
                             light_budget,  visibility_map,
                             map_check,     ids.empty() ? nullptr : ids.data()};

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
  result["albedo"] = to_numpy(std::move(albedo), {n, 3});
  result["carried_normal"] = to_numpy(std::move(carried_normal), {n, 3});
  const auto scalar = [&](const char* name, auto value) {
    using T = std::conditional_t<std::is_floating_point_v<decltype(value)>, double, std::int64_t>;
    std::unique_ptr<T[]> one(new T[1]{T(value)});
    result[name] = to_numpy(std::move(one), {});
  };
  scalar("chords", stats.chords);
  scalar("light_failures", stats.light_failures);
  scalar("light_paths", stats.light_paths);
  scalar("light_energy", stats.light_energy);
  scalar("emitter_paths", stats.emitter_paths);
  scalar("emitter_energy", stats.emitter_energy);
  scalar("bounce_paths", stats.bounce_paths);
  scalar("emitter_hits", stats.emitter_hits);
  scalar("shadow_walks", stats.shadow_walks);
  scalar("shadowed_walks", stats.shadowed_walks);
  scalar("map_lookups", stats.map_lookups);
  scalar("map_checks", stats.map_checks);
  scalar("map_texels", stats.map_texels);
  scalar("map_checked_light", stats.map_checked_light);
  scalar("map_error_light", stats.map_error_light);
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
    handle.tracer->query_segments(n, view2<double>(starts), view2<double>(ends), t.get(),
                                  prim.get(), instance.get());
  }
  return nb::make_tuple(to_numpy(std::move(t), {n}), to_numpy(std::move(prim), {n}),
                        to_numpy(std::move(instance), {n}));
}

const char* const kTracerDoc =
    R"(Ray tracer for inside views of quotient manifolds of Thurston's geometries.

Tracer(scene, threads=0): the compiled scene (a thurston_core.Scene), checked as it is taken:
every array as it is (no conversion); wrong dtypes, shapes, indices or values raise ValueError
naming the array. threads: worker threads, 0 for one per hardware thread (ThreadStartError where
the system cannot start them all).)";

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
light_budget: shadow walks per shaded point for direct light: the geodesics to the lights'
copies and to the emitters' samples are weighed by their unshadowed light, the strongest traced
always and the rest sampled in proportion to it (one stratified draw), each traced one weighted by
1 / its probability (unbiased); 0: every geodesic is traced (the exact sum).
visibility_map: texels per cube-face edge of each point light's visibility map (0: none; from
1 to 4096): the first occluder's distance from the light along the geodesic leaving it in each
texel's direction, traced on first use and kept across traces with the same tolerances and
crossing limit. A point light's geodesic from a shaded point is answered by the four texels about
its direction at the light (the share of them that reach the point, bilinearly weighted) instead
of a shadow walk. map_check: the probability that an answered geodesic is walked too, to measure
the map's error (map_checked_light, map_error_light; the light is the map's).
ray_ids: int64 (N,), the index each ray's random numbers are drawn for (so that a subset of a
larger trace's rays, as adaptive sampling traces, draws what they drew there); None: its position.
progress(done, total) is called about every 0.1 s (and at the start and end); returning False
stops the trace like cancel(). Returns a dict of:
color float32 (N,3), depth float64 (N,) (inf: no hit), position float64 (N,3) chart point of the
hit (NaN: none), normal float32 (N,3) unit chart normal facing the ray (NaN: none), object int32
(N,) (-1: none), crossings int32 (N,), stop uint8 (N,) (0 hit, 1 distance limit, 2 crossing
limit, 3 cancelled), distance float64 (N,) geodesic length travelled, ray_chords int32 (N,)
Embree queries of each ray, error float64 (N,) an upper estimate of the hit position's error
(chart units: the path's distance from the true geodesic over the cosine of incidence; NaN: no
hit), end float64 (N,3) the chart point where the ray stopped (the hit, the point at the distance
or crossing limit, inside the domain; NaN where there is none), albedo float32 (N,3) the hit's diffuse albedo (the
base colour there, textures included, dimmed under a glossy layer as the shading has it; 0: no
hit), carried_normal float32 (N,3) the hit's shading normal carried back along the ray to its
origin, as its chart image there (unit in the chart; exact parallel transport in E3, S3 and H3,
an approximation of the turn about the ray in the marching geometries; 0: no hit), chords int64 () Embree queries of primary rays in all, light_failures int64 () light
paths known to be missed (Sol's shooting: seeds that did not converge), light_paths int64 () geodesics to lights summed
at the shaded points (those arriving at their front), light_energy float64 () their mean radiance times falloff (times fog: light
falls to 1/e over `fog` of its path) summed before cosines and shadows, emitter_paths int64 ()
and emitter_energy float64 () the same for the emitters' samples (their energy: mean radiance
times the emitter's cosine times falloff over the sampling density), bounce_paths int64 ()
geodesics traced for bounces, shadow_walks int64 () shadow walks traced for direct light,
shadowed_walks int64 () those of them that met a blocker, map_lookups int64 () point lights'
geodesics looked up in visibility maps, map_checks int64 () of them those walked as checks,
map_texels int64 () texels traced, map_checked_light float64 () the checked geodesics'
unshadowed light (mean radiance times falloff, cosine, fog and cone) and map_error_light float64
() its part that the map answered wrongly (times |visibility walked - map's answer|),
emitter_hits int64 () bounces that met an emitter and added its
light, and with record_segments segment_starts /
segment_ends float64 (S,3), the chart endpoints of the queries.)";

}  // namespace

void bind_tracer(nb::module_& m) {
  nb::class_<TracerHandle>(m, "Tracer", kTracerDoc)
      .def(
          "__init__",
          [](TracerHandle* self, const SceneRecord& scene, int threads) {
            if (threads < 0)
              throw nb::value_error("threads must be >= 0 (0: all hardware threads)");
            new (self) TracerHandle{
                make_tracer(scene.geometry, scene_from_record(scene), unsigned(threads)),
                scene.geometry};
          },
          nb::arg("scene"), nb::arg("threads") = 0)
      .def("trace", &trace,
           nb::sig("def trace(self, origins: numpy.ndarray, directions: numpy.ndarray, "
                   "max_distance: float, max_crossings: int, shade: bool = True, "
                   "progress: collections.abc.Callable[[int, int], bool | None] | None = None, "
                   "record_segments: bool = False, tolerance: float = 1e-3, "
                   "tolerance_per_distance: float = 0.0, skip_empty: bool = True, "
                   "fog: float = float('inf'), light_samples: int = 1, seed: int = 0, "
                   "bounces: int = 0, emitter_sampling: str = 'mis', light_budget: int = 0, "
                   "ray_ids: numpy.ndarray | None = None, visibility_map: int = 0, "
                   "map_check: float = 0.0) -> "
                   "dict[str, numpy.ndarray]"),
           nb::arg("origins").noconvert(), nb::arg("directions").noconvert(),
           nb::arg("max_distance"), nb::arg("max_crossings"), nb::arg("shade") = true,
           nb::arg("progress").none() = nb::none(), nb::arg("record_segments") = false,
           nb::arg("tolerance") = 1e-3, nb::arg("tolerance_per_distance") = 0.0,
           nb::arg("skip_empty") = true, nb::arg("fog") = kInf, nb::arg("light_samples") = 1,
           nb::arg("seed") = 0, nb::arg("bounces") = 0, nb::arg("emitter_sampling") = "mis",
           nb::arg("light_budget") = 0, nb::arg("ray_ids").noconvert().none() = nb::none(),
           nb::arg("visibility_map") = 0, nb::arg("map_check") = 0.0, kTraceDoc)
      .def(
          "cancel", [](TracerHandle& t) { t.tracer->cancel(); },
          "Stops a running trace(); callable from any Python thread.")
      .def("query_segments", &query_segments,
           nb::sig("def query_segments(self, starts: numpy.ndarray, ends: numpy.ndarray) -> "
                   "tuple[numpy.ndarray, numpy.ndarray, numpy.ndarray]"),
           nb::arg("starts").noconvert(), nb::arg("ends").noconvert(),
           "Bare Embree first hit of the chart "
           "segments (float64 (N,3) each) on the same BVH and threads: chord parameter t float32 "
           "(N,) in [0, 1] (inf: none), the mesh triangle prim int32 (N,) and its instance int32 "
           "(N,) (-1: none).")
      .def_prop_ro("geometry", [](const TracerHandle& t) { return t.geometry; })
      .def_prop_ro(
          "light_reach", [](const TracerHandle& t) { return t.tracer->light_reach(); },
          "Light paths longer than this are not summed (E3, S3, H3, H2xR, S2xR).")
      .def_prop_ro("num_light_lifts",
                   [](const TracerHandle& t) { return t.tracer->num_light_lifts(); })
      .def_prop_ro(
          "light_power", [](const TracerHandle& t) { return t.tracer->light_power(); },
          "The sum over lights of their radiance's mean over RGB.")
      .def_prop_ro("num_emitter_triangles",
                   [](const TracerHandle& t) { return t.tracer->num_emitter_triangles(); })
      .def_prop_ro("num_emitter_copies",
                   [](const TracerHandle& t) { return t.tracer->num_emitter_copies(); })
      .def_prop_ro(
          "num_unmatched_emitters",
          [](const TracerHandle& t) { return t.tracer->num_unmatched_emitters(); },
          "Emissive triangles (per instance) not found among the emitters' copies: bounces "
          "that meet them add nothing (their light comes from the emitters' samples).")
      .def_prop_ro("num_threads", [](const TracerHandle& t) { return t.tracer->num_threads(); })
      .def_prop_ro(
          "num_triangles", [](const TracerHandle& t) { return t.tracer->num_triangles(); },
          "The meshes' own triangles (each stored once).")
      .def_prop_ro("num_instances", [](const TracerHandle& t) { return t.tracer->num_instances(); })
      .def_prop_ro(
          "num_instanced_triangles",
          [](const TracerHandle& t) { return t.tracer->num_instanced_triangles(); },
          "The triangles the instances place, each instance counting its mesh's.");
}

}  // namespace thurston::bindings
