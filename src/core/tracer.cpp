#include "tracer.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace thurston {

namespace {

constexpr std::size_t kChunk = kRayBlock;
constexpr std::chrono::milliseconds kPollInterval{100};

// The chunks' starts (and count at the end): runs of kChunk rays, or with ray ids the runs whose
// ids lie in one block of kChunk ids. A chunk's rays learn shadow-walk visibility together
// (kernel_tracer.hpp), so a ray's light then depends on its block's rays alone, not on which of
// them the call traces: a tile of an image or an adaptive pass's subset learns as the whole image.
std::vector<std::size_t> chunk_starts(std::size_t count, const std::int64_t* ray_ids) {
  std::vector<std::size_t> starts;
  for (std::size_t i = 0; i < count; ++i) {
    const bool new_block = ray_ids ? i == 0 || ray_ids[i] / std::int64_t(kChunk) !=
                                                   ray_ids[i - 1] / std::int64_t(kChunk)
                                   : i % kChunk == 0;
    if (new_block) starts.push_back(i);
  }
  starts.push_back(count);
  return starts;
}

}  // namespace

Tracer::Tracer(SceneData& scene, unsigned threads, bool occupancy)
    : vertices_(std::move(scene.meshes.vertices)),
      triangles_(std::move(scene.meshes.triangles)),
      triangle_object_(std::move(scene.meshes.triangle_object)),
      mesh_first_(std::move(scene.meshes.first)),
      surfaces_(std::move(scene.surfaces)),
      light_radiance_(std::move(scene.lights.radiance)),
      light_cone_(std::move(scene.lights.cone)),
      emitters_(std::move(scene.emitters)),
      light_reach_(scene.lights.reach),
      geodesic_loop_(scene.lights.geodesic_loop),
      pool_(threads) {
  domain_.faces = scene.domain.covectors.size();
  for (const Vec4& c : scene.domain.covectors)
    for (int a = 0; a < 4; ++a) domain_.components[a].push_back(c[a]);
  while (domain_.components[0].size() % 4 != 0)  // zero covectors: never an exit
    for (int a = 0; a < 4; ++a) domain_.components[a].push_back(0.0);
  domain_.maps = std::move(scene.domain.maps);
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
  light_copies_.resize(light_radiance_.size());
  light_cone_.resize(light_radiance_.size());
  for (std::size_t k = 0; k < scene.lights.lifts.size(); ++k) {
    const std::int32_t l = scene.lights.of_lift[k];
    light_lifts_[l].push_back(scene.lights.lifts[k]);
    if (light_cone_[l].active()) light_axes_[l].push_back(scene.lights.axis[k]);
    if (!scene.lights.copies.empty()) light_copies_[l].push_back(scene.lights.copies[k]);
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

  build_scenes();
}

Tracer::~Tracer() = default;

std::size_t Tracer::num_instanced_triangles() const {
  std::size_t n = 0;
  for (const Placement& p : instances_) n += mesh_first_[p.mesh + 1] - mesh_first_[p.mesh];
  return n;
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
  prepare(options);
  const std::vector<std::size_t> starts = chunk_starts(count, options.ray_ids);
  const std::size_t chunks = starts.size() - 1;
  // Kept by chunk, so that the recording does not depend on the thread count.
  std::vector<std::vector<double>> chunk_segments(options.record_segments ? chunks : 0);
  TraceStats stats;
  std::mutex stats_mutex;
  // summed in chunk order: the same for any threads
  std::vector<double> chunk_energy(chunks, 0.0), chunk_emitter_energy(chunks, 0.0);
  const std::size_t traced = run_chunks(
      starts,
      [&](std::size_t chunk, std::size_t begin, std::size_t end) {
        std::vector<double>* segments = options.record_segments ? &chunk_segments[chunk] : nullptr;
        TraceStats local;
        trace_range(begin, end, origins, directions, options, out, segments, local);
        {
          const std::lock_guard<std::mutex> hold(stats_mutex);
          stats.add_counts(local);
        }
        chunk_energy[chunk] = local.light_energy;
        chunk_emitter_energy[chunk] = local.emitter_energy;
      },
      poll, true);
  for (std::size_t i = traced; i < count; ++i) out.write_miss(i, kCancelled, 0, 0.0, 0);
  for (const double e : chunk_energy) stats.light_energy += e;
  for (const double e : chunk_emitter_energy) stats.emitter_energy += e;
  stats.segments = std::move(chunk_segments);
  return stats;
}

void Tracer::query_segments(std::size_t count, Strided2<double> starts, Strided2<double> ends,
                            float* t, std::int32_t* prim, std::int32_t* instance) {
  const RunLock lock(*this);
  run_chunks(
      chunk_starts(count, nullptr),
      [&](std::size_t, std::size_t begin, std::size_t end) {
        for (std::size_t i = begin; i < end; ++i) {
          const Vec3 x0{starts(i, 0), starts(i, 1), starts(i, 2)};
          const Vec3 x1{ends(i, 0), ends(i, 1), ends(i, 2)};
          const embree::FirstHit hit =
              embree::intersect(scene_.get(), embree::chord_ray(x0, x1, 0.0f));
          const bool found = hit.prim >= 0;
          prim[i] = found ? std::int32_t(triangle_of(hit)) : -1;
          instance[i] = found ? std::int32_t(hit.instance) : -1;
          t[i] = found ? hit.u : std::numeric_limits<float>::infinity();
        }
      },
      nullptr, false);
}

std::size_t Tracer::run_chunks(const std::vector<std::size_t>& starts,
                               const std::function<void(std::size_t, std::size_t, std::size_t)>& fn,
                               const Poll& poll, bool cancellable) {
  const std::size_t chunks = starts.size() - 1;
  std::atomic<std::size_t> next{0}, done{0};
  std::atomic<bool>& stop = run_stop_;
  stop = poll && !poll(0);
  const std::function<void()> task = [&] {
    try {
      while (!stop.load()) {
        const std::size_t chunk = next.fetch_add(1);
        if (chunk >= chunks) break;
        const std::size_t begin = starts[chunk], end = starts[chunk + 1];
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
  return starts[std::min(next.load(), chunks)];
}

}  // namespace thurston
