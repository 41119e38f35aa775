// The kernel registry: the geometries by name, each with its kernel (projective.hpp, march.hpp and
// the flows), and what the bindings ask of a geometry by name. The one place besides the kernel
// headers that knows the geometries.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "kernel.hpp"
#include "scene.hpp"
#include "tracer.hpp"

namespace thurston {

// The geometries by name ("E3", "S3", "H3", "Nil", "Sol", "H2xR", "S2xR", "SL2", "graph"), in the
// registry's order.
std::vector<std::string> geometry_names();
bool has_geometry(const std::string& name);

// A chart that is not all of R^3 (H3's Klein ball): the region in words, and whether a chart point
// lies in it.
struct ChartRegion {
  const char* words;
  int curvature;
  bool (*contains)(int curvature, const Vec3& x);
  bool operator()(const Vec3& x) const { return contains(curvature, x); }
};
// nullopt where the geometry's chart is all of R^3.
std::optional<ChartRegion> chart_region(const std::string& geometry);

// Brings a light's position onto the geometry's model (false: not a point of it).
bool normalise_point(const std::string& geometry, Vec4& X);
// Brings a point and a tangent vector there onto the geometry's model, the vector of unit length
// (false: no point, or no direction).
bool normalise_direction(const std::string& geometry, Vec4& X, Vec4& V);
// Whether the geometry takes these parameters (scene.geometry_parameters: graph's bumps; the
// others take none).
bool accepts_parameters(const std::string& geometry, const std::vector<double>& parameters);
// Whether the geometry has a marching flow (the projective ones do not: their geodesics are lines).
bool has_flow(const std::string& geometry);
std::unique_ptr<Tracer> make_tracer(const std::string& geometry, SceneData scene, unsigned threads);
// The geometry's flow (with its parameters) from chart points x with unit chart velocities v over
// arclength t, as the tracer follows it (asked for `accuracy`); false for geometries without one
// (the projective ones, whose geodesics are exact lines) or parameters that are not its.
bool geodesic_flow(const std::string& geometry, const std::vector<double>& parameters,
                   const Vec3& x, const Vec3& v, double t, double accuracy, Vec3& xt, Vec3& vt);
// The tracer's light paths of a marching geometry within a reach, for the bindings: every
// geodesic from the chart point h to the chart point l no longer than the reach, and how many the
// search could tell it missed.
class Connections {
 public:
  virtual ~Connections() = default;
  virtual int connect(const Vec3& h, const Vec3& l, std::vector<LightPath>& paths) const = 0;
};
// nullptr for geometries without a marching flow (or parameters that are not the geometry's).
std::unique_ptr<Connections> make_connections(const std::string& geometry, double reach,
                                              const std::vector<double>& parameters);

}  // namespace thurston
