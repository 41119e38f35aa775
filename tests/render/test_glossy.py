"""The glossy BSDF (Blender's Principled subset: GGX specular layer over Lambert, metallic GGX) against
its albedo integrated here, and the materials' scattering from TOML, MTL and glTF files.

Glossy furnace: a closed sphere of one material emitting Le (both sides) around a camera off its
centre. Every point of the sphere receives Le from every direction, so a camera ray meeting it at
cos_o to its normal sees Le (1 + a(cos_o)) with direct light only, a(cos_o) the BSDF's directional
albedo (the integral of f cos over the hemisphere); with one bounce also Le times the integral of
f cos a(cos_i): a chord of a sphere meets it at the same angle at both ends, so the bounce's hit is
seen at cos_i. a and that integral are computed here by Gauss-Legendre quadrature (scipy) of the
GGX BRDF written below from the formulas (D, height-correlated Smith G, Schlick's or the dielectric
Fresnel), sharing nothing with the tracer, and integrated over the microfacet normals."""

from __future__ import annotations

import base64
import json
import math

import numpy as np
import pytest
import trimesh
from scipy.special import roots_legendre

from thurston_addon import render, spaces
from thurston_addon.scenes import Material, Scene, SceneError, SceneObject, load_mesh_file, load_scene_file

LE = 1.0


# --- the BRDF, from the formulas ------------------------------------------------------------------
def fresnel_dielectric(c, eta):
    g = np.sqrt(eta**2 - 1 + c**2)
    a, b = (g - c) / (g + c), (c * (g + c) - 1) / (c * (g - c) + 1)
    return 0.5 * a**2 * (1 + b**2)


def layer_eta(ior, level):
    """Blender's Specular IOR Level: F0 of the IOR times 2 level, back to an index."""
    f0 = ((ior - 1) / (ior + 1)) ** 2 * 2 * level
    return (1 + math.sqrt(f0)) / (1 - math.sqrt(f0))


def half_vectors(n_theta=160, n_phi=64):
    """Microfacet normals h over the upper hemisphere (Gauss-Legendre in the polar angle, where
    GGX's D peaks at 0; uniform in the azimuth) and their solid-angle weights."""
    x, w = roots_legendre(n_theta)
    theta, w_theta = (x + 1) * math.pi / 4, w * math.pi / 4
    phi = 2 * math.pi * np.arange(n_phi) / n_phi
    T, P = np.meshgrid(theta, phi, indexing="ij")
    h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    return h, np.outer(w_theta * np.sin(theta), np.full(n_phi, 2 * math.pi / n_phi))


class Principled:
    """The reference BSDF of a material (one colour channel): Lambert base of albedo rho under a
    dielectric GGX layer of index eta, dimmed by the layer's albedo (dimmed=False: not), or a
    metal (GGX, Schlick's Fresnel from f0 = rho). Its specular part is integrated over the
    microfacet normals h, wi the mirror image of wo about h: dw_i = 4 (wo.h) dw_h, and f_spec cos_i
    dw_i = fresnel(wo.h) D(h) G2 (wo.h) / cos_o dw_h."""

    def __init__(self, rho, roughness, metallic, eta=None, dimmed=True):
        self.rho, self.alpha, self.metallic, self.eta, self.dimmed = rho, roughness**2, metallic, eta, dimmed
        self.h, self.weights = half_vectors()
        x, w = roots_legendre(200)  # cos_i over [0, 1], for the Lambert part
        self.mu, self.mu_weights = (x + 1) / 2, w / 2

    def fresnel(self, c):
        if self.metallic:
            return self.rho + (1 - self.rho) * (1 - c) ** 5
        return fresnel_dielectric(c, self.eta)

    def specular(self, cos_o):
        """(cos_i of the reflected directions, f_spec cos_i dw_i / dw_h) at the normals h."""
        wo = np.array([math.sqrt(1 - cos_o**2), 0.0, cos_o])
        c = self.h @ wo
        cos_i = 2 * c * self.h[..., 2] - cos_o
        a2 = self.alpha**2
        D = a2 / (np.pi * (self.h[..., 2] ** 2 * (a2 - 1) + 1) ** 2)

        def smith_lambda(u):
            return 0.5 * (np.sqrt(1 + a2 * (1 / u**2 - 1)) - 1)

        up = (cos_i > 0) & (c > 0)
        G = np.where(up, 1 / (1 + smith_lambda(cos_o) + smith_lambda(np.where(up, cos_i, 1.0))), 0.0)
        return cos_i, self.fresnel(np.abs(c)) * D * G * c / cos_o

    def albedo(self, cos_o):
        _, spec = self.specular(cos_o)
        layer = np.sum(spec * self.weights)
        if self.metallic:
            return layer
        return layer + self.rho * (1 - (layer if self.dimmed else 0.0))

    def bounce(self, cos_o, albedo):
        """The integral of f cos albedo(cos_i): one bounce's light in the furnace."""
        cos_i, spec = self.specular(cos_o)
        total = np.sum(spec * albedo(np.clip(cos_i, 0, 1)) * self.weights)
        if not self.metallic:  # the Lambert part: rho (1 - E) / pi cos over the hemisphere
            layer = np.sum(spec * self.weights) if self.dimmed else 0.0
            total += self.rho * (1 - layer) * 2 * np.sum(self.mu * albedo(self.mu) * self.mu_weights)
        return float(total)


def furnace_truth(reference, cos_o, bounces):
    """Per ray, Le (1 + a(cos_o)) [+ Le b(cos_o)], a and b tabulated over cos_o and interpolated."""
    nodes = np.linspace(0.02, 1.0, 50)
    a = np.array([reference.albedo(c) for c in nodes])
    truth = LE * (1 + np.interp(cos_o, nodes, a))
    if bounces:
        b = np.array([reference.bounce(c, lambda c_i: np.interp(c_i, nodes, a)) for c in nodes])
        truth += LE * np.interp(cos_o, nodes, b)
    return truth


# --- the furnace ------------------------------------------------------------------------------------
RADIUS = 0.3
CAMERA = np.array([0.2, 0.1, -0.05])  # off the centre: cos_o from 1 down to about 0.55


def glossy_furnace(material, bounces, n=12000, seed=3, light_samples=4):
    """(colours, cos_o) of n random rays from CAMERA inside a smooth sphere (corner normals along
    the radius) of the material in the 3-torus."""
    ball = trimesh.creation.icosphere(subdivisions=4, radius=RADIUS)
    walls = SceneObject(
        "walls",
        ball.vertices,
        ball.faces,
        corner_normals=(ball.vertices / RADIUS)[ball.faces],
        materials=[material],
        triangle_material=np.zeros(len(ball.faces), np.int32),
    )
    space = spaces.load("torus")
    tracer = render.make_tracer(space, Scene(objects=[walls], lights=[]), threads=2, light_reach=2 * RADIUS + 0.05)
    d = np.random.default_rng(seed).normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    P = np.ascontiguousarray(np.c_[np.repeat(CAMERA[None], n, axis=0), np.ones(n)])
    out = tracer.trace(
        P, np.ascontiguousarray(np.c_[d, np.zeros(n)]), 5.0, 40, light_samples=light_samples, seed=seed, bounces=bounces
    )
    assert np.all(out["stop"] == 0)
    # where the ray meets the sphere |x| = R: sin of its angle to the normal is |c x d| / R
    cos_o = np.sqrt(1 - np.sum(np.cross(CAMERA, d) ** 2, axis=1) / RADIUS**2)
    return out["color"], cos_o


METAL = dict(color=(0.95, 0.6, 0.3), roughness=0.35, metallic=1.0)
LAYERED = dict(color=(0.5, 0.5, 0.5), roughness=0.3, specular=0.5, ior=1.5)


@pytest.mark.parametrize("kind, bounces", [("metal", 0), ("metal", 1), ("layered", 0), ("layered", 1)])
def test_glossy_furnace_matches_the_integrated_albedo(kind, bounces):
    """Per colour channel, the mean over the rays of colour - truth(cos_o) within four measured
    standard errors of 0, and those errors small enough that a wrong BSDF would fail: the metal's
    roughness mapped wrongly (alpha = roughness instead of its square), the layered base not dimmed
    by the layer's albedo. One bounce draws directions from the glossy lobes (and weighs the
    emitters' samples against them, MIS)."""
    spec = METAL if kind == "metal" else LAYERED
    material = Material(emission=(LE,) * 3, name=kind, **spec)
    color, cos_o = glossy_furnace(material, bounces)
    for channel, rho in enumerate(spec["color"]):
        eta = None if kind == "metal" else layer_eta(spec["ior"], spec["specular"])
        reference = Principled(rho, spec["roughness"], spec.get("metallic", 0.0), eta)
        truth = furnace_truth(reference, cos_o, bounces)
        diff = color[:, channel] - truth
        mean, error = diff.mean(), diff.std(ddof=1) / math.sqrt(len(diff))
        if kind == "metal":
            wrong = Principled(rho, math.sqrt(spec["roughness"]), 1.0)
        else:
            wrong = Principled(rho, spec["roughness"], 0.0, eta, dimmed=False)
        wrong = furnace_truth(wrong, cos_o, bounces)
        print(
            f"{kind} bounces {bounces} channel {channel}: mean {color[:, channel].mean():.5f} truth "
            f"{truth.mean():.5f} (difference {mean:+.2e} +- {error:.1e}); the wrong BSDF: {wrong.mean():.5f}"
        )
        assert abs(mean) < 4 * error
        assert abs(wrong.mean() - truth.mean()) > 8 * error


def test_lambert_materials_shade_as_before():
    """metallic 0 and specular 0 (the default Material) is the Lambert surface: the furnace gives
    Le (1 + rho) exactly, with no spread but the emitters' samples'."""
    color, _ = glossy_furnace(Material(color=(0.5, 0.5, 0.5), emission=(LE,) * 3, roughness=0.1), 0, n=2000)
    mean, error = color[:, 0].mean(), color[:, 0].std(ddof=1) / math.sqrt(len(color))
    assert abs(mean - LE * 1.5) < 4 * error


# --- scattering from files ---------------------------------------------------------------------------
def test_toml_keys_set_the_scattering_of_every_material(tmp_path):
    (tmp_path / "scene.toml").write_text(
        '[[object]]\nprimitive = "sphere"\nradius = 0.1\nroughness = 0.25\nmetallic = 1.0\n'
        '[[object]]\nprimitive = "box"\nspecular = 0.5\nior = 1.45\n'
    )
    ball, box = load_scene_file(tmp_path / "scene.toml").objects
    (m,) = ball.surface_materials()[0]
    assert (m.roughness, m.metallic, m.specular, m.ior) == (0.25, 1.0, 0.0, 1.5)
    (m,) = box.surface_materials()[0]
    assert (m.roughness, m.metallic, m.specular, m.ior) == (0.5, 0.0, 0.5, 1.45)


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("roughness", 1.5, "roughness must be a number in \\[0, 1\\]"),
        ("metallic", '"shiny"', "metallic must be a number in \\[0, 1\\]"),
        ("specular", -0.5, "specular must be a number >= 0"),
        ("ior", 0, "ior must be a number > 0"),
    ],
)
def test_bad_scattering_is_one_clear_error(tmp_path, key, value, message):
    (tmp_path / "scene.toml").write_text(f'[[object]]\nprimitive = "sphere"\n{key} = {value}\n')
    with pytest.raises(SceneError, match=f"scene.toml: object 0: material 'sphere': {message}"):
        load_scene_file(tmp_path / "scene.toml")


def test_mtl_scattering_as_blender_imports_it(tmp_path):
    """Pr and Pm as they are; without Pr the roughness from the exponent Ns (1 - sqrt(Ns / 1000));
    the specular level the mean of Ks; Ni the index where it is one (Ni 0: none)."""
    (tmp_path / "m.mtl").write_text(
        "newmtl pbr\nKd 0.5 0.5 0.5\nPr 0.2\nPm 0.7\nKs 0.2 0.4 0.6\nNi 1.6\n"
        "newmtl phong\nKd 0.5 0.5 0.5\nNs 250\nKs 0.5 0.5 0.5\nNi 0.0\n"
        "newmtl plain\nKd 0.5 0.5 0.5\n"
    )
    (tmp_path / "a.obj").write_text(
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl pbr\nf 1 2 3\nusemtl phong\nf 1 3 2\nusemtl plain\nf 2 1 3\n"
    )
    (obj,) = load_mesh_file(tmp_path / "a.obj")
    pbr, phong, plain = obj.materials
    assert (pbr.roughness, pbr.metallic, pbr.specular, pbr.ior) == pytest.approx((0.2, 0.7, 0.4, 1.6))
    assert (phong.roughness, phong.metallic, phong.specular, phong.ior) == pytest.approx((0.5, 0.0, 0.5, 1.5))
    assert (plain.metallic, plain.specular) == (0.0, 0.0)  # Lambert, as before


def test_gltf_metallic_roughness_factors(tmp_path):
    """glTF's factors, absent ones 1 as the format has it, over its dielectric of F0 0.04."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes()
    gltf = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0, "name": "brushed"}, {"mesh": 1, "name": "default"}],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": 0}, "material": 0}]},
            {"primitives": [{"attributes": {"POSITION": 0}, "material": 1}]},
        ],
        "materials": [
            {"name": "brushed", "pbrMetallicRoughness": {"metallicFactor": 0.25, "roughnessFactor": 0.4}},
            {"name": "default", "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1]}},
        ],
        "buffers": [
            {"byteLength": 36, "uri": "data:application/octet-stream;base64," + base64.b64encode(positions).decode()}
        ],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}
        ],
    }
    (tmp_path / "two.gltf").write_text(json.dumps(gltf))
    brushed, default = load_mesh_file(tmp_path / "two.gltf")
    m = brushed.materials[0]
    assert (m.roughness, m.metallic, m.specular, m.ior) == pytest.approx((0.4, 0.25, 0.5, 1.5))
    m = default.materials[0]
    assert (m.roughness, m.metallic) == (1.0, 1.0)
