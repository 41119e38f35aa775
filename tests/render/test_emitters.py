"""Emissive meshes and spot lights as lights, against closed forms and numerical integration.

An emitter of radiance Le gives a Lambert surface of base colour rho the radiance
rho / pi * integral Le cos cos' / J dA over every copy of the emitter in the universal cover within the
light reach (J the area density of the geodesic sphere, r^2 in E3, sin^2 r in S3). The tracer
estimates it from random points on the emitters (next-event estimation); the tests trace one pixel
many times (each ray its own random numbers), and compare the mean with the truth within four
standard errors measured from the spread of the estimates."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from thurston_addon import render, spaces
from thurston_addon.scenes import PointLight, Scene, SceneObject, flat_light

RHO, LE = 0.5, 2.0


def one_pixel(space, scene, origin, direction, reach, rays, light_samples, max_crossings=40):
    """The colours of `rays` identical rays (independent samples of the emitters)."""
    g = space.geometry
    tracer = render.make_tracer(space, scene, threads=2, light_reach=reach)
    o = np.repeat(np.array([origin], float), rays, axis=0)
    P = g.to_model(o)
    D = g.normalize_tangent(P, g.tangent_to_model(o, np.repeat(np.array([direction], float), rays, axis=0)))
    out = tracer.trace(
        np.ascontiguousarray(P),
        np.ascontiguousarray(D),
        5.0,
        max_crossings,
        shade=True,
        light_samples=light_samples,
        seed=7,
    )
    assert np.all(out["stop"] == 0)
    return out


def check_mean(colours, truth, relative_error):
    """The mean colour against the truth within 4 standard errors of the mean (from the samples'
    spread), and that spread small enough to tell a missing part of relative_error."""
    values = colours[:, 0].astype(float)
    mean, error = values.mean(), values.std(ddof=1) / math.sqrt(len(values))
    print(f"mean {mean:.6g} truth {truth:.6g} (relative {mean / truth - 1:+.2e}), standard error {error / truth:.1e}")
    assert error < relative_error / 4 * truth
    assert abs(mean - truth) < 4 * error


def polygon_irradiance(corners, p, n):
    """Lambert's closed form: the irradiance at p (normal n) from a polygon of unit radiance that lies
    wholly above p's tangent plane: half the sum over its edges of the edge's angle seen from p times
    n . (the unit normal of the plane through p and the edge)."""
    w = corners - p
    w = w / np.linalg.norm(w, axis=1)[:, None]
    total = 0.0
    for a, b in zip(w, np.roll(w, -1, axis=0)):
        c = np.cross(a, b)
        total += math.acos(np.clip(a @ b, -1, 1)) * (n @ c) / np.linalg.norm(c)
    return abs(total) / 2


def test_emissive_square_lights_a_plane_of_the_torus_from_every_copy_within_the_reach():
    """E3, the 3-torus: a floor spanning the domain (a plane in the cover, every 1 in z) lit by a
    square facing it 0.5 above, one-sided. A point of the floor sees the square's copies of its own
    layer (the floor's copy above hides the rest; the layer below is under the horizon); the truth
    is the sum of the square's closed-form irradiance over the copies within the reach, chosen so
    that no copy straddles it."""
    space = spaces.load("torus")
    half = 0.05
    floor = SceneObject(
        "floor",
        [[-0.5, -0.5, -0.3], [0.5, -0.5, -0.3], [0.5, 0.5, -0.3], [-0.5, 0.5, -0.3]],
        [[0, 1, 2], [0, 2, 3]],
        (RHO,) * 3,
    )
    centre = np.array([0.1, 0.05, 0.2])
    lamp = flat_light("lamp", centre, [half, 0, 0], [0, -half, 0], (LE,) * 3)  # facing down
    p, n = np.array([0.35, 0.3, -0.3]), np.array([0.0, 0.0, 1.0])
    square = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]) * half
    ranges = []
    for i, j in itertools.product(range(-4, 5), repeat=2):
        corners = centre + [i, j, 0] + square
        horizontal = corners[:, :2] - p[:2]
        nearest = np.clip(p[:2], corners[:, :2].min(axis=0), corners[:, :2].max(axis=0)) - p[:2]
        ranges.append(
            (
                math.hypot(0.5, np.linalg.norm(nearest)),
                max(math.hypot(0.5, np.linalg.norm(h)) for h in horizontal),
                corners,
            )
        )
    reach = 2.12
    assert all(far < reach - 0.003 or near > reach + 0.003 for near, far, _ in ranges)  # no copy straddles the reach
    within = [corners for _, far, corners in ranges if far < reach]
    assert len(within) > 4  # not just the nearest
    truth = RHO / math.pi * LE * sum(polygon_irradiance(c, p, n) for c in within)
    own = RHO / math.pi * LE * polygon_irradiance(ranges[40][2], p, n)  # (i, j) = (0, 0)
    print(f"{len(within)} copies within the reach; the square's own copy gives {own / truth:.2f} of the light")
    out = one_pixel(space, Scene(objects=[floor, lamp]), p + [0, 0, 0.2], [0, 0, -1], reach, 2000, 16)
    check_mean(out["color"], truth, min(0.01, 1 - own / truth))
    assert out["emitter_paths"] > 0 and out["light_paths"] == 0


def gnomonic_area_density(y, e1, e2):
    """Metric area per chart area of the gnomonic chart's plane spanned by the orthonormal chart
    vectors e1, e2 at chart points y (rows): the Gram determinant of the unit sphere point's
    derivatives along them (R^4, central differences)."""

    def point(q):
        Y = np.concatenate([q, np.ones((len(q), 1))], axis=1)
        return Y / np.linalg.norm(Y, axis=1)[:, None]

    h = 1e-6
    a = (point(y + h * e1) - point(y - h * e1)) / (2 * h)
    b = (point(y + h * e2) - point(y - h * e2)) / (2 * h)
    aa, bb, ab = (a * a).sum(1), (b * b).sum(1), (a * b).sum(1)
    return np.sqrt(aa * bb - ab * ab)


def test_emissive_square_in_the_poincare_sphere_against_integration_over_its_120_copies():
    """S3, the Poincare sphere: a small chart square (a geodesic quadrilateral) lights a tiny
    receiver; the truth integrates Le cos cos' / sin^2 d over each of the square's 120 copies
    (Gauss-Legendre in the chart times the gnomonic area density, cos and cos' from the unit
    vectors of R^4), along the short arcs only (-1 is in the group, so a long arc from an opaque
    point passes through it again). The square lights its front only (cos' > 0); in S3 that is
    every copy the receiver sees (the short arc stays in the receiver's half of S3 about the copy's
    great sphere, so the copy shows its front exactly where the receiver lies in front of it)."""
    space = spaces.load("poincare")
    g = space.geometry
    half = 0.01  # small: its copies hide under 0.1% of the sky from each other (they cast shadows)
    centre = np.array([0.05, 0.12, 0.02])
    # the front (u x v) faces -y, towards the receiver; its back faces the copies beyond
    u, v = np.array([half, 0, 0]), np.array([0, 0, half])
    lamp = flat_light("lamp", centre, u, v, (LE,) * 3)
    p = np.array([0.0, -0.08, 0.0])
    tri = np.array([[-1, 0, -1], [1, 0, -1], [0, 0, 1.5]]) * 0.002 + p  # shaded on the side the ray meets
    receiver = SceneObject("receiver", tri, [[0, 1, 2]], (RHO,) * 3)

    def normal(X, covector):  # the unit normal of the plane covector . X = 0 at X: its gradient on the sphere
        t = covector - (X @ covector)[..., None] * X
        return t / np.linalg.norm(t, axis=-1, keepdims=True)

    H = g.normalize_point(g.to_model(p[None]))[0]
    N = normal(H, np.array([0.0, 1.0, 0.0, -p[1]]))  # the receiver's plane y = p_y, towards the lamp
    nodes, weights = np.polynomial.legendre.leggauss(24)
    a, b = np.meshgrid(nodes, nodes, indexing="ij")
    w = np.outer(weights, weights).ravel()
    y = centre + a.ravel()[:, None] * u + b.ravel()[:, None] * v
    Y = g.normalize_point(g.to_model(y))
    Nl = normal(Y, np.array([0.0, -1.0, 0.0, centre[1]]))  # the lamp's plane y = centre_y, its front (-y)
    density = gnomonic_area_density(y, u / half, v / half) * half * half  # d(chart area) = half^2 da db
    total = 0.0
    group = space.elements_within(math.pi + 1e-6)
    assert len(group) == 120
    for M in group:
        Z, Nz = Y @ M.T, Nl @ M.T
        c = Z @ H
        d = np.arccos(np.clip(c, -1, 1))
        towards_light = (Z - c[:, None] * H) / np.sin(d)[:, None]
        towards_receiver = (H - c[:, None] * Z) / np.sin(d)[:, None]
        cos = towards_light @ N
        cos_light = (towards_receiver * Nz).sum(1)
        total += np.sum(w * density * np.clip(cos, 0, None) * np.clip(cos_light, 0, None) / np.sin(d) ** 2)
    truth = RHO / math.pi * LE * total
    out = one_pixel(space, Scene(objects=[lamp, receiver]), p + [0, 0.05, 0], [0, -1, 0], None, 4000, 8)
    check_mean(out["color"], truth, 0.02)


def test_spot_cone_and_blend_against_the_closed_form():
    """A spot light in the torus (spot size 70 degrees, blend 0.4) lighting a point of a small
    emissive ball (which casts no shadow on lamps' light): the sum over the lattice copies within
    the reach of cos * p / r^2 * smoothstep((cos theta - cos 35 deg) / ((1 - cos 35 deg) 0.4)), theta
    the angle at the copy between its axis and the direction to the point (Cycles' spot_attenuation);
    some copies are in the cone, some in its blend, some outside."""
    import trimesh

    space = spaces.load("torus")
    light, axis, power, reach = np.array([-0.2, 0.1, 0.3]), np.array([0.3, -0.2, -1.0]), 0.7, 2.5
    size, blend = math.radians(70), 0.4
    centre = np.array([0.1, 0.2, -0.15])
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.02)
    glow = 1e-4
    scene = Scene(
        objects=[SceneObject("ball", ball.vertices + centre, ball.faces, (RHO,) * 3, emission=(glow,) * 3)],
        lights=[PointLight(light, np.ones(3), power, spot_direction=axis, spot_size=size, spot_blend=blend)],
    )
    out = one_pixel(space, scene, centre + [0, -0.4, 0.1], centre - (centre + [0, -0.4, 0.1]), reach, 1, 1)
    x, n = out["position"][0], out["normal"][0].astype(float)
    cos_half = math.cos(size / 2)
    total, copies, cone, blending = 0.0, 0, 0, 0
    for k in itertools.product(range(-4, 5), repeat=3):
        v = light + np.array(k) - x
        r = np.linalg.norm(v)
        if r > reach:
            continue
        copies += 1
        f = (-v / r @ axis / np.linalg.norm(axis) - cos_half) / ((1 - cos_half) * blend)
        attenuation = 0.0 if f <= 0 else 1.0 if f >= 1 else f * f * (3 - 2 * f)
        cone += attenuation > 0
        blending += 0 < attenuation < 1
        if n @ v > 0:
            total += (n @ v / r) * power / r**2 * attenuation
    assert 0 < blending < cone < copies
    np.testing.assert_allclose(out["color"][0], glow + RHO * total, rtol=1e-4)


@pytest.mark.parametrize(
    "spec, message",
    [
        ('type = "sun"', "unknown light type 'sun'"),
        ('type = "spot"\ndirection = [0, 0, 0]', "direction must be a non-zero vector"),
        ('type = "spot"\ndirection = [0, 0, -1]\nspot_blend = 2', "spot blend must be in"),
        ('type = "spot"\ndirection = [0, 0, -1]\nspot_size = 200', "spot size must be an angle"),
        ('type = "area"\ndirection = [0, 0, -1]\nx_axis = [0, 0, 1]', "x_axis not along it"),
        ('type = "area"\nsize = [0.1, 0]', "positive size"),
    ],
)
def test_bad_lights_in_a_scene_file_are_one_clear_error(tmp_path, spec, message):
    from thurston_addon.scenes import SceneError, load_scene_file

    path = tmp_path / "scene.toml"
    path.write_text(f"[[light]]\nposition = [0, 0, 0.2]\n{spec}\n")
    with pytest.raises(SceneError, match=message):
        load_scene_file(path)


def test_an_area_light_in_a_scene_file_is_a_one_sided_emitter_facing_its_direction(tmp_path):
    from thurston_addon.scenes import load_scene_file

    path = tmp_path / "scene.toml"
    path.write_text(
        '[[light]]\ntype = "area"\nposition = [0.1, 0, 0.2]\ndirection = [0, 0, -2]\n'
        "size = [0.2, 0.1]\nemission = [3, 3, 3]\n"
    )
    (lamp,) = load_scene_file(path).objects
    P = lamp.vertices[lamp.triangles]
    normals = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    np.testing.assert_allclose(normals / np.linalg.norm(normals, axis=1)[:, None], [[0, 0, -1]] * 2)
    np.testing.assert_allclose(np.ptp(lamp.vertices, axis=0), [0.2, 0.1, 0.0])
    assert lamp.materials[0].one_sided and lamp.emission.tolist() == [3, 3, 3]
