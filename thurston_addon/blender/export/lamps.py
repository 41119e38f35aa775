"""Blender lamps as Cycles shades them: the colour a light's Temperature and its node tree (an
Emission node's Strength and Color, a Blackbody into that Color) give its power, and a point
light's radius as an emitting sphere."""

from __future__ import annotations

import math

import numpy as np

from ... import scenes

# Cycles' blackbody range (kernel/svm/math_util.h): below it the colour of 800 K, above it 12000 K's
BLACKBODY_RANGE = (800.0, 12000.0)

# The CIE 1931 2-degree colour matching functions as the multi-lobe Gaussian fit of Wyman, Sloan and
# Shirley, "Simple Analytic Approximations to the CIE XYZ Color Matching Functions" (JCGT 2013):
# per function, lobes (weight, centre nm, sigma below, sigma above).
_CMF_LOBES = (
    ((1.056, 599.8, 37.9, 31.0), (0.362, 442.0, 16.0, 26.7), (-0.065, 501.1, 20.4, 26.2)),
    ((0.821, 568.8, 46.9, 40.5), (0.286, 530.9, 16.3, 31.1)),
    ((1.217, 437.0, 11.8, 36.0), (0.681, 459.0, 26.0, 13.8)),
)
# CIE XYZ (D65) to linear Rec. 709 (IEC 61966-2-1)
_XYZ_TO_REC709 = np.array(
    [[3.2404542, -1.5371385, -0.4985314], [-0.9692660, 1.8760108, 0.0415560], [0.0556434, -0.2040259, 1.0572252]]
)
_WAVELENGTHS = np.arange(360.0, 831.0, 1.0)  # nm


def _cmf(wavelengths: np.ndarray) -> np.ndarray:
    out = np.zeros((3, len(wavelengths)))
    for i, lobes in enumerate(_CMF_LOBES):
        for weight, centre, below, above in lobes:
            sigma = np.where(wavelengths < centre, below, above)
            out[i] += weight * np.exp(-0.5 * ((wavelengths - centre) / sigma) ** 2)
    return out


def blackbody(kelvin: float) -> np.ndarray:
    """The linear Rec. 709 colour of a black body at `kelvin`, of luminance 1, as Cycles' Blackbody
    node gives it (clamped to Cycles' range, negative channels to 0): Planck's law integrated
    against the CIE 1931 colour matching functions (Wyman et al.'s fit), converted from XYZ.
    Within 1% of Blender's own conversion (Light.temperature_color) from 1000 K to 12000 K."""
    t = min(max(float(kelvin), BLACKBODY_RANGE[0]), BLACKBODY_RANGE[1])
    lam = _WAVELENGTHS
    planck = lam**-5.0 / np.expm1(1.4387769e7 / (lam * t))  # c2 = hc / k in nm K
    xyz = _cmf(lam) @ planck
    return np.maximum(_XYZ_TO_REC709 @ (xyz / xyz[1]), 0.0)


def to_scene_linear(rec709) -> np.ndarray:
    """A linear Rec. 709 colour in Blender's scene linear space (the same under the default
    configuration)."""
    from mathutils import Color

    return np.array(Color(tuple(float(c) for c in rec709)).from_rec709_linear_to_scene_linear()[:])


def temperature_tint(light) -> np.ndarray:
    """The factor a light's Temperature (Blender 4.5+: use_temperature) puts on its colour: Blender's
    own blackbody colour (luminance 1), which Cycles multiplies into the light's strength."""
    if getattr(light, "use_temperature", False):
        return np.array(light.temperature_color[:3], float)
    return np.ones(3)


def _linked_from(socket):
    """The node feeding an input (through reroutes), or None where it is unlinked."""
    while socket.is_linked:
        link = socket.links[0]
        if link.is_muted:
            return None
        node = link.from_node
        if node.type != "REROUTE":
            return node
        socket = node.inputs[0]
    return None


def node_tint(light) -> tuple[np.ndarray, str | None]:
    """The factor a light's node tree (use_nodes) puts on its power and colour where the tree is
    constant: its Emission node's Strength times its Color (a Blackbody node of constant
    temperature into that Color gives the blackbody colour), as Cycles multiplies the shader's
    emission into the light's strength; nothing into the output: 0 (Cycles' light is black).
    Otherwise (textures, Light Falloff, ...) (1, what is not constant): the light shines as
    without its nodes."""
    tree = light.node_tree if getattr(light, "use_nodes", False) else None
    if tree is None:
        return np.ones(3), None
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_LIGHT"]
    output = next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)
    if output is None:
        return np.ones(3), None
    node = _linked_from(output.inputs["Surface"])
    if node is None:
        return np.zeros(3), None
    if node.type != "EMISSION" or node.mute:
        return np.ones(3), f"node {node.name!r} into the output"
    strength = _linked_from(node.inputs["Strength"])
    if strength is not None:
        return np.ones(3), f"node {strength.name!r} into the Strength"
    colour = _linked_from(node.inputs["Color"])
    if colour is None:
        rgb = np.array(node.inputs["Color"].default_value[:3], float)
    elif colour.type == "BLACKBODY" and not colour.mute and _linked_from(colour.inputs["Temperature"]) is None:
        rgb = to_scene_linear(blackbody(colour.inputs["Temperature"].default_value))
    else:
        return np.ones(3), f"node {colour.name!r} into the Color"
    return rgb * node.inputs["Strength"].default_value, None


def _icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """A unit icosphere: vertices on the sphere, triangles wound outwards."""
    p = (1 + math.sqrt(5)) / 2
    V = [(-1, p, 0), (1, p, 0), (-1, -p, 0), (1, -p, 0), (0, -1, p), (0, 1, p)]
    V += [(0, -1, -p), (0, 1, -p), (p, 0, -1), (p, 0, 1), (-p, 0, -1), (-p, 0, 1)]
    vertices = [np.array(v, float) / np.linalg.norm(v) for v in V]
    F = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2)]
    F += [(10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5)]
    F += [(2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(subdivisions):
        middle: dict[tuple[int, int], int] = {}

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in middle:
                m = vertices[a] + vertices[b]
                vertices.append(m / np.linalg.norm(m))
                middle[key] = len(vertices) - 1
            return middle[key]

        F = [
            t
            for a, b, c in F
            for t in (
                (a, mid(a, b), mid(a, c)),
                (b, mid(b, c), mid(a, b)),
                (c, mid(a, c), mid(b, c)),
                (mid(a, b), mid(b, c), mid(a, c)),
            )
        ]
    return np.array(vertices), np.array(F)


SPHERE_SUBDIVISIONS = 2  # 320 triangles


def sphere_light(name: str, centre, radius: float, colour, power: float) -> scenes.SceneObject:
    """A point light of radius `radius` as Cycles renders it: a sphere emitting `power` (Blender's
    watts) uniformly over its surface, one-sided outwards, black (it reflects nothing): radiance
    power / (pi area), the area the mesh's own (an inscribed polyhedron, so that the power is kept)."""
    unit, triangles = _icosphere(SPHERE_SUBDIVISIONS)
    vertices = np.asarray(centre, float) + radius * unit
    P = vertices[triangles]
    area = 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1).sum()
    radiance = np.asarray(colour, float) * power / (math.pi * area)
    material = scenes.Material(np.zeros(3), radiance, name=name, one_sided=True)
    return scenes.SceneObject(name, vertices, triangles, material.color, material.emission, materials=[material])


SPOT_POINTS = 16  # the point spots a spot light with a radius is shown as


def ball_points(count: int) -> np.ndarray:
    """`count` points in the unit ball whose projection onto any plane through its centre is close
    to uniform on the unit disc (as a sphere of uniform radiance looks from any side): radial
    density 1 / sqrt(1 - s^2) (the inverse Abel transform of a constant), so radius s = sin u with
    u of density sin^2 u on [0, pi / 2]; stratified radii, directions on a Fibonacci sphere taken
    in a shuffled order (so that radius and direction do not correlate)."""
    u = np.linspace(0.0, math.pi / 2, 4097)
    cdf = (u - np.sin(u) * np.cos(u)) / (math.pi / 2)
    radius = np.sin(np.interp((np.arange(count) + 0.5) / count, cdf, u))
    k = np.arange(count)
    z = 1 - (2 * k + 1) / count
    phi = k * math.pi * (3 - math.sqrt(5))
    directions = np.stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z], -1)
    order = (k * _coprime_step(count)) % count
    return radius[:, None] * directions[order]


def _coprime_step(count: int) -> int:
    """A step near count times the golden ratio's fraction, coprime to count."""
    step = max(1, round(count * 0.618034))
    while math.gcd(step, count) != 1:
        step += 1
    return step


def spot_points(centre, radius: float, colour, power: float, **spot) -> list[scenes.PointLight]:
    """A spot light of radius `radius` as SPOT_POINTS point spots of power / SPOT_POINTS each,
    spread through its sphere (ball_points), each with the spot's cone: its shadows soft in
    SPOT_POINTS steps. (Cycles takes the cone from the sphere's centre, each point here from itself:
    the cone's edge moves by at most the radius.)"""
    offsets = radius * ball_points(SPOT_POINTS)
    share = power / SPOT_POINTS
    return [scenes.PointLight(np.asarray(centre, float) + d, colour, share, **spot) for d in offsets]
