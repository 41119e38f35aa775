"""End-to-end tests of the render pipeline (spaces -> compile_scene -> C++ tracer -> passes) against
closed forms: ray-sphere distances to every copy of a geodesic ball under the group, lattice
crossing counts, Lambert shading, and the behaviour of render() itself."""

import math
import os
import subprocess
import sys
import textwrap
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import trimesh
from support.presets import presets

from thurston_addon import passes, render, spaces
from thurston_addon.scenes import Camera, PointLight, Scene, SceneError, SceneObject, default_scene

ORIGIN = np.array([0.0, 0.0, 0.0, 1.0])
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def space_cache():
    cache = {}

    def get(sid):
        if sid not in cache:
            cache[sid] = spaces.load(sid)
        return cache[sid]

    return get


# --- helpers: geodesic balls and closed-form first hits ----------------------------------------------
def chart_radius(g, rho):
    """Chart (gnomonic / Klein / Euclidean) radius of the geodesic ball of radius rho about O."""
    return {0: rho, 1: math.tan(rho), -1: math.tanh(rho)}[g.curvature]


def geodesic_radius(g, r):
    return {0: r, 1: math.atan(r), -1: math.atanh(r)}[g.curvature]


def ball_mesh(g, centre_dir, centre_dist, rho, subdivisions=5):
    """A polyhedral geodesic ball: the chart icosphere about O (its vertices on the geodesic sphere
    of radius rho) moved by the translation taking O to the centre. Returns (vertices, faces,
    centre as a model point, geodesic sagitta: the largest distance between faces and sphere)."""
    ico = trimesh.creation.icosphere(subdivisions=subdivisions, radius=chart_radius(g, rho))
    V, F = np.asarray(ico.vertices, float), np.asarray(ico.faces)
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(B - A, C - A)
    h = np.min(np.abs(np.einsum("ij,ij->i", n, A)) / np.linalg.norm(n, axis=1))
    sagitta = rho - geodesic_radius(g, h)
    if centre_dist == 0:
        return V, F, ORIGIN.copy(), sagitta
    T = g.translation(centre_dir, centre_dist)
    return g.transform_points(T, V), F, T[:, 3].copy(), sagitta


def first_entry(g, P, V, centres, rho):
    """Closed-form arclength at which the geodesic from P (model) with unit tangent V first enters
    one of the geodesic balls of radius rho about the model points `centres`, and the cosine of
    the angle of incidence there. (N,) arrays; inf / 0 where no ball is entered."""
    k = g.curvature
    with np.errstate(invalid="ignore", divide="ignore"):
        if k == 0:
            w = P[:, None, :3] - centres[None, :, :3]
            b = np.einsum("nj,nkj->nk", V[:, :3], w)
            q = np.einsum("nkj,nkj->nk", w, w) - rho * rho
            disc = b * b - q
            t = -b - np.sqrt(disc)
            cos = np.sqrt(disc) / rho
            ok = (disc > 0) & (t > 0)
        elif k > 0:
            A, B = P @ centres.T, V @ centres.T
            R = np.hypot(A, B)
            alpha = np.arccos(np.clip(math.cos(rho) / R, -1, 1))
            t = np.mod(np.arctan2(B, A) - alpha, 2 * math.pi)
            cos = np.sqrt(np.maximum(R * R - math.cos(rho) ** 2, 0)) / math.sin(rho)
            ok = R > math.cos(rho)
        else:
            J = np.array([1.0, 1.0, 1.0, -1.0])
            a, b = -(P * J) @ centres.T, -(V * J) @ centres.T
            kk = math.cosh(rho)
            disc = kk * kk - a * a + b * b
            u = (kk - np.sqrt(disc)) / (a + b)
            t = np.log(u)
            cos = np.sqrt(disc) / math.sinh(rho)
            ok = (disc > 0) & (u > 1)
    t = np.where(ok, t, np.inf)
    j = np.argmin(t, axis=1)
    rows = np.arange(len(P))
    return t[rows, j], np.where(ok[rows, j], cos[rows, j], 0.0)


def model_rays(g, p, u):
    """Model origins and unit model tangents from chart points p and chart directions u."""
    X = g.to_model(p)
    return X, g.normalize_tangent(X, g.tangent_to_model(p, u))


def random_units(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def edge_targets(space, rng, n):
    """n chart points on the domain's edges, the vertices among them."""
    V = space.domain.vertices
    E = np.array([e[:2] for e in space.domain.edges])
    pick = E[rng.integers(len(E), size=n)]
    s = rng.random(n)
    s[: n // 5] = rng.integers(0, 2, size=n // 5)  # a fifth exactly at vertices
    return s[:, None] * V[pick[:, 0]] + (1 - s[:, None]) * V[pick[:, 1]]


def interior_points(space, rng, n, fraction=0.8):
    """n chart points in the chart ball about the origin that the domain contains."""
    r = fraction * space.chart_inradius
    return random_units(rng, n) * (r * rng.random(n) ** (1 / 3))[:, None]


def sphere_scene(V, F):
    return Scene(objects=[SceneObject("ball", V, F, (0.5, 0.5, 0.5))])


def check_against_balls(space, V, F, centre, rho, sagitta, P, D, max_distance, max_crossings=400):
    """Trace and compare with the closed-form first entry into the group's copies of the ball."""
    g = space.geometry
    tracer = render.make_tracer(space, sphere_scene(V, F))
    out = tracer.trace(np.ascontiguousarray(P), np.ascontiguousarray(D), max_distance, max_crossings, shade=False)
    reach = max_distance + rho + g.distance(ORIGIN, centre) + float(np.max(g.distance(ORIGIN, P)))
    elements = space.elements_within(reach if g.curvature <= 0 else math.pi + 1e-6)
    centres = np.array([M @ centre for M in elements])
    # the origins must lie outside every copy
    dmin = np.min(g.distance(P[:, None, :], centres[None, :, :]), axis=-1)
    assert np.all(dmin > rho + 1e-3), "test set-up: a ray starts inside a copy of the ball"
    t, cos = first_entry(g, P, D, centres, rho)
    tol = 2 * sagitta / np.maximum(cos, 1e-3) + 1e-6
    hit = (t < max_distance - tol) & (cos > 0.3)
    miss = t > max_distance + 1e-6
    assert hit.sum() > 200 and miss.sum() > 50, (hit.sum(), miss.sum())
    assert np.all(out["stop"][hit] == 0), f"{np.sum(out['stop'][hit] != 0)} rays missed a ball they enter"
    err = np.abs(out["depth"][hit] - t[hit])
    worst = int(np.argmax(err / tol[hit]))
    assert np.all(err <= tol[hit]), (
        f"depth off by {err[worst]:.3g} (tolerance {tol[hit][worst]:.3g}) at analytic depth {t[hit][worst]:.4f}, "
        f"traced {out['depth'][hit][worst]:.4f}"
    )
    # rays that stay clear of every copy (the polyhedron lies inside the ball) find nothing
    assert np.all(out["stop"][miss] == 1), np.bincount(out["stop"][miss])
    assert np.all(np.isinf(out["depth"][miss]))
    # hit positions: chart points on the domain side, in the domain
    X = g.to_model(out["position"][hit])
    assert np.all(space.domain.contains(X, tol=1e-6))
    return hit.sum()


CASES = {
    # space: (chart direction of the centre, its geodesic distance from O, geodesic radius, max distance,
    # radius of the ball of ray origins as a fraction of the inradius)
    "torus": ([0.6, 0.3, -0.5], 0.3, 0.15, 4.0, 0.8),
    "quarter_turn": ([0.2, -0.5, 0.4], 0.3, 0.12, 4.0, 0.8),
    "hantzsche_wendt": ([0.5, 0.4, 0.3], 0.35, 0.15, 4.0, 0.8),
    "poincare": ([0.3, 0.2, -0.4], 0.15, 0.1, 6.0, 0.8),
    # H3: the group grows exponentially; keep the enumeration radius near 3.2
    "seifert_weber": ([0.2, 0.7, 0.3], 0.3, 0.25, 2.4, 0.3),
}


@pytest.mark.parametrize("sid", list(CASES))
def test_depth_matches_closed_form_ball_copies(space_cache, sid):
    space = space_cache(sid)
    g = space.geometry
    direction, dist, rho, max_distance, spread = CASES[sid]
    V, F, centre, sagitta = ball_mesh(g, direction, dist, rho)
    assert sagitta < 5e-4 * max(rho, 0.1)
    rng = np.random.default_rng(1)
    n = 1500
    # from the domain centre in random directions, and aimed at edges and vertices
    p0 = np.zeros((2 * n, 3))
    u0 = np.vstack([random_units(rng, n), edge_targets(space, rng, n)])
    # from random interior points (away from the ball) in random directions
    p1 = interior_points(space, rng, 4 * n, spread)
    c_chart = g.to_chart(centre)
    p1 = p1[np.linalg.norm(p1 - c_chart, axis=1) > 2.5 * chart_radius(g, rho)][:n]
    u1 = random_units(rng, len(p1))
    P, D = model_rays(g, np.vstack([p0, p1]), np.vstack([u0, u1]))
    hits = check_against_balls(space, V, F, centre, rho, sagitta, P, D, max_distance)
    assert hits > 300


# --- objects that straddle faces ---------------------------------------------------------------------
def test_straddling_ball_on_torus_face(space_cache):
    space = space_cache("torus")
    g = space.geometry
    rho = 0.2
    V, F, centre, sag = ball_mesh(g, [1, 0, 0], 0.5, rho)
    tracer = render.make_tracer(space, sphere_scene(V, F))
    dirs = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    P, D = model_rays(g, np.zeros((2, 3)), dirs)
    out = tracer.trace(P, D, 5.0, 20, shade=False)
    assert list(out["stop"]) == [0, 0]
    np.testing.assert_allclose(out["depth"], 0.3, atol=2 * sag + 1e-6)
    # towards -x the ray crosses no face: it meets the part re-entering through x = -0.5
    assert list(out["crossings"]) == [0, 0]
    np.testing.assert_allclose(out["position"][1], [-0.3, 0, 0], atol=2 * sag + 1e-6)
    # and everywhere else as the closed form over the lattice copies says
    rng = np.random.default_rng(2)
    P, D = model_rays(g, np.zeros((3000, 3)), random_units(rng, 3000))
    check_against_balls(space, V, F, centre, rho, sag, P, D, 3.0)


def test_straddling_ball_on_torus_vertex(space_cache):
    space = space_cache("torus")
    g = space.geometry
    rho = 0.2
    V, F, centre, sag = ball_mesh(g, [1, 1, 1], math.sqrt(3) / 2, rho)
    np.testing.assert_allclose(g.to_chart(centre), [0.5, 0.5, 0.5], atol=1e-12)
    tracer = render.make_tracer(space, sphere_scene(V, F))
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    P, D = model_rays(g, np.zeros((8, 3)), corners)
    out = tracer.trace(P, D, 5.0, 20, shade=False)
    assert np.all(out["stop"] == 0)
    np.testing.assert_allclose(out["depth"], math.sqrt(3) / 2 - rho, atol=2 * sag + 1e-6)
    hitpoints = corners / np.linalg.norm(corners, axis=1)[:, None] * (math.sqrt(3) / 2 - rho)
    np.testing.assert_allclose(out["position"], hitpoints, atol=2 * sag + 1e-6)
    rng = np.random.default_rng(3)
    P, D = model_rays(g, interior_points(space, rng, 3000, 0.5), random_units(rng, 3000))
    check_against_balls(space, V, F, centre, rho, sag, P, D, 3.0)


def test_object_reaching_two_domains_away_is_whole(space_cache):
    """A bar at y = 0.2 spanning x in [1.05, 1.55] lies outside the torus's domain; its parts come
    back through one (x - 1) and two (x - 2) face crossings. A ray along +y at x = -0.48 can only
    meet the part two domains away, at depth 0.2 - 0.025."""
    space = space_cache("torus")
    g = space.geometry
    bar = trimesh.creation.box(extents=[0.5, 0.05, 0.05])
    bar.apply_translation([1.3, 0.2, 0.0])
    tracer = render.make_tracer(space, Scene(objects=[SceneObject("bar", bar.vertices, bar.faces)]))
    P, D = model_rays(g, np.array([[-0.48, 0, 0], [0.3, 0, 0], [-0.3, 0, 0]]), np.array([[0, 1.0, 0]] * 3))
    out = tracer.trace(P, D, 0.5, 4, shade=False)
    np.testing.assert_allclose(out["depth"][:2], 0.175, atol=1e-9)
    assert out["stop"][2] == 1  # x = -0.3 maps to 0.7 and 1.7: the bar is not there


@pytest.mark.parametrize(
    "sid, word", [("torus", (0, 0, 0, 0, 2, 2, 2)), ("poincare", (0, 0)), ("seifert_weber", (0, 0))]
)
def test_object_far_out_in_the_cover_is_brought_in(space_cache, sid, word):
    """A ball placed by a word in the face pairings, outside the domain and its neighbouring copies
    (H3: 4 from the centre; farther, chart coordinates lose the ball's shape), is the same point set
    of the manifold as the ball at home: the depths are the closed-form first entries into the copies
    of the ball at home."""
    space = space_cache(sid)
    g = space.geometry
    rho = 0.08
    V, F, centre, sag = ball_mesh(g, np.array([0.3, -0.5, 0.8]), 0.12, rho, subdivisions=4)
    M = np.eye(4)
    for k in word:
        M = space.domain.faces[k].pairing @ M
    far = g.to_chart(g.to_model(V) @ M.T)
    assert not space.domain.contains(g.to_model(far.mean(axis=0)))
    rng = np.random.default_rng(11)
    P, D = model_rays(g, np.zeros((3000, 3)), random_units(rng, 3000))
    check_against_balls(space, far, F, centre, rho, sag, P, D, 2.0)


def test_straddling_ball_on_poincare_face(space_cache):
    space = space_cache("poincare")
    g = space.geometry
    rho = 0.1
    face = space.domain.faces[0]
    mid = g.normalize_point(ORIGIN + face.element[:, 3])  # the face centre: midpoint of O and gO
    n = g.to_chart(mid)
    assert abs(g.distance(ORIGIN, mid) - math.pi / 10) < 1e-9
    V, F, centre, sag = ball_mesh(g, n, math.pi / 10, rho)
    np.testing.assert_allclose(centre, mid, atol=1e-12)
    partner = space.domain.faces[face.partner]
    m2 = g.to_chart(g.normalize_point(ORIGIN + partner.element[:, 3]))
    tracer = render.make_tracer(space, sphere_scene(V, F))
    P, D = model_rays(g, np.zeros((2, 3)), np.array([n, m2]))
    out = tracer.trace(P, D, 10.0, 100, shade=False)
    assert list(out["stop"]) == [0, 0]
    np.testing.assert_allclose(out["depth"], math.pi / 10 - rho, atol=2 * sag + 1e-6)
    rng = np.random.default_rng(4)
    P, D = model_rays(g, np.zeros((3000, 3)), random_units(rng, 3000))
    check_against_balls(space, V, F, centre, rho, sag, P, D, 5.0)


# --- no leaks at edges and vertices ----------------------------------------------------------------------
def check_trace_outputs(space, out, max_distance, max_crossings, n_objects):
    g = space.geometry
    stop, hit = out["stop"], out["stop"] == 0
    assert set(np.unique(stop)) <= {0, 1, 2}, np.bincount(stop)
    if n_objects == 0:
        assert not hit.any()
    for key in ("distance", "color"):
        assert np.all(np.isfinite(out[key])), key
    assert np.all(out["crossings"] >= 0) and np.all(out["crossings"] <= max_crossings)
    d = out["distance"]
    assert np.all(d >= 0) and np.all(d <= max_distance * (1 + 1e-12))
    np.testing.assert_allclose(d[stop == 1], max_distance, rtol=1e-12)
    assert np.all(out["crossings"][stop == 2] == max_crossings)
    assert np.all(np.isinf(out["depth"][~hit])) and np.all(out["object"][~hit] == -1)
    assert np.all(np.isnan(out["position"][~hit])) and np.all(np.isnan(out["normal"][~hit]))
    if hit.any():
        assert np.all(np.isfinite(out["depth"][hit]))
        np.testing.assert_allclose(out["depth"][hit], d[hit], rtol=1e-12)
        assert np.all(np.isfinite(out["position"][hit])) and np.all(np.isfinite(out["normal"][hit]))
        np.testing.assert_allclose(np.linalg.norm(out["normal"][hit], axis=1), 1.0, atol=1e-4)
        assert np.all((out["object"][hit] >= 0) & (out["object"][hit] < n_objects))
        inside = space.domain.contains(g.to_model(out["position"][hit]), tol=1e-6)
        assert inside.all(), f"{(~inside).sum()} hit positions outside the domain"


@pytest.mark.parametrize("sid", presets())
def test_no_leak_at_edges_and_vertices(space_cache, sid):
    space = space_cache(sid)
    if not space.domain.edges:
        pytest.skip("a shell domain has no edges or vertices (test_s2xr.py shoots its radial and tangential rays)")
    g = space.geometry
    rng = np.random.default_rng(5)
    n = 100_000
    targets = edge_targets(space, rng, n)
    p = np.zeros((n, 3))
    p[n // 2 :] = interior_points(space, rng, n - n // 2)
    P, D = model_rays(g, p, targets - p)
    assert np.all(np.isfinite(P)) and np.all(np.isfinite(D))
    max_distance, max_crossings = (3.0 if g.name == "H3" else 6.0), 40
    scenes = [Scene()]
    if sid in ("poincare", "seifert_weber", "torus"):
        scenes.append(default_scene(space))
    for scene in scenes:
        out = render.make_tracer(space, scene).trace(P, D, max_distance, max_crossings, shade=True)
        check_trace_outputs(space, out, max_distance, max_crossings, len(scene.objects))
        if scene.objects:
            assert (out["stop"] == 0).mean() > 0.2


def test_torus_crossings_count_lattice_planes(space_cache):
    """A straight line of length L crosses the planes x_i = k + 1/2 of the cube lattice once each."""
    space = space_cache("torus")
    g = space.geometry
    rng = np.random.default_rng(6)
    n = 20000
    L = 7.318309886
    p = np.zeros((n, 3))
    p[n // 2 :] = rng.uniform(-0.45, 0.45, size=(n - n // 2, 3))
    d = random_units(rng, n)
    e = p + L * d
    frac = np.abs((e + 0.5) - np.round(e + 0.5))
    keep = np.all(frac > 1e-6, axis=1)
    expected = np.sum(np.abs(np.floor(e + 0.5) - np.floor(p + 0.5)), axis=1).astype(int)
    P, D = model_rays(g, p, d)
    out = render.make_tracer(space, Scene()).trace(P, D, L, 1000, shade=False)
    assert np.all(out["stop"] == 1)
    assert keep.mean() > 0.99
    np.testing.assert_array_equal(out["crossings"][keep], expected[keep])


# --- Lambert shading ----------------------------------------------------------------------------------
def square(x, half):
    V = np.array([[x, -half, -half], [x, half, -half], [x, half, half], [x, -half, half]])
    return V, np.array([[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("sid, reach", [("torus", 0.6), ("poincare", 0.3), ("seifert_weber", 1.0)])
def test_lambert_shading_closed_form(space_cache, sid, reach):
    """Within a light reach that holds only the light's own copy (the sum over copies: test_light)."""
    space = space_cache(sid)
    g = space.geometry
    x0, half = {"torus": (0.3, 0.4), "poincare": (0.15, 0.1), "seifert_weber": (0.4, 0.3)}[sid]
    V, F = square(x0, half)
    base = np.array([0.8, 0.5, 0.25])
    light_chart = np.array([0.02, 0.05, -0.03])
    power = 0.7
    light_color = np.array([1.0, 0.9, 0.6])
    scene = Scene(objects=[SceneObject("wall", V, F, base)], lights=[PointLight(light_chart, light_color, power)])
    tracer = render.make_tracer(space, scene, light_reach=reach)
    rng = np.random.default_rng(7)
    targets = np.column_stack([np.full(50, x0), rng.uniform(-0.8 * half, 0.8 * half, size=(50, 2))])
    P, D = model_rays(g, np.zeros((50, 3)), targets)
    out = tracer.trace(P, D, 5.0, 40, shade=True)
    assert np.all(out["stop"] == 0)
    np.testing.assert_allclose(out["position"], targets, atol=1e-6)
    H = g.to_model(targets)
    L = g.to_model(light_chart)
    r = g.distance(H, L[None, :])
    # unit normal of the plane x = x0 at H (the covector (1,0,0,-x0) as a tangent vector), towards O
    N = g.normalize_tangent(
        H, np.tile([-1.0, 0.0, 0.0, x0 * g.curvature], (50, 1)) if g.curvature else np.tile([-1.0, 0, 0, 0], (50, 1))
    )
    assert np.all(g.inner(N, g.direction_to(H, ORIGIN[None, :])) > 0)
    cos = g.inner(N, g.direction_to(H, L[None, :]))
    expected = base[None, :] * light_color[None, :] * power * (cos * g.falloff(r))[:, None]
    np.testing.assert_allclose(out["color"], expected, rtol=2e-5)
    # not shaded: the base colour
    plain = tracer.trace(P, D, 5.0, 40, shade=False)
    np.testing.assert_allclose(plain["color"], np.broadcast_to(base, (50, 3)), rtol=1e-6)


def test_emission_adds_and_shadow_blocks(space_cache):
    space = space_cache("torus")
    g = space.geometry
    V, F = square(0.3, 0.4)
    blocker_V, blocker_F = square(0.15, 0.05)  # between the light and the wall's centre
    scene = Scene(
        objects=[
            SceneObject("wall", V, F, (1, 1, 1), emission=(0.1, 0.2, 0.3)),
            SceneObject("blocker", blocker_V + [0, 0.2, 0.2], blocker_F, (1, 1, 1)),
        ],
        lights=[PointLight(np.array([0.0, 0.2, 0.2]), np.ones(3), 1.0)],
    )
    tracer = render.make_tracer(space, scene, light_reach=0.7)  # the light's own copy only
    # ray to the wall point straight behind the blocker (seen from the light) and one beside it
    targets = np.array([[0.3, 0.2, 0.2], [0.3, -0.2, -0.2]])
    # the first ray passes below the blocker to reach the wall
    p = np.array([[0.0, 0.2, -0.1], [0.0, -0.2, -0.2]])
    P, D = model_rays(g, p, targets - p)
    out = tracer.trace(P, D, 5.0, 40, shade=True)
    assert list(out["object"]) == [0, 0]
    np.testing.assert_allclose(out["color"][0], [0.1, 0.2, 0.3], rtol=1e-6)  # shadowed: emission only
    r = np.linalg.norm(targets[1] - [0.0, 0.2, 0.2])
    cos = 0.3 / r
    np.testing.assert_allclose(out["color"][1], np.array([0.1, 0.2, 0.3]) + cos / r**2, rtol=2e-5)


# --- render() ---------------------------------------------------------------------------------------------
def test_render_sizes_passes_and_quality(space_cache):
    space = space_cache("torus")
    scene = default_scene(space)
    for projection, (w, h) in (("perspective", (24, 13)), ("equirect", (32, 16))):
        res = render.render(space, scene, render.Settings(width=w, height=h, projection=projection, quality="draft"))
        p = res.passes
        assert set(p) == set(render.PASSES) - {"noisy"} | {"alpha"}  # noisy: only where denoised
        # each pass fills the EXR channels the pass table gives it
        assert all(p[n].reshape(h, w, -1).shape[2] == len(passes.CHANNELS[n]) for n in p if n != "alpha")
        assert p["color"].shape == (h, w, 3) and p["color"].dtype == np.float32
        np.testing.assert_array_equal(p["alpha"], 1.0)  # opaque unless Settings.transparent
        assert p["depth"].shape == (h, w) and p["depth"].dtype == np.float64
        assert p["normal"].shape == (h, w, 3) and p["position"].shape == (h, w, 3)
        assert p["object"].shape == (h, w) and p["object"].dtype == np.int32
        assert p["crossings"].shape == (h, w) and p["stop"].shape == (h, w)
        assert res.stats["rays"] == w * h and res.stats["samples_per_pixel"] == 1
        assert np.all(np.isfinite(p["color"]))
        assert "rays" in res.summary()
    res = render.render(space, scene, render.Settings(width=8, height=6, quality="standard"))
    assert res.stats["samples_per_pixel"] == 4 and res.stats["rays"] == 4 * 48


def test_render_depth_is_the_camera_ray_depth(space_cache):
    """Pixel (i, j) of a perspective render is the geodesic along the pinhole direction."""
    space = space_cache("torus")
    g = space.geometry
    V, F, centre, sag = ball_mesh(g, [0, 1, 0], 0.0, 0.2)
    scene = sphere_scene(V + [0, 0.3, 0], F)
    W, H = 21, 11
    cam = Camera(np.array([0.0, -0.2, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 60.0)
    res = render.render(space, scene, render.Settings(width=W, height=H, quality="draft", max_distance=3.0), camera=cam)
    depth = res.passes["depth"]
    t = math.tan(math.radians(30))
    for i, j in ((5, 10), (3, 12), (7, 8)):
        sx = (2 * (j + 0.5) / W - 1) * t
        sy = (1 - 2 * (i + 0.5) / H) * t * H / W
        d = np.array([sx, 1.0, sy])  # right = forward x up = +x
        d /= np.linalg.norm(d)
        P, D = model_rays(g, cam.position[None, :], d[None, :])
        tt, cos = first_entry(g, P, D, np.array([[0, 0.3, 0, 1.0]]), 0.2)
        assert cos[0] > 0.3
        assert abs(depth[i, j] - tt[0]) < 2 * sag / cos[0] + 1e-6


def test_camera_outside_domain_is_brought_inside(space_cache):
    space = space_cache("torus")
    scene = default_scene(space)
    settings = render.Settings(width=24, height=12, quality="draft")
    f, u = np.array([0.3, 1.0, 0.1]), np.array([0.0, 0.0, 1.0])
    a = render.render(space, scene, settings, camera=Camera(np.array([1.1, 0.0, 0.0]), f, u))
    b = render.render(space, scene, settings, camera=Camera(np.array([0.1, 0.0, 0.0]), f, u))
    np.testing.assert_array_equal(a.passes["object"], b.passes["object"])
    np.testing.assert_allclose(a.passes["depth"], b.passes["depth"], rtol=1e-9)


def test_camera_outside_twisted_domain(space_cache):
    """quarter_turn: the camera outside is carried in by the pairing, its frame turned with it."""
    space = space_cache("quarter_turn")
    g = space.geometry
    scene = default_scene(space)
    settings = render.Settings(width=24, height=12, quality="draft")
    p, f, u = np.array([0.1, 0.2, 0.9]), np.array([0.3, 1.0, 0.1]), np.array([0.0, 0.0, 1.0])
    X, _, M = space.bring_inside(g.to_model(p))
    assert not np.allclose(M[:3, :3], np.eye(3))  # the pairing used turns the frame
    inside = Camera(g.to_chart(X), M[:3, :3] @ f, M[:3, :3] @ u)
    a = render.render(space, scene, settings, camera=Camera(p, f, u))
    b = render.render(space, scene, settings, camera=inside)
    np.testing.assert_array_equal(a.passes["object"], b.passes["object"])
    np.testing.assert_allclose(a.passes["depth"], b.passes["depth"], rtol=1e-9)


def test_camera_not_a_point_raises(space_cache):
    space = space_cache("seifert_weber")
    cam = Camera(np.array([2.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    with pytest.raises(render.RenderError, match="camera"):
        render.render(space, Scene(), render.Settings(width=4, height=4, quality="draft"), camera=cam)


def test_render_cancel(space_cache):
    space = space_cache("torus")
    calls = []

    def progress(done, total):
        calls.append((done, total))
        return False

    with pytest.raises(render.Cancelled):
        render.render(
            space, default_scene(space), render.Settings(width=64, height=32, quality="draft"), progress=progress
        )
    assert calls


def test_bad_settings_raise(space_cache):
    space = space_cache("torus")
    for kw in (
        dict(width=0),
        dict(projection="fisheye"),
        dict(quality="ultra"),
        dict(shading="toon"),
        dict(max_distance=float("nan")),
        dict(max_crossings=-1),
        dict(fog=float("nan")),
        dict(fog=-0.5),
        dict(fog=0.0),
        dict(fog=float("inf")),
        dict(threads=-1),
        dict(max_crossings=2.7),
    ):
        with pytest.raises(render.RenderError):
            render.render(space, Scene(), render.Settings(**{"width": 4, "height": 4, **kw}))


def test_projection_orientation_and_fog(space_cache):
    """Perspective and equirect: an object to the camera's right shows right of centre, one above
    shows in the top rows (rows run top-down); fog scales colour by exp(-depth / fog)."""
    space = space_cache("torus")

    def box(c, s=0.1):
        m = trimesh.creation.box(extents=[s] * 3)
        return SceneObject(f"box {c}", m.vertices + c, m.faces, (0, 0, 0), emission=(0.2, 0.4, 0.8))

    # camera looks along +y with up +z: right is +x
    scene = Scene(objects=[box([0.3, 0.1, 0.0]), box([0.0, 0.1, 0.3]), box([0.0, 0.3, 0.0])])
    cam = Camera(np.zeros(3), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 150.0)
    W, H = 41, 41
    common = dict(width=W, height=H, quality="draft", max_distance=0.45)
    res = render.render(space, scene, render.Settings(**common), camera=cam)
    obj = res.passes["object"]
    assert obj[20, 20] == 2  # ahead
    assert obj[20, 36] == 0 and obj[20, 4] == -1  # right, not left
    assert obj[4, 20] == 1 and obj[36, 20] == -1  # up in the top rows
    W, H = 64, 32
    scene = Scene(objects=[box([0.3, 0.0, 0.0]), box([0.0, 0.0, 0.3]), box([0.0, 0.3, 0.0])])
    res = render.render(
        space, scene, render.Settings(**{**common, "width": W, "height": H, "projection": "equirect"}), camera=cam
    )
    obj = res.passes["object"]
    assert obj[16, 32] == 2  # longitude 0 (column centre) is forward
    assert obj[16, 48] == 0  # longitude +90 degrees: right
    assert obj[0, 5] == 1 and obj[0, 60] == 1  # the top row looks straight up
    assert obj[16, 16] == -1 and obj[31, 30] == -1
    # fog
    plain = render.render(space, scene, render.Settings(**{**common, "width": 9, "height": 9}), camera=cam)
    foggy = render.render(space, scene, render.Settings(**{**common, "width": 9, "height": 9, "fog": 0.5}), camera=cam)
    d = plain.passes["depth"][4, 4]
    assert d == pytest.approx(0.25, abs=1e-6)
    np.testing.assert_allclose(plain.passes["color"][4, 4], [0.2, 0.4, 0.8], rtol=1e-6)
    np.testing.assert_allclose(foggy.passes["color"][4, 4], np.array([0.2, 0.4, 0.8]) * math.exp(-d / 0.5), rtol=1e-5)


def test_camera_several_cells_away(space_cache):
    space = space_cache("torus")
    scene = default_scene(space)
    settings = render.Settings(width=16, height=8, quality="draft")
    f, u = np.array([0.3, 1.0, 0.1]), np.array([0.0, 0.0, 1.0])
    a = render.render(space, scene, settings, camera=Camera(np.array([3.1, -2.2, 5.05]), f, u))
    b = render.render(space, scene, settings, camera=Camera(np.array([0.1, -0.2, 0.05]), f, u))
    np.testing.assert_array_equal(a.passes["object"], b.passes["object"])
    np.testing.assert_allclose(a.passes["depth"], b.passes["depth"], rtol=1e-9)


def test_negative_light_power_is_rejected(space_cache):
    space = space_cache("torus")
    for power in (-5.0, float("nan")):
        with pytest.raises(SceneError, match=r"light at \[0\.0, 0\.0, 0\.0\]: power must be a number >= 0"):
            PointLight(np.zeros(3), np.ones(3), power)
        light = PointLight(np.zeros(3), np.ones(3), 1.0)
        light.power = power  # changed after it was made: the compiler checks again
        with pytest.raises(SceneError, match="light 0: power"):
            render.compile_scene(space, Scene(lights=[light]))


# --- antialiasing: stratified samples, centre-ray passes ---------------------------------------------
@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 7, 9, 16, 64])
def test_sample_offsets_cover_each_stratum_once_and_average_to_the_centre(n):
    o = np.array(render.sample_offsets(n))
    assert o.shape == (n, 2)
    assert np.all((o >= 0) & (o < 1))
    np.testing.assert_allclose(o.mean(axis=0), [0.5, 0.5], rtol=0, atol=1e-15)
    k = math.isqrt(n)
    if k * k == n:  # one sample in each of the k x k sub-squares
        cells = {(int(x * k), int(y * k)) for x, y in o}
        assert cells == {(a, b) for a in range(k) for b in range(k)}
    else:  # n-rooks: one sample in each column and each row of width 1/n
        assert sorted(int(x * n) for x in o[:, 0]) == list(range(n))
        assert sorted(int(y * n) for y in o[:, 1]) == list(range(n))
    assert len({tuple(p) for p in o}) == n  # no sample counted twice


@pytest.mark.parametrize("n", [16, 32, 64, 256])
def test_every_prefix_of_the_sample_offsets_spreads_over_the_pixel(n):
    """Adaptive sampling and the time limit stop a pixel after a prefix of its samples: every even
    prefix averages to the pixel's centre (mirror pairs), and the first 4 lie in the four quadrants,
    the first 16 in 16 of the 4 x 4 cells or within one cell of each empty one (farthest-point order).
    In stratum order a prefix of 4 of n samples lay in one strip of the pixel: its error grew with n."""
    o = np.array(render.sample_offsets(n))
    for k in range(2, n + 1, 2):
        np.testing.assert_allclose(o[:k].mean(axis=0), [0.5, 0.5], rtol=0, atol=1e-12)
    assert {(int(x * 2), int(y * 2)) for x, y in o[:4]} == {(0, 0), (0, 1), (1, 0), (1, 1)}
    gaps = [min(np.hypot(*(o[:16] - [(a + 0.5) / 4, (b + 0.5) / 4]).T)) for a in range(4) for b in range(4)]
    assert max(gaps) < 0.25 * math.sqrt(2)


@pytest.mark.parametrize("samples", [4, 9, 16, 3])
def test_colour_of_a_linear_ramp_is_its_value_at_the_pixel_centre(space_cache, samples):
    """A wall at constant depth seen head-on, shaded by chart position: the colour is linear in
    the screen coordinates across each pixel, so an unbiased pixel average equals the value at
    the pixel centre (x = y0 * sx, z = y0 * sy, the pinhole's closed form)."""
    space = space_cache("torus")
    y0, half = 0.3, 0.45
    V = np.array([[-half, y0, -half], [half, y0, -half], [half, y0, half], [-half, y0, half]])
    scene = Scene(objects=[SceneObject("wall", V, np.array([[0, 1, 2], [0, 2, 3]]))])
    cam = Camera(np.zeros(3), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 60.0)
    W, H = 9, 7
    res = render.render(
        space,
        scene,
        render.Settings(width=W, height=H, samples=samples, shading="position", max_distance=1.0),
        camera=cam,
    )
    assert np.all(res.passes["object"] == 0)
    lo, hi = space.domain.vertices.min(axis=0), space.domain.vertices.max(axis=0)
    t = math.tan(math.radians(30))
    j, i = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    x = y0 * (2 * j / W - 1) * t
    z = y0 * (1 - 2 * i / H) * t * H / W
    expected = (np.stack([x, np.full_like(x, y0), z], axis=-1) - lo) / (hi - lo)
    np.testing.assert_allclose(res.passes["color"], expected, rtol=0, atol=2e-6)


@pytest.mark.parametrize("samples", [1, 4, 9])
def test_passes_are_the_unshaded_centre_ray_trace(space_cache, samples):
    """Depth, normal, position, object, crossings and stop come from the pinhole ray through the
    pixel centre (closed form here), traced with shade=False."""
    space = space_cache("torus")
    g = space.geometry
    V, F, _, _ = ball_mesh(g, [0, 1, 0], 0.0, 0.2, subdivisions=3)
    scene = Scene(
        objects=[SceneObject("ball", V + [0.1, 0.3, 0.05], F, (0.5, 0.5, 0.5))],
        lights=[PointLight(np.array([0.0, 0.0, 0.2]), np.ones(3), 1.0)],
    )
    W, H = 13, 9
    cam = Camera(np.array([0.0, -0.2, 0.0]), np.array([0.2, 1.0, 0.1]), np.array([0.0, 0.0, 1.0]), 80.0)
    tracer = render.make_tracer(space, scene)
    res = render.render(
        space, scene, render.Settings(width=W, height=H, samples=samples, max_distance=3.0), camera=cam, tracer=tracer
    )
    f = cam.forward / np.linalg.norm(cam.forward)
    r = np.cross(f, cam.up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    t = math.tan(math.radians(40))
    j, i = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    d = f + ((2 * j / W - 1) * t)[..., None] * r + ((1 - 2 * i / H) * t * H / W)[..., None] * u
    P, D = model_rays(g, np.broadcast_to(cam.position, (H * W, 3)), d.reshape(-1, 3))
    out = tracer.trace(np.ascontiguousarray(P), np.ascontiguousarray(D), 3.0, space.max_crossings, shade=False)
    p = res.passes
    assert (out["stop"] == 0).sum() > 20 and (out["stop"] != 0).sum() > 20
    np.testing.assert_array_equal(p["object"].ravel(), out["object"])
    np.testing.assert_array_equal(p["stop"].ravel(), out["stop"])
    np.testing.assert_array_equal(p["crossings"].ravel(), out["crossings"])
    np.testing.assert_allclose(p["depth"].ravel(), out["depth"], rtol=1e-12)
    np.testing.assert_allclose(p["position"].reshape(-1, 3), out["position"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(p["normal"].reshape(-1, 3), out["normal"], rtol=0, atol=1e-6)
    assert res.stats["rays"] == samples * W * H
    assert res.stats["rays_traced"] == (samples + (samples % 2 == 0)) * W * H


def test_camera_frame_once_per_render(space_cache, monkeypatch):
    space = space_cache("poincare")
    calls = []
    frame = render.camera_frame

    def counting(*a, **k):
        calls.append(1)
        return frame(*a, **k)

    for module in (render.camera, render.loop):  # the loop's calls and camera_rays' own
        monkeypatch.setattr(module, "camera_frame", counting)
    render.render(space, Scene(), render.Settings(width=4, height=3, samples=16))
    assert len(calls) == 1


# --- memory: sizes this machine cannot hold are refused before anything is allocated -------------------
@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="VmHWM in /proc/self/status: Linux")
def test_bytes_per_pixel_estimate_covers_the_measured_peak():
    """The estimate behind the refusal, against the peak resident memory of a real render
    (subprocess, 1000 x 800, 4 samples, after a warm-up render)."""
    # the peak (VmHWM) is reset first: a child starts with its parent's high-water mark
    code = textwrap.dedent("""
        import gc
        from thurston_addon import render, spaces, scenes
        def status(key):
            for line in open("/proc/self/status"):
                if line.startswith(key):
                    return int(line.split()[1]) * 1024
        space = spaces.load("torus"); sc = scenes.default_scene(space)
        t = render.make_tracer(space, sc)
        render.render(space, sc, render.Settings(width=64, height=64, samples=4), tracer=t)
        gc.collect()
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        base = status("VmRSS")
        assert status("VmHWM") < base + 2**20, "could not reset the high-water mark"
        for shading, projection in (("lambert", "perspective"), ("object", "equirect")):
            res = render.render(space, sc, render.Settings(width=1000, height=800, samples=4, shading=shading, max_distance=0.5,
                                                           projection=projection), tracer=t)
            del res
        print((status("VmHWM") - base) / 8e5)
    """)
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    measured = float(proc.stdout.split()[-1])
    assert 100 < measured <= render.BYTES_PER_PIXEL, measured
    assert render.BYTES_PER_PIXEL < 2 * measured  # not so cautious that usable sizes are refused


@pytest.mark.skipif(not hasattr(os, "sysconf"), reason="physical memory from sysconf")
def test_size_beyond_memory_is_refused_without_allocating(space_cache):
    space = space_cache("torus")
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    pixels = 0.8 * memory / render.BYTES_PER_PIXEL  # the most that may be rendered
    W = 65536
    H_over = math.floor(pixels / W) + 1
    H_under = math.floor(pixels / W) - 1
    render.Settings(width=W, height=H_under).check()  # just under: accepted
    tracemalloc.start()
    try:
        with pytest.raises(render.RenderError) as info:
            render.render(space, Scene(), render.Settings(width=W, height=H_over, quality="draft"))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    msg = str(info.value)
    assert f"{W}x{H_over}" in msg and "memory" in msg and f"{memory / 2**30:.1f} GiB" in msg, msg
    assert peak < 10 * 2**20  # refused before any image-sized allocation


def test_memory_error_during_render_is_a_render_error(space_cache, monkeypatch):
    def no_memory(*a, **k):
        raise MemoryError

    monkeypatch.setattr(render.loop, "camera_rays", no_memory)
    with pytest.raises(render.RenderError, match="out of memory rendering 8x4"):
        render.render(space_cache("torus"), Scene(), render.Settings(width=8, height=4, quality="draft"))


# --- lights in S3: the nearest copy over the whole group ----------------------------------------------
def test_poincare_light_sums_all_120_copies_near_the_vertices(space_cache):
    """A tiny facet near one vertex of the dodecahedron, lit by a light near another vertex and seen
    from a point just in front of it: the Lambert closed form summed over all 120 copies of the
    light and both arcs to each (closed-form distances; the facet glows faintly, so that it casts
    no shadow), for pairs where the copies around the domain alone would miss the nearest one."""
    space = space_cache("poincare")
    g = space.geometry
    group = space.elements_within(math.pi + 1e-6)
    assert len(group) == 120
    ring = space.neighbourhood(1)
    Vd = space.domain.vertices
    rng = np.random.default_rng(11)

    def tangent(H, v):  # the part of an R^4 vector tangent to S3 at H, unit
        v = v - (v @ H) * H
        return v / np.linalg.norm(v)

    cases = []
    for _ in range(20000):
        a, b = rng.integers(len(Vd), size=2)
        # on the segments from O to two vertices, near the vertices (inside: the domain is star-shaped)
        h = Vd[a] * (1 - 0.1 * rng.random() ** 2)
        l = Vd[b] * (1 - 0.1 * rng.random() ** 2)
        H, L = g.to_model(h), g.to_model(l)
        copies = np.array([M @ L for M in group])
        d = g.distance(H[None, :], copies)
        near = copies[int(np.argmin(d))]
        d_ring = min(float(g.distance(H, M @ L)) for M in ring)
        room = -float(np.max(space.face_distances(H)))  # geodesic distance from H to the faces' planes
        if d_ring > d.min() + 1e-3 and room > 1e-3:
            cases.append((h, l, H, near, float(d.min()), room))
        if len(cases) == 6:
            break
    assert len(cases) >= 3, "test set-up: too few pairs where the ring of copies misses the nearest light"
    base, power, glow = np.array([0.9, 0.6, 0.3]), 0.8, 1e-3
    for h, l, H, near, r, room in cases:
        L = g.to_model(l)
        # the facet's unit normal at H, tilted from the nearest light; in S3 a tangent N at H is the
        # covector of its plane, so the chart plane is N[:3] . x + N[3] = 0 (through h)
        N = tangent(H, g.direction_to(H, near) + 0.5 * tangent(H, rng.normal(size=4)))
        cos = float(N @ tangent(H, g.direction_to(H, near)))
        w = tangent(H, N + 0.7 * tangent(H, rng.normal(size=4)))  # the viewer's side
        assert cos > 0.3 and N @ w > 0.3
        delta = 0.5 * room  # the viewer Q = exp_H(delta w): inside the domain
        Q = math.cos(delta) * H + math.sin(delta) * w
        V = math.sin(delta) * H - math.cos(delta) * w  # unit tangent at Q towards H
        n = N[:3] / np.linalg.norm(N[:3])
        assert abs(n @ h + N[3] / np.linalg.norm(N[:3])) < 1e-9
        e1 = np.cross(n, [0.3, 0.5, 0.8])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        s = 0.1 * delta
        quad = np.array([h + s * (x * e1 + y * e2) for x, y in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        scene = Scene(
            objects=[SceneObject("facet", quad, np.array([[0, 1, 2], [0, 2, 3]]), base, emission=(glow,) * 3)],
            lights=[PointLight(l, np.ones(3), power)],
        )
        tracer = render.make_tracer(space, scene)
        out = tracer.trace(Q[None, :], V[None, :], 3.0, 200, shade=True)
        assert out["stop"][0] == 0 and out["object"][0] == 0
        assert out["depth"][0] == pytest.approx(delta, rel=1e-9)
        np.testing.assert_allclose(out["position"][0], h, atol=1e-9)
        arcs = [(N @ tangent(H, g.direction_to(H, Y)), float(g.distance(H, Y))) for Y in (M @ L for M in group)]
        # the short arc where the light is in front (c > 0), the long one, leaving the other way, else
        summed = sum(abs(c) * g.falloff(d) for c, d in arcs)
        assert cos * g.falloff(r) < 0.5 * summed  # not the nearest copy alone
        expected = glow + base * power * summed
        np.testing.assert_allclose(out["color"][0], expected, rtol=1e-4)


# --- the geodesic error: measured, and it sees a wrong pairing -------------------------------------------
@pytest.mark.parametrize("sid", presets(lambda space: space.geometry.projective))
def test_geodesic_error_is_small_for_presets(space_cache, sid):
    space = space_cache(sid)
    res = render.render(space, default_scene(space), render.Settings(width=64, height=36, quality="draft"))
    assert res.stats["hit_fraction"] > 0.5
    assert 0 <= res.stats["geodesic_error"] < 1e-9, res.stats["geodesic_error"]
    assert "geodesic error" in res.summary()


@pytest.mark.parametrize("sid", ["nil", "sol"])
@pytest.mark.parametrize("quality", ["draft", "standard"])
def test_curved_render_states_and_keeps_its_bound(space_cache, sid, quality):
    """A Nil or Sol render's summary states its bound, chords per ray and measured error, and the
    measured error (against the re-traced geodesic) and the error against the Python reference are
    within the bound: the quality's fraction of the pixel footprint at the hit's distance."""
    space = space_cache(sid)
    res = render.render(space, default_scene(space), render.Settings(width=64, height=36, quality=quality))
    st, fraction = res.stats, render.QUALITY[quality].footprint_fraction
    assert res.stats["hit_fraction"] > 0.5 and st["chords_per_ray"] > 1
    assert f"within {fraction:g} of the pixel footprint" in st["bound"]
    summary = res.summary()
    for text in (st["bound"], "chords/ray", "measured error", "pixel footprints"):
        assert text in summary
    assert 0 <= st["measured_error_pixels"] <= fraction
    # the nearest hit's footprint bounds the reference's error in chart units from below
    nearest = np.nanmin(np.where(res.passes["stop"] == 0, res.passes["depth"], np.nan))
    pixel = math.radians(space.camera.fov) / 64
    assert st["geodesic_error"] <= fraction * render.footprint(space, pixel, nearest)
    # that footprint in closed form (the domain's chart extent is Nil's and Sol's metric one)
    assert render.footprint(space, pixel, nearest) == pytest.approx(
        pixel * (nearest + render.NEAR_FRACTION * space.extent), rel=1e-12
    )


def test_geodesic_error_sees_a_perturbed_pairing(space_cache):
    """A tracer built by hand whose pairing of an x face of the torus also translates 1e-6 (then
    1e-5) along y: each crossing of that face moves the ray sideways by that much, and the
    measured error grows with the perturbation (about linearly), bounded by the number of
    crossings times it."""
    import thurston_core

    space = space_cache("torus")
    scene = default_scene(space)
    data = render.compile_scene(space, scene)
    face = next(i for i, f in enumerate(space.domain.faces) if abs(f.covector[0]) > 0.5)
    settings = render.Settings(width=64, height=36, quality="draft")
    errors = {}
    for eps in (0.0, 1e-6, 1e-5):
        maps = data["face_maps"].copy()
        maps[face, 1, 3] += eps  # a translation off the lattice, across the face's normal
        tracer = thurston_core.Tracer(render.core_scene({**data, "face_maps": np.ascontiguousarray(maps)}))
        res = render.render(space, scene, settings, tracer=tracer)
        errors[eps] = res.stats["geodesic_error"]
        crossings = int(res.passes["crossings"].max())
    assert errors[0.0] < 1e-12
    assert 1e-6 <= errors[1e-6] <= crossings * 1e-6 * 1.01, errors
    assert 5 < errors[1e-5] / errors[1e-6] < 20, errors


def test_winding_numbers_tell_inside_from_outside():
    """The solid-angle sum of a closed mesh about a point: 1 inside (either orientation's sign),
    0 outside, for a sphere mesh; the chunking does not change it."""
    from thurston_addon import checks

    ico = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    V, F = np.asarray(ico.vertices), np.asarray(ico.faces)
    points = np.array([[0, 0, 0], [0.1, -0.1, 0.2], [0.5, 0, 0], [0, 0.31, 0.0], [2, 2, 2]])
    w = checks.winding_numbers(points, V, F)
    np.testing.assert_allclose(w, [1, 1, 0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(checks.winding_numbers(points, V, F[:, ::-1], block=7), -w, atol=1e-9)
