"""Tests of the C++ core (thurston_core) against closed-form answers, with real Embree."""

import math
import threading
import time

import numpy as np
import pytest
import thurston_core as _core

from thurston_addon.render import core_scene

HALF = 0.5  # the E3 torus domain is the cube [-HALF, HALF]^3
GEOMETRY = {0: "E3", 1: "S3", -1: "H3"}  # the projective geometries by curvature


# --- scene construction -------------------------------------------------------------------------


def translation(v):
    m = np.eye(4)
    m[:3, 3] = v
    return m


def rotation(i, j, angle):
    """Rotation of R^4 in the (i, j) coordinate plane: e_i -> cos e_i + sin e_j."""
    m = np.eye(4)
    c, s = np.cos(angle), np.sin(angle)
    m[i, i], m[j, i], m[i, j], m[j, j] = c, s, -s, c
    return m


def boost(i, rapidity):
    """Lorentz boost in the (i, 3) plane, moving points along axis i by `rapidity`."""
    m = np.eye(4)
    c, s = np.cosh(rapidity), np.sinh(rapidity)
    m[i, i], m[i, 3], m[3, i], m[3, 3] = c, s, s, c
    return m


def cube_faces(half, w=None):
    """Covectors of the chart cube |x_i| <= half: (+-e_i, -half)."""
    faces = []
    for axis in range(3):
        for sign in (1.0, -1.0):
            c = np.zeros(4)
            c[axis] = sign
            c[3] = -half
            faces.append(c)
    return np.array(faces)


def torus_maps(half=HALF):
    """E3 cube torus: leaving through x_i = +half re-enters at x_i = -half, and vice versa."""
    maps = []
    for axis in range(3):
        for sign in (1.0, -1.0):
            v = np.zeros(3)
            v[axis] = -2.0 * half * sign
            maps.append(translation(v))
    return np.array(maps)


def s3_cube_maps():
    """Gnomonic cube |x_i| <= 1 (a cell of the 8-cell tiling of S3); the face x_i = 1 goes to
    x_i = -1 by the quarter rotation in the (i, 3) plane taking the neighbouring cell onto it."""
    maps = []
    for axis in range(3):
        maps.append(rotation(axis, 3, np.pi / 2))  # (X_i, X_3) -> (-X_3, X_i)
        maps.append(rotation(axis, 3, -np.pi / 2))  # its inverse, for the face x_i = -1
    return np.array(maps)


def h3_cube_maps(half):
    """Klein cube |x_i| <= half; faces paired by the boosts along the axes (an isometric face
    pairing, though not a manifold: enough for rays that cross faces away from edges)."""
    r = 2.0 * np.arctanh(half)
    maps = []
    for axis in range(3):
        maps.append(boost(axis, -r))
        maps.append(boost(axis, r))
    return np.array(maps)


def box_mesh(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    corners = np.array([[(hi if (i >> a) & 1 else lo)[a] for a in range(3)] for i in range(8)])
    quads = [(0, 2, 6, 4), (1, 5, 7, 3), (0, 4, 5, 1), (2, 3, 7, 6), (0, 1, 3, 2), (4, 6, 7, 5)]
    tris = [(q[0], q[1], q[2]) for q in quads] + [(q[0], q[2], q[3]) for q in quads]
    return corners, np.array(tris, dtype=np.int32)


def square_x(x, half_size):
    """Two triangles spanning the chart square {x} x [-s, s]^2."""
    s = half_size
    v = np.array([[x, -s, -s], [x, s, -s], [x, s, s], [x, -s, s]], float)
    return v, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)


def square_z(z, half_size):
    s = half_size
    v = np.array([[-s, -s, z], [s, -s, z], [s, s, z], [-s, s, z]], float)
    return v, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)


def make_tracer(
    curvature, faces, maps, meshes=(), colors=None, emissions=None, lights=(), threads=0, light_reach=math.inf
):
    """meshes: list of (vertices, triangles), one object each; lights: list of (lifts, radiance)."""
    vertices, triangles, objects = [np.zeros((0, 3))], [np.zeros((0, 3), np.int32)], [np.zeros(0, np.int32)]
    offset = 0
    for i, (v, t) in enumerate(meshes):
        vertices.append(v)
        triangles.append(t + offset)
        objects.append(np.full(len(t), i, np.int32))
        offset += len(v)
    n = len(meshes)
    colors = np.ones((n, 3), np.float32) if colors is None else np.asarray(colors, np.float32)
    emissions = np.zeros((n, 3), np.float32) if emissions is None else np.asarray(emissions, np.float32)
    lifts = [np.zeros((0, 4))] + [np.asarray(l, float).reshape(-1, 4) for l, _ in lights]
    of_lift = [np.zeros(0, np.int32)] + [np.full(len(l), i, np.int32) for i, l in enumerate(lifts[1:])]
    radiance = np.array([r for _, r in lights], np.float32).reshape(-1, 3)
    scene = _core.Scene(
        GEOMETRY[curvature],
        _core.Domain(np.asarray(faces, float).reshape(-1, 4), np.asarray(maps, float).reshape(-1, 4, 4)),
        _core.Meshes(np.concatenate(vertices), np.concatenate(triangles).astype(np.int32), np.concatenate(objects)),
        _core.Surfaces(colors, emissions),
        _core.Lights(np.concatenate(lifts), np.concatenate(of_lift), radiance, light_reach=light_reach),
    )
    return _core.Tracer(scene, threads=threads)


def e3_rays(origins, directions):
    origins = np.atleast_2d(np.asarray(origins, float))
    directions = np.atleast_2d(np.asarray(directions, float))
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    n = max(len(origins), len(directions))
    o = np.ones((n, 4))
    o[:, :3] = origins
    d = np.zeros((n, 4))
    d[:, :3] = directions
    return o, d


def random_directions(n, seed):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def origin_rays(curvature, directions):
    """Rays from the chart origin (model point e_3) with the given unit chart directions."""
    directions = np.atleast_2d(np.asarray(directions, float))
    o = np.zeros((len(directions), 4))
    o[:, 3] = 1.0
    d = np.zeros((len(directions), 4))
    d[:, :3] = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    return o, d


# --- closed-form truth in the E3 universal cover ---------------------------------------------------


def planes_crossed(o, p):
    """Number of torus face planes (x_i = HALF + k) strictly between chart points o and p."""
    cell = lambda x: np.floor((x + HALF) / (2 * HALF))
    return np.abs(cell(p) - cell(o)).sum(axis=-1).astype(int)


def lattice_box_hit(o, d, lo, hi, reach=6):
    """Distance from o along unit d to the nearest copy lo..hi + Z^3 (inf if none)."""
    best = np.full(len(d), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
    r = np.arange(-reach, reach + 1)
    for n in np.stack(np.meshgrid(r, r, r), -1).reshape(-1, 3):
        t0 = (lo + n - o) * inv
        t1 = (hi + n - o) * inv
        tmin = np.nanmax(np.minimum(t0, t1), axis=1)
        tmax = np.nanmin(np.maximum(t0, t1), axis=1)
        hit = (tmax >= tmin) & (tmin > 0)
        best = np.where(hit & (tmin < best), tmin, best)
    return best


# --- E3 ------------------------------------------------------------------------------------------

BOX_LO, BOX_HI = np.array([0.3, -0.1, -0.1]), np.array([0.4, 0.1, 0.1])


def test_box_straight_ahead_and_around_the_torus():
    tracer = make_tracer(0, cube_faces(HALF), torus_maps(), [box_mesh(BOX_LO, BOX_HI)])
    o, d = e3_rays([0, 0, 0], [[1, 0, 0], [-1, 0, 0]])
    r = tracer.trace(o, d, max_distance=10.0, max_crossings=10, shade=False)
    np.testing.assert_allclose(r["depth"], [0.3, 0.6], atol=1e-12)
    np.testing.assert_array_equal(r["crossings"], [0, 1])
    np.testing.assert_array_equal(r["stop"], [0, 0])
    np.testing.assert_array_equal(r["object"], [0, 0])
    np.testing.assert_allclose(r["position"], [[0.3, 0, 0], [0.4, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(r["normal"], [[-1, 0, 0], [1, 0, 0]], atol=1e-6)
    np.testing.assert_allclose(r["color"], np.ones((2, 3)))  # base colour without shading
    # The first chord of the second ray misses the scene's bounding box and is not queried.
    assert r["chords"].shape == () and r["chords"].dtype == np.int64 and int(r["chords"]) == 2


def test_random_rays_match_lattice_of_boxes():
    tracer = make_tracer(0, cube_faces(HALF), torus_maps(), [box_mesh(BOX_LO, BOX_HI)])
    origin = np.array([-0.2, 0.13, 0.07])
    d = random_directions(3000, 1)
    o, dm = e3_rays(origin, d)
    r = tracer.trace(o, dm, max_distance=5.0, max_crossings=1000, shade=False)
    truth = lattice_box_hit(origin, d, BOX_LO, BOX_HI)
    truth[truth > 5.0] = np.inf
    hit = np.isfinite(truth)
    assert hit.sum() > 300
    np.testing.assert_array_equal(np.isfinite(r["depth"]), hit)
    np.testing.assert_allclose(r["depth"][hit], truth[hit], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(r["stop"], np.where(hit, 0, 1))
    np.testing.assert_array_equal(r["object"], np.where(hit, 0, -1))
    # The hit point in the cover, reduced into the domain, and the faces crossed to get there.
    p = origin + truth[hit, None] * d[hit]
    np.testing.assert_array_equal(r["crossings"][hit], planes_crossed(origin, p))
    np.testing.assert_allclose(r["position"][hit], p - np.round(p), atol=1e-9)
    assert np.all(np.abs(r["position"][hit]) <= HALF)
    assert np.all(np.einsum("ij,ij->i", r["normal"][hit], d[hit]) < 0)
    np.testing.assert_allclose(np.linalg.norm(r["normal"][hit], axis=1), 1, atol=1e-6)
    assert np.all(np.isnan(r["position"][~hit])) and np.all(np.isnan(r["normal"][~hit]))


def test_empty_scene_distance_limit():
    tracer = make_tracer(0, cube_faces(HALF), torus_maps())
    assert tracer.num_triangles == 0
    origin = np.array([0.1, -0.2, 0.3])
    d = random_directions(2000, 2)
    o, dm = e3_rays(origin, d)
    r = tracer.trace(o, dm, max_distance=3.7, max_crossings=1000)
    assert np.all(np.isinf(r["depth"]))
    np.testing.assert_array_equal(r["stop"], 1)
    np.testing.assert_array_equal(r["distance"], 3.7)
    np.testing.assert_array_equal(r["crossings"], planes_crossed(origin, origin + 3.7 * d))
    np.testing.assert_array_equal(r["color"], 0)
    assert int(r["chords"]) == 0  # nothing to query in an empty scene


def test_crossing_limit():
    tracer = make_tracer(0, cube_faces(HALF), torus_maps())
    d = random_directions(500, 3)
    o, dm = e3_rays([0, 0, 0], d)
    r = tracer.trace(o, dm, max_distance=np.inf, max_crossings=2)
    np.testing.assert_array_equal(r["stop"], 2)
    np.testing.assert_array_equal(r["crossings"], 2)
    # The third face crossing, where the ray stops, in the cover: planes at 0.5, 1.5, ...
    times = np.sort(np.concatenate([(k + 0.5) / np.abs(d) for k in range(3)], axis=1), axis=1)
    np.testing.assert_allclose(r["distance"], times[:, 2], rtol=1e-12)


def test_no_leak_through_edges_and_vertices():
    rng = np.random.default_rng(4)
    n = 100_000
    origins = rng.uniform(-HALF, HALF, size=(n, 3))
    origins[: n // 10] = 0.0  # diagonal rays from the centre pass through a vertex every sqrt(3)
    targets = rng.choice([-HALF, HALF], size=(n, 3))
    edge = rng.random(n) < 0.5  # half aim at a point on an edge, half at a vertex
    targets[edge, 2] = rng.uniform(-HALF, HALF, size=edge.sum())
    targets += rng.integers(-2, 3, size=(n, 3))  # also at edges and vertices further away
    targets[:10] = rng.choice([-HALF, HALF], size=(10, 3))
    d = targets - origins
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o, dm = e3_rays(origins, d)
    tracer = make_tracer(0, cube_faces(HALF), torus_maps())
    r = tracer.trace(o, dm, max_distance=10.0, max_crossings=50)
    assert not np.isnan(r["distance"]).any()
    assert np.all(np.isin(r["stop"], [1, 2]))
    limit = r["stop"] == 1
    assert limit.mean() > 0.9
    np.testing.assert_array_equal(r["distance"][limit], 10.0)
    # Each plane passed in the cover is crossed exactly once, also at edges and vertices.
    end = origins + 10.0 * d
    np.testing.assert_array_equal(r["crossings"][limit], planes_crossed(origins, end)[limit])
    np.testing.assert_array_equal(r["crossings"][:10], 3 * 6)  # 6 vertices within 10


def test_lambert_plane_closed_form():
    # No faces: plain E3. A floor z = 0 lit by a point light; rays straight down onto it.
    floor = square_z(0.0, 5.0)
    light, radiance = np.array([0.3, 0.2, 2.0]), np.array([2.0, 1.0, 0.5])
    tracer = make_tracer(0, [], [], [floor], colors=[[0.5, 0.25, 1.0]], lights=[([*light, 1.0], radiance)])
    xs = np.linspace(-2, 2, 9)
    o, d = e3_rays(np.stack([xs, np.zeros(9), np.ones(9)], 1), [0, 0, -1])
    r = tracer.trace(o, d, max_distance=np.inf, max_crossings=0)
    h = np.stack([xs, np.zeros(9), np.zeros(9)], 1)
    r2 = np.sum((light - h) ** 2, axis=1)
    cos = light[2] / np.sqrt(r2)
    expected = np.array([0.5, 0.25, 1.0]) * radiance * (cos / r2)[:, None]
    np.testing.assert_allclose(r["color"], expected, rtol=1e-5)
    np.testing.assert_allclose(r["depth"], 1.0, atol=1e-12)
    np.testing.assert_array_equal(r["crossings"], 0)
    # Rays missing everything in a domain without faces run to infinity.
    o, d = e3_rays([0, 0, 1], [[0, 0, 1], [1, 0, 0]])
    r = tracer.trace(o, d, max_distance=np.inf, max_crossings=0)
    np.testing.assert_array_equal(r["stop"], 1)
    assert np.all(np.isinf(r["distance"])) and np.all(np.isinf(r["depth"]))


def test_shadows_emission_and_lamps():
    floor = square_z(0.0, 5.0)
    blocker = box_mesh([0.9, -0.1, 0.9], [1.1, 0.1, 1.1])  # halfway between (2,0,0) and the light
    lamp = box_mesh([-0.05, -0.05, 1.95], [0.05, 0.05, 2.05])  # emissive, around the light
    tracer = make_tracer(
        0,
        [],
        [],
        [floor, blocker, lamp],
        colors=[[1, 1, 1], [1, 1, 1], [0, 0, 0]],
        emissions=[[0, 0, 0], [0, 0, 0], [3, 2, 1]],
        lights=[([0, 0, 2, 1], [1, 1, 1])],
    )
    o, d = e3_rays([[2, 0, 1], [-2, 0, 1], [0, 0, 3]], [0, 0, -1])
    r = tracer.trace(o, d, max_distance=np.inf, max_crossings=0)
    np.testing.assert_array_equal(r["object"], [0, 0, 2])
    np.testing.assert_array_equal(r["color"][0], 0)  # in the blocker's shadow
    np.testing.assert_allclose(r["color"][1], 2 / 8**1.5, rtol=1e-5)  # the lamp casts no shadow
    np.testing.assert_allclose(r["color"][2], [3, 2, 1])  # lamp: its emission
    r = tracer.trace(o, d, max_distance=np.inf, max_crossings=0, shade=False)
    np.testing.assert_array_equal(r["color"], [[1, 1, 1], [1, 1, 1], [0, 0, 0]])


def test_light_through_a_face_sums_the_lifts_and_shadow_crosses():
    # Floor z = -0.3 across the torus cell; the light at (-0.45, 0, -0.1) reaches the hit point
    # (0.45, 0, -0.3) through the face x = 0.5 as its lift (0.55, 0, -0.1), the only one within 0.5.
    floor = square_z(-0.3, HALF)
    light = np.array([-0.45, 0.0, -0.1])
    lifts = [[*(light + n), 1.0] for n in np.stack(np.meshgrid(*[[-1, 0, 1]] * 3), -1).reshape(-1, 3)]
    o, d = e3_rays([0.45, 0, 0.2], [0, 0, -1])
    r2 = 0.1**2 + 0.2**2
    expected = 0.2 / np.sqrt(r2) / r2
    lit = make_tracer(0, cube_faces(HALF), torus_maps(), [floor], lights=[(lifts, [1, 1, 1])], light_reach=0.5)
    np.testing.assert_allclose(lit.trace(o, d, 10.0, 10)["color"][0], expected, rtol=1e-5)
    # Every lift: those above the floor's plane light it (cos / r^2); those above the floor's next
    # copy (z = 0.7) are shadowed by it, those below face its back.
    every = make_tracer(0, cube_faces(HALF), torus_maps(), [floor], lights=[(lifts, [1, 1, 1])])
    hit = np.array([0.45, 0.0, -0.3])
    above = [np.asarray(l[:3]) - hit for l in lifts if abs(l[2] + 0.1) < 1e-9]
    total = sum(v[2] / np.linalg.norm(v) ** 3 for v in above)
    np.testing.assert_allclose(every.trace(o, d, 10.0, 10)["color"][0], total, rtol=1e-5)
    # A blocker just inside x = -0.5 sits on that path in the neighbouring copy.
    blocker = box_mesh([-0.495, -0.05, -0.21], [-0.485, 0.05, -0.15])
    dark = make_tracer(
        0, cube_faces(HALF), torus_maps(), [floor, blocker], lights=[(lifts, [1, 1, 1])], light_reach=0.5
    )
    np.testing.assert_array_equal(dark.trace(o, d, 10.0, 10)["color"][0], 0)


def test_thread_count_does_not_change_results():
    meshes = [box_mesh(BOX_LO, BOX_HI), box_mesh([-0.3, 0.2, -0.4], [-0.1, 0.45, 0.3]), square_z(-0.45, HALF)]
    lights = [
        ([[0.1, 0.1, 0.1, 1.0], [1.1, 0.1, 0.1, 1.0]], [1, 0.5, 0.2]),
        ([[-0.2, -0.3, 0.2, 1.0]], [0.3, 0.3, 1.0]),
    ]
    d = random_directions(50_000, 5)
    o, dm = e3_rays([0.05, -0.1, 0.0], d)
    results = []
    for threads in (1, 2):
        tracer = make_tracer(
            0,
            cube_faces(HALF),
            torus_maps(),
            meshes,
            colors=[[1, 0, 0], [0, 1, 0], [0.5, 0.5, 0.5]],
            lights=lights,
            threads=threads,
        )
        assert tracer.num_threads == threads
        results.append(tracer.trace(o, dm, 8.0, 20, record_segments=True))
    one, two = results
    assert one.keys() == two.keys()
    for key in one:
        np.testing.assert_array_equal(one[key], two[key], err_msg=key)
    assert (one["stop"] == 0).mean() > 0.5


def test_recorded_segments_replay_on_query_segments():
    tracer = make_tracer(0, cube_faces(HALF), torus_maps(), [box_mesh(BOX_LO, BOX_HI)])
    o, d = e3_rays([-0.2, 0.13, 0.07], random_directions(3000, 6))
    r = tracer.trace(o, d, 5.0, 1000, shade=False, record_segments=True)
    starts, ends = r["segment_starts"], r["segment_ends"]
    assert starts.shape == ends.shape == (int(r["chords"]), 3)
    t, prim, _ = tracer.query_segments(starts, ends)
    assert t.dtype == np.float32 and prim.dtype == np.int32
    # Every ray stops at its first hit chord, so hit chords and hit rays correspond one to one.
    assert (prim >= 0).sum() == (r["stop"] == 0).sum()
    assert np.all(np.isinf(t[prim < 0])) and np.all((t[prim >= 0] >= 0) & (t[prim >= 0] <= 1))


def test_query_segments_against_a_box():
    tracer = make_tracer(0, [], [], [box_mesh([0, 0, 0], [1, 1, 1])])
    starts = np.array([[-1, 0.5, 0.5], [-1, 0.5, 0.5], [0.5, 0.5, -3.0], [2, 2, 2]])
    ends = np.array([[1, 0.5, 0.5], [-0.5, 0.5, 0.5], [0.5, 0.5, 1.0], [3, 3, 3]])
    t, prim, _ = tracer.query_segments(starts, ends)
    np.testing.assert_allclose(t, [0.5, np.inf, 0.75, np.inf])
    assert prim[0] >= 0 and prim[1] == -1 and prim[2] >= 0 and prim[3] == -1


# --- S3 and H3 ------------------------------------------------------------------------------------


def test_s3_depth_to_a_plane_and_through_a_face():
    d = 0.5  # the chart plane x = tan(d) lies at geodesic distance d from the origin
    tracer = make_tracer(1, cube_faces(1.0), s3_cube_maps(), [square_x(np.tan(d), 1.0)])
    phi = np.linspace(-0.6, 0.6, 7)
    dirs = np.stack([np.cos(phi), np.sin(phi), np.zeros(7)], 1)
    o, v = origin_rays(1, np.vstack([dirs, [[-1, 0, 0]]]))
    r = tracer.trace(o, v, max_distance=10.0, max_crossings=5, shade=False)
    expected = np.arctan(np.tan(d) / np.cos(phi))
    np.testing.assert_allclose(r["depth"][:7], expected, atol=1e-12)
    np.testing.assert_array_equal(r["crossings"], [0] * 7 + [1])
    # Backwards: out through x = -1 at pi/4, in at x = +1, back to the plane from behind.
    np.testing.assert_allclose(r["depth"][7], np.pi / 2 - d, atol=1e-12)
    np.testing.assert_allclose(r["position"][7], [np.tan(d), 0, 0], atol=1e-12)
    np.testing.assert_allclose(r["normal"][7], [1, 0, 0], atol=1e-6)


def test_h3_depth_to_a_plane_and_through_a_face():
    d, half = 0.3, 0.8  # the Klein chart plane x = tanh(d) lies at distance d from the origin
    tracer = make_tracer(-1, cube_faces(half), h3_cube_maps(half), [square_x(np.tanh(d), 0.5)])
    phi = np.linspace(-0.6, 0.6, 7)
    dirs = np.stack([np.cos(phi), np.zeros(7), np.sin(phi)], 1)
    o, v = origin_rays(-1, np.vstack([dirs, [[-1, 0, 0]]]))
    r = tracer.trace(o, v, max_distance=10.0, max_crossings=5, shade=False)
    expected = np.arctanh(np.tanh(d) / np.cos(phi))
    np.testing.assert_allclose(r["depth"][:7], expected, atol=1e-12)
    np.testing.assert_array_equal(r["crossings"], [0] * 7 + [1])
    np.testing.assert_allclose(r["depth"][7], 2 * np.arctanh(half) - d, atol=1e-12)
    np.testing.assert_allclose(r["normal"][7], [1, 0, 0], atol=1e-6)


def test_h3_origin_on_the_lower_sheet_is_the_same_chart_ray():
    half = 0.8
    tracer = make_tracer(-1, cube_faces(half), h3_cube_maps(half), [square_x(np.tanh(0.3), 0.5)])
    o, v = origin_rays(-1, [[1, 0.2, 0], [-1, 0.1, 0.1]])
    upper = tracer.trace(o, v, 10.0, 5)
    lower = tracer.trace(-o, -v, 10.0, 5)
    assert np.all(upper["stop"] == 0)
    for key in ("depth", "position", "crossings"):
        np.testing.assert_array_equal(upper[key], lower[key])


@pytest.mark.parametrize("curvature, falloff", [(1, np.sin), (-1, np.sinh)])
def test_curved_lambert_at_the_foot_point(curvature, falloff):
    # Light on the x axis at distance 0.1, plane perpendicular to it at distance 0.5: the ray along
    # the axis meets the plane at the light's foot point, cos = 1 and r = 0.4.
    d, ell = 0.5, 0.1
    chart = np.tan if curvature > 0 else np.tanh
    light = (
        np.array([np.sin(ell), 0, 0, np.cos(ell)]) if curvature > 0 else np.array([np.sinh(ell), 0, 0, np.cosh(ell)])
    )
    tracer = make_tracer(
        curvature,
        cube_faces(0.9),
        np.array([np.eye(4)] * 6),
        [square_x(chart(d), 0.5)],
        colors=[[0.5, 1, 1]],
        lights=[(light, [1, 2, 3])],
    )
    o, v = origin_rays(curvature, [[1, 0, 0]])
    r = tracer.trace(o, v, 10.0, 5)
    np.testing.assert_allclose(r["color"][0], np.array([0.5, 2, 3]) / falloff(d - ell) ** 2, rtol=1e-6)


@pytest.mark.parametrize("curvature", [1, -1])
def test_curved_spaces_without_faces_stop_cleanly(curvature):
    tracer = make_tracer(curvature, [], [], [square_x(0.5, 0.2)])
    o, v = origin_rays(curvature, np.vstack([[[1, 0, 0]], random_directions(200, 7)]))
    r = tracer.trace(o, v, max_distance=1000.0, max_crossings=5)
    assert r["stop"][0] == 0
    assert np.all(np.isin(r["stop"], [0, 1]))
    for key in ("depth", "distance", "color"):
        assert not np.isnan(r[key]).any(), key


# --- degenerate input, progress, cancel, errors ------------------------------------------------


def test_degenerate_rays_do_not_produce_nan():
    tracer = make_tracer(0, cube_faces(HALF), torus_maps(), [box_mesh(BOX_LO, BOX_HI)])
    o = np.array([[0, 0, 0, 1], [0, 0, 0, 0], [0, 0, 0, 1.0]])
    d = np.array([[0, 0, 0, 0], [1, 0, 0, 0], [1e-300, 0, 0, 0.0]])
    r = tracer.trace(o, d, 10.0, 10)
    np.testing.assert_array_equal(r["stop"][:2], 1)
    assert not np.isnan(r["distance"]).any() and not np.isnan(r["color"]).any()


def many_rays(n=400_000):
    o, d = e3_rays([0.01, 0.02, 0.03], random_directions(n, 8))
    return o, d


def test_progress_false_cancels_everything_at_the_start():
    tracer = make_tracer(0, cube_faces(HALF), torus_maps(), [box_mesh(BOX_LO, BOX_HI)])
    calls = []
    o, d = many_rays(5000)
    r = tracer.trace(o, d, 10.0, 10, progress=lambda done, total: calls.append((done, total)) or False)
    assert calls == [(0, 5000)]
    np.testing.assert_array_equal(r["stop"], 3)
    assert np.all(np.isinf(r["depth"])) and np.all(r["object"] == -1)


def test_progress_reports_and_can_stop_midway():
    tracer = make_tracer(0, cube_faces(HALF), torus_maps(), [box_mesh(BOX_LO, BOX_HI)], threads=2)
    o, d = many_rays()
    calls = []

    def progress(done, total):
        calls.append(done)
        return len(calls) < 2  # stop at the first report after the start

    r = tracer.trace(o, d, 200.0, 1000, progress=progress)
    assert calls[0] == 0 and all(0 <= c <= len(o) for c in calls)
    stopped = r["stop"] == 3
    if len(calls) == 2 and calls[1] < len(o):  # the trace outlived the first 0.1 s
        assert stopped.any()
    assert np.all(np.isinf(r["depth"][stopped])) and np.all(r["crossings"][stopped] == 0)
    assert np.all(r["stop"][~stopped] < 3)


def test_progress_runs_to_completion():
    tracer = make_tracer(0, cube_faces(HALF), torus_maps(), [box_mesh(BOX_LO, BOX_HI)])
    o, d = many_rays(3000)
    calls = []
    r = tracer.trace(o, d, 10.0, 10, progress=lambda done, total: calls.append((done, total)))
    assert calls[0] == (0, 3000) and calls[-1] == (3000, 3000)
    assert np.all(r["stop"] < 3)


def test_cancel_from_another_thread():
    tracer = make_tracer(0, cube_faces(HALF), torus_maps(), [box_mesh(BOX_LO, BOX_HI)], threads=2)
    o, d = many_rays()
    started = threading.Event()
    canceller = threading.Thread(target=lambda: started.wait(30) and tracer.cancel())
    canceller.start()
    r = tracer.trace(o, d, 200.0, 1000, progress=lambda done, total: started.set())
    canceller.join()
    assert (r["stop"] == 3).any()
    # A later trace is not affected by the earlier cancel.
    assert np.all(tracer.trace(o[:100], d[:100], 10.0, 10)["stop"] < 3)


def test_cancel_stops_a_ray_that_never_ends():
    """One ray through an empty torus with limits it never reaches: cancel() ends it inside its walk
    (measured well under 0.2 s; 5 s allowed), marked cancelled, not after its 2^31 crossings."""
    tracer = make_tracer(0, cube_faces(HALF), torus_maps(), threads=1)
    o, d = e3_rays([0.01, 0.02, 0.03], [[1.0, 0.3, 0.2]])
    threading.Timer(0.3, tracer.cancel).start()
    start = time.perf_counter()
    r = tracer.trace(o, d, 1e300, 2**31 - 1, progress=lambda done, total: True)
    took = time.perf_counter() - start - 0.3
    print(f"cancelled {took:.3f} s after cancel()")
    assert r["stop"][0] == 3 and took < 5.0


def test_exception_in_progress_propagates():
    tracer = make_tracer(0, cube_faces(HALF), torus_maps(), [box_mesh(BOX_LO, BOX_HI)])
    o, d = many_rays(3000)

    def progress(done, total):
        raise RuntimeError("stop here")

    with pytest.raises(RuntimeError, match="stop here"):
        tracer.trace(o, d, 10.0, 10, progress=progress)
    assert np.all(tracer.trace(o, d, 10.0, 10)["stop"] < 3)


def test_tracer_cannot_be_reentered_from_its_callback():
    tracer = make_tracer(0, cube_faces(HALF), torus_maps(), [box_mesh(BOX_LO, BOX_HI)])
    o, d = many_rays(10)
    with pytest.raises(RuntimeError, match="own progress callback"):
        tracer.trace(o, d, 10.0, 10, progress=lambda done, total: tracer.trace(o, d, 1.0, 1))


def scene_arrays():
    v, t = box_mesh(BOX_LO, BOX_HI)
    return dict(
        geometry="E3",
        face_covectors=cube_faces(HALF),
        face_maps=torus_maps(),
        vertices=v,
        triangles=t,
        triangle_object=np.zeros(len(t), np.int32),
        object_color=np.ones((1, 3), np.float32),
        object_emission=np.zeros((1, 3), np.float32),
        light_lifts=np.array([[0, 0, 0, 1.0]]),
        light_of_lift=np.zeros(1, np.int32),
        light_radiance=np.ones((1, 3), np.float32),
    )


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(geometry="Flat"), r"unknown geometry 'Flat' \(known: E3, S3, H3, Nil, Sol, H2xR, S2xR, SL2, graph\)"),
        (
            dict(face_covectors=cube_faces(HALF).astype(np.float32)),
            r"face_covectors must have dtype float64, got float32",
        ),
        (dict(face_maps=torus_maps()[:5]), r"face_maps must have shape \(F,4,4\) with F = len"),
        (dict(vertices=np.ones((8, 2))), r"vertices must have shape \(NV,3\), got \(8, 2\)"),
        (
            dict(vertices=np.where(np.arange(24).reshape(8, 3) == 4, np.nan, 0.1)),
            "vertices contain NaN or inf at row 1",
        ),
        (dict(triangles=np.full((12, 3), 8, np.int32)), "triangles has vertex index 8"),
        (dict(triangles=np.zeros((12, 3), np.int64)), "triangles must have dtype int32, got int64"),
        (dict(triangle_object=np.ones(12, np.int32)), "triangle_object has index 1 at row 0"),
        (dict(object_emission=np.zeros((2, 3), np.float32)), r"object_emission must have shape"),
        (dict(light_of_lift=np.array([3], np.int32)), "light_of_lift has index 3"),
        (dict(light_lifts=np.array([[0, 0, 0, 0.0]])), "light_lifts row 0 is not a point"),
    ],
)
def test_constructor_errors(change, message):
    args = scene_arrays() | change
    with pytest.raises(ValueError, match=message):
        _core.Tracer(core_scene(args))


def test_hyperbolic_vertices_must_be_in_the_ball():
    args = scene_arrays() | dict(geometry="H3", vertices=box_mesh([0.5, 0.5, 0.5], [0.7, 0.7, 0.7])[0])
    with pytest.raises(ValueError, match="inside the unit ball"):
        _core.Tracer(core_scene(args))


def test_zero_triangles_allowed_and_lists_rejected():
    args = scene_arrays() | dict(
        vertices=np.zeros((0, 3)), triangles=np.zeros((0, 3), np.int32), triangle_object=np.zeros(0, np.int32)
    )
    assert _core.Tracer(core_scene(args)).num_triangles == 0
    with pytest.raises(TypeError):
        _core.Tracer(core_scene(args | dict(vertices=[[0.0, 0.0, 0.0]])))


def test_trace_errors():
    tracer = _core.Tracer(core_scene(scene_arrays()))
    o, d = e3_rays(np.zeros((5, 3)), [1, 0, 0])
    bad = d.copy()
    bad[3, 1] = np.inf
    with pytest.raises(ValueError, match="ray 3 has a non-finite origin or direction"):
        tracer.trace(o, bad, 1.0, 1)
    with pytest.raises(ValueError, match=r"directions must have shape \(N,4\) with N = len"):
        tracer.trace(o, d[:4], 1.0, 1)
    with pytest.raises(ValueError, match="origins must have dtype float64"):
        tracer.trace(o.astype(np.float32), d, 1.0, 1)
    with pytest.raises(ValueError, match="max_distance"):
        tracer.trace(o, d, -1.0, 1)
    with pytest.raises(ValueError, match="max_crossings"):
        tracer.trace(o, d, 1.0, -1)
    with pytest.raises(ValueError, match="tolerance must be a positive"):
        tracer.trace(o, d, 1.0, 1, tolerance=0.0)
    with pytest.raises(ValueError, match="tolerance_per_distance must be"):
        tracer.trace(o, d, 1.0, 1, tolerance_per_distance=np.nan)
    # Strided (non-contiguous) input is read in place.
    wide = np.zeros((5, 8))
    wide[:, ::2] = o
    np.testing.assert_array_equal(tracer.trace(wide[:, ::2], d, 1.0, 1)["depth"], tracer.trace(o, d, 1.0, 1)["depth"])
