// The kernel registry: the static table that chooses a geometry's kernel by name, and the
// instantiation of the tracer (kernel_tracer.hpp, integrator.hpp) for each kernel.
#include "registry.hpp"

#include <cmath>
#include <stdexcept>

#include "graph.hpp"
#include "h2xr.hpp"
#include "integrator.hpp"
#include "kernel_tracer.hpp"
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

// (projective.hpp's; defined here, in the translation unit of the walks that call it, so that
// they may inline it)
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

// Whether a flow is configured by parameters (GraphFlow's bumps: Flow::from_parameters).
template <class Flow, class = void>
struct HasParameters : std::false_type {};
template <class Flow>
struct HasParameters<Flow, std::void_t<decltype(&Flow::from_parameters)>> : std::true_type {};

// The flow of the geometry's parameters; false where they are not its (flows without parameters
// take none).
template <class Flow>
bool configured(const std::vector<double>& parameters, Flow& flow) {
  if constexpr (HasParameters<Flow>::value) {
    return Flow::from_parameters(parameters, flow);
  } else {
    flow = Flow();
    return parameters.empty();
  }
}

template <class Flow>
bool accepts_of(const std::vector<double>& parameters) {
  Flow flow;
  return configured(parameters, flow);
}

bool accepts_none(const std::vector<double>& parameters) { return parameters.empty(); }

template <class Flow>
bool start_marching(int, Vec4& X, Vec4& V) {
  return MarchingKernel<Flow>().start(X, V);
}

bool start_projective(int k, Vec4& X, Vec4& V) { return ProjectiveKernel{k}.start(X, V); }

bool in_projective_chart(int k, const Vec3& x) { return ProjectiveKernel{k}.in_chart(x); }

struct Geometry {
  const char* name;
  int curvature;  // projective kernels; unused by the others
  std::unique_ptr<Tracer> (*make)(int curvature, SceneData scene, unsigned threads);
  bool (*normalise)(int curvature, Vec4& X);
  bool (*start)(int curvature, Vec4& X, Vec4& V);
  bool (*flow)(const std::vector<double>& parameters, const Vec3& x, const Vec3& v, double t,
               double accuracy, Vec3& xt, Vec3& vt);
  std::unique_ptr<Connections> (*connections)(double reach, const std::vector<double>& parameters);
  bool (*accepts)(const std::vector<double>& parameters);
  const char* chart_region = nullptr;  // where the chart is not all of R^3: the region, in words
  bool (*in_chart)(int curvature, const Vec3& x) = nullptr;
};

std::unique_ptr<Tracer> make_projective(int k, SceneData scene, unsigned threads) {
  return std::make_unique<KernelTracer<ProjectiveKernel>>(ProjectiveKernel{k}, std::move(scene),
                                                          threads, false);
}

template <class Flow>
std::unique_ptr<Tracer> make_marching(int, SceneData scene, unsigned threads) {
  Flow flow;
  if (!configured(scene.geometry_parameters, flow))
    throw std::invalid_argument("geometry_parameters are not the geometry's");
  return std::make_unique<KernelTracer<MarchingKernel<Flow>>>(MarchingKernel<Flow>(flow),
                                                              std::move(scene), threads, true);
}

template <class Flow>
bool flow_of(const std::vector<double>& parameters, const Vec3& x, const Vec3& v, double t,
             double accuracy, Vec3& xt, Vec3& vt) {
  Flow flow;
  if (!configured(parameters, flow)) return false;
  double error;
  flow.flow(x, v, t, accuracy, xt, vt, error);
  return true;
}

// A marching kernel prepared for a reach, as Connections.
template <class Flow>
class MarchingConnections final : public Connections {
 public:
  MarchingConnections(double reach, const Flow& flow) : kernel_(flow), reach_(reach) {
    kernel_.prepare_light_paths(reach);
  }
  int connect(const Vec3& h, const Vec3& l, std::vector<LightPath>& paths) const override {
    return kernel_.light_paths(point4(h), {point4(l)}, reach_, paths);
  }

 private:
  MarchingKernel<Flow> kernel_;
  double reach_;
};

template <class Flow>
std::unique_ptr<Connections> connections_of(double reach, const std::vector<double>& parameters) {
  Flow flow;
  if (!configured(parameters, flow)) return nullptr;
  return std::make_unique<MarchingConnections<Flow>>(reach, flow);
}

const Geometry kGeometries[] = {
    {"E3", 0, make_projective, normalise_projective, start_projective, nullptr, nullptr,
     accepts_none},
    {"S3", 1, make_projective, normalise_projective, start_projective, nullptr, nullptr,
     accepts_none},
    {"H3", -1, make_projective, normalise_projective, start_projective, nullptr, nullptr,
     accepts_none, "the unit ball (the Klein model)", in_projective_chart},
    {"Nil", 0, make_marching<NilFlow>, normalise_affine, start_marching<NilFlow>, flow_of<NilFlow>,
     connections_of<NilFlow>, accepts_of<NilFlow>},
    {"Sol", 0, make_marching<SolFlow>, normalise_affine, start_marching<SolFlow>, flow_of<SolFlow>,
     connections_of<SolFlow>, accepts_of<SolFlow>},
    {"H2xR", 0, make_marching<H2xRFlow>, H2xRFlow::normalise_lift, start_marching<H2xRFlow>,
     flow_of<H2xRFlow>, connections_of<H2xRFlow>, accepts_of<H2xRFlow>},
    {"S2xR", 0, make_marching<S2xRFlow>, normalise_affine, start_marching<S2xRFlow>,
     flow_of<S2xRFlow>, connections_of<S2xRFlow>, accepts_of<S2xRFlow>},
    {"SL2", 0, make_marching<SL2Flow>, SL2Flow::normalise_lift, start_marching<SL2Flow>,
     flow_of<SL2Flow>, connections_of<SL2Flow>, accepts_of<SL2Flow>},
    {"graph", 0, make_marching<GraphFlow>, normalise_affine, start_marching<GraphFlow>,
     flow_of<GraphFlow>, connections_of<GraphFlow>, accepts_of<GraphFlow>},
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

std::optional<ChartRegion> chart_region(const std::string& geometry) {
  const Geometry& g = find(geometry);
  if (!g.chart_region) return std::nullopt;
  return ChartRegion{g.chart_region, g.curvature, g.in_chart};
}

bool normalise_point(const std::string& geometry, Vec4& X) {
  const Geometry& g = find(geometry);
  return g.normalise(g.curvature, X);
}

bool normalise_direction(const std::string& geometry, Vec4& X, Vec4& V) {
  const Geometry& g = find(geometry);
  return g.start(g.curvature, X, V);
}

std::unique_ptr<Tracer> make_tracer(const std::string& geometry, SceneData scene,
                                    unsigned threads) {
  const Geometry& g = find(geometry);
  return g.make(g.curvature, std::move(scene), threads);
}

bool has_flow(const std::string& geometry) { return find(geometry).flow != nullptr; }

bool accepts_parameters(const std::string& geometry, const std::vector<double>& parameters) {
  return find(geometry).accepts(parameters);
}

bool geodesic_flow(const std::string& geometry, const std::vector<double>& parameters,
                   const Vec3& x, const Vec3& v, double t, double accuracy, Vec3& xt, Vec3& vt) {
  const Geometry& g = find(geometry);
  return g.flow && g.flow(parameters, x, v, t, accuracy, xt, vt);
}

std::unique_ptr<Connections> make_connections(const std::string& geometry, double reach,
                                              const std::vector<double>& parameters) {
  const Geometry& g = find(geometry);
  return g.connections ? g.connections(reach, parameters) : nullptr;
}

}  // namespace thurston
