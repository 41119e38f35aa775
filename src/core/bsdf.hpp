// The surface's scattering: the subset of Blender's Principled BSDF the tracer shades with, in a
// local orthonormal frame at the hit (z the shading normal; the tracer builds the frame in the
// metric, so the formulas are those of flat space). A Lambert base under a dielectric GGX
// (Trowbridge-Reitz) specular layer, the base dimmed by the layer's directional albedo as Cycles
// layers them, mixed with a metallic GGX lobe (Schlick's Fresnel from the base colour: Cycles'
// F82-tint model with a white tint). Single scattering, height-correlated Smith masking.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>

#include "vec.hpp"

namespace thurston {

// Smallest GGX alpha (roughness^2): below it the lobe would be a mirror that neither the lights'
// samples nor the densities of float arithmetic can handle.
constexpr double kMinAlpha = 1e-3;

// The GGX distribution of microfacet normals, alpha2 = alpha^2.
struct Ggx {
  double alpha2 = 1.0;

  double density(double cos_h) const {  // D(h)
    const double c2 = cos_h * cos_h;
    const double d = 1.0 + (alpha2 - 1.0) * c2;
    return alpha2 / (kPi * d * d);
  }
  double lambda(double cos_n) const {  // Smith's Lambda of a direction at cos_n to the normal
    const double tan2 = std::max(1.0 / (cos_n * cos_n) - 1.0, 0.0);
    return 0.5 * (std::sqrt(1.0 + alpha2 * tan2) - 1.0);
  }
  // A microfacet normal drawn from the normals visible from wo (wo.z > 0), as Heitz (JCGT 2018)
  // maps two uniform numbers to them: wo stretched to the hemisphere configuration, a point of the
  // projected disk, back-projected onto the hemisphere and unstretched.
  Vec3 visible_normal(const Vec3& wo, double u1, double u2) const {
    const double alpha = std::sqrt(alpha2);
    Vec3 v{alpha * wo[0], alpha * wo[1], wo[2]};
    v = scaled3(1.0 / norm3(v), v);
    const double across = v[0] * v[0] + v[1] * v[1];
    const Vec3 t1 = across > 0.0 ? scaled3(1.0 / std::sqrt(across), Vec3{-v[1], v[0], 0.0})
                                 : Vec3{1.0, 0.0, 0.0};
    const Vec3 t2 = cross3(v, t1);
    const double r = std::sqrt(u1), phi = 2.0 * kPi * u2, s = 0.5 * (1.0 + v[2]);
    const double a = r * std::cos(phi);
    const double b = (1.0 - s) * std::sqrt(std::max(1.0 - a * a, 0.0)) + s * r * std::sin(phi);
    const double c = std::sqrt(std::max(1.0 - a * a - b * b, 0.0));
    const Vec3 n = add3(add3(scaled3(a, t1), scaled3(b, t2)), scaled3(c, v));
    const Vec3 h{alpha * n[0], alpha * n[1], std::max(n[2], 0.0)};
    return scaled3(1.0 / norm3(h), h);
  }
  // The density (solid angle) of the reflected directions wi when the normal is drawn by
  // visible_normal: D_wo(h) / (4 wo.h) = G1(wo) D(h) / (4 wo.z).
  double reflection_density(const Vec3& wo, const Vec3& wi) const {
    const Vec3 h = half_vector(wo, wi);
    return density(h[2]) / ((1.0 + lambda(wo[2])) * 4.0 * wo[2]);
  }
  // D G2 / (4 wi.z wo.z): the specular BRDF without its Fresnel factor (both above the surface).
  double reflectance(const Vec3& wo, const Vec3& wi) const {
    const Vec3 h = half_vector(wo, wi);
    return density(h[2]) / ((1.0 + lambda(wo[2]) + lambda(wi[2])) * 4.0 * wo[2] * wi[2]);
  }
  static Vec3 half_vector(const Vec3& wo, const Vec3& wi) {
    const Vec3 h = add3(wo, wi);
    return scaled3(1.0 / norm3(h), h);
  }
  static Vec3 reflect(const Vec3& wo, const Vec3& h) {
    return sub3(scaled3(2.0 * dot3(wo, h), h), wo);
  }
};

// A direction of the local frame (z the normal) with density cos / pi over the upper hemisphere,
// from two uniform numbers.
inline Vec3 cosine_hemisphere(double u1, double u2) {
  const double r = std::sqrt(u1), phi = 2.0 * kPi * u2;
  return {r * std::cos(phi), r * std::sin(phi), std::sqrt(1.0 - u1)};
}

// The Fresnel reflectance of unpolarised light meeting a dielectric of relative index eta > 1 at
// cos_i to its normal (from outside).
inline double dielectric_fresnel(double cos_i, double eta) {
  const double c = std::abs(cos_i);
  const double g2 = eta * eta - 1.0 + c * c;
  if (g2 <= 0.0) return 1.0;
  const double g = std::sqrt(g2);
  const double a = (g - c) / (g + c);
  const double b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0);
  return 0.5 * a * a * (1.0 + b * b);
}

// Schlick's reflectance of a metal of normal reflectance f0 at cos_i.
inline double schlick_fresnel(double f0, double cos_i) {
  const double m = std::clamp(1.0 - cos_i, 0.0, 1.0);
  const double m2 = m * m;
  return f0 + (1.0 - f0) * m2 * m2 * m;
}

// Blender's Specular IOR Level: the normal reflectance F0 of the index scaled by 2 level, turned
// back into an index (level 0.5: the index itself, or its inverse where it is below 1; 0: no
// specular layer, index 1).
inline double layer_index(double ior, double level) {
  const double r = (ior - 1.0) / (ior + 1.0);
  const double f0 = std::min(r * r * 2.0 * level, 0.999999);
  const double s = std::sqrt(f0);
  return (1.0 + s) / (1.0 - s);
}

// The directional albedo E(cos_o) of the dielectric specular layer (single-scattering GGX with the
// dielectric Fresnel), at the cosines (k + 1/2) / kAlbedoNodes, by a fixed stratified rule over
// the visible normals (kAlbedoGrid^2 points): the share of light the layer reflects, which the
// base below it does not get (Cycles layers the Principled BSDF so).
constexpr int kAlbedoNodes = 32;
constexpr int kAlbedoGrid = 24;
using AlbedoTable = std::array<float, kAlbedoNodes>;

inline AlbedoTable layer_albedo(const Ggx& ggx, double eta) {
  AlbedoTable table{};
  for (int k = 0; k < kAlbedoNodes; ++k) {
    const double c = (k + 0.5) / kAlbedoNodes;
    const Vec3 wo{std::sqrt(1.0 - c * c), 0.0, c};
    double sum = 0.0;
    for (int i = 0; i < kAlbedoGrid; ++i)
      for (int j = 0; j < kAlbedoGrid; ++j) {
        const Vec3 h = ggx.visible_normal(wo, (i + 0.5) / kAlbedoGrid, (j + 0.5) / kAlbedoGrid);
        const Vec3 wi = Ggx::reflect(wo, h);
        if (!(wi[2] > 0.0)) continue;
        // f cos / density = F G2 / G1(wo)
        sum += dielectric_fresnel(dot3(wo, h), eta) * (1.0 + ggx.lambda(wo[2])) /
               (1.0 + ggx.lambda(wo[2]) + ggx.lambda(wi[2]));
      }
    table[k] = float(sum / (kAlbedoGrid * kAlbedoGrid));
  }
  return table;
}

// The table at cos_o, linear between its nodes (constant beyond the first and last).
inline double albedo_at(const AlbedoTable& table, double cos_o) {
  const double x = std::clamp(cos_o * kAlbedoNodes - 0.5, 0.0, kAlbedoNodes - 1.0);
  const int k = std::min(int(x), kAlbedoNodes - 2);
  const double t = x - k;
  return (1.0 - t) * table[k] + t * table[k + 1];
}

using Color = std::array<double, 3>;

// A material's scattering, fixed per material: how metallic, the GGX lobe and the index of the
// dielectric layer (1: none) with its albedo table.
struct Principled {
  double metallic = 0.0;
  Ggx ggx;
  double eta = 1.0;
  AlbedoTable albedo{};

  // roughness, metallic, Specular IOR Level and IOR as Blender's Principled BSDF takes them
  static Principled from(double roughness, double metallic, double level, double ior) {
    Principled p;
    p.metallic = std::clamp(metallic, 0.0, 1.0);
    const double alpha = std::max(roughness * roughness, kMinAlpha);
    p.ggx.alpha2 = alpha * alpha;
    p.eta = p.metallic < 1.0 && level > 0.0 && ior != 1.0 ? layer_index(ior, level) : 1.0;
    if (p.eta > 1.0) p.albedo = layer_albedo(p.ggx, p.eta);
    return p;
  }
  bool glossy() const { return metallic > 0.0 || eta > 1.0; }
};

// The BSDF of a glossy material at a shading point of base colour `base`, seen from wo (local,
// the unit direction towards the viewer). Its parts: the Lambert lobe of albedo `diffuse` (BRDF
// diffuse / pi) and the specular lobe (BRDF specular(wi)); directions are drawn from a mixture of
// the cosine density (probability 1 - specular_share) and GGX's visible normals, whose density
// (the one multiple importance sampling needs) is density(wi).
struct Bsdf {
  const Principled* material;
  Color base, diffuse{};
  Vec3 wo;
  double specular_share = 0.0;  // 0 where wo lies below the shading normal's plane

  Bsdf(const Principled& p, const Color& base_color, const Vec3& view)
      : material(&p), base(base_color), wo(view) {
    const double m = p.metallic, layer = p.eta > 1.0 ? albedo_at(p.albedo, wo[2]) : 0.0;
    for (int a = 0; a < 3; ++a) diffuse[a] = (1.0 - m) * (1.0 - layer) * base[a];
    if (!(wo[2] > 0.0)) return;
    // the lobes' shares of the light they reflect, from their albedos seen from wo
    const double metal = m * schlick_fresnel((base[0] + base[1] + base[2]) / 3.0, wo[2]);
    const double glossy = metal + (1.0 - m) * layer;
    const double total = glossy + (diffuse[0] + diffuse[1] + diffuse[2]) / 3.0;
    specular_share = total > 0.0 ? glossy / total : 0.0;
  }

  // The specular BRDF towards wi (per colour channel; zero below the surface).
  Color specular(const Vec3& wi) const {
    if (!(wi[2] > 0.0) || !(wo[2] > 0.0)) return {0.0, 0.0, 0.0};
    const Principled& p = *material;
    const double r = p.ggx.reflectance(wo, wi);
    const double c = dot3(wo, Ggx::half_vector(wo, wi));
    const double layer = p.eta > 1.0 ? (1.0 - p.metallic) * dielectric_fresnel(c, p.eta) : 0.0;
    Color f;
    for (int a = 0; a < 3; ++a) f[a] = r * (layer + p.metallic * schlick_fresnel(base[a], c));
    return f;
  }
  double density(const Vec3& wi) const {
    if (!(wi[2] > 0.0)) return 0.0;
    const double spec = specular_share > 0.0 ? material->ggx.reflection_density(wo, wi) : 0.0;
    return specular_share * spec + (1.0 - specular_share) * wi[2] / kPi;
  }
  // A direction from three uniform numbers: the lobe by u0, then the direction by (u1, u2).
  Vec3 sample(double u0, double u1, double u2) const {
    if (u0 < specular_share) return Ggx::reflect(wo, material->ggx.visible_normal(wo, u1, u2));
    return cosine_hemisphere(u1, u2);
  }
};

}  // namespace thurston
