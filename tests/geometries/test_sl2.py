"""SL2~ (model D x R) against independent truth.

The metric is written in support/truth.py from lam^2 (dx^2 + dy^2) + (dphi + lam (x dy - y dx))^2, lam = 2 / (1 - |w|^2);
its derivatives by hand there, checked against finite differences; the Christoffel symbols and the geodesic
equation are built from them (truth.christoffel_from) and integrated with DOP853 at 1e-12.
"""

import math
import tomllib

import numpy as np
import pytest
import trimesh
from support.cover import assert_no_leak_at_the_prism_edges, check_depths, first_hits
from support.truth import (
    assert_sl2_flow,
    sl2_body_direction,
    sl2_christoffel,
    sl2_metric,
    sl2_metric_derivative,
    unit_in,
)

from thurston_addon import render, spaces
from thurston_addon.geometries import sl2
from thurston_addon.scenes import PointLight, Scene, SceneObject

G = sl2.SL2()


def unit(x, u):
    return unit_in(sl2_metric, x, u)


def random_point(rng, radius=0.8):
    r, a = radius * math.sqrt(rng.random()), rng.uniform(0, 2 * math.pi)
    return np.array([r * math.cos(a), r * math.sin(a), rng.uniform(-3, 3)])


def random_element(rng):
    return sl2.multiply(sl2.fibre_translation(rng.uniform(-5, 5)), sl2.from_origin(random_point(rng)))


def jacobian(f, x, h=1e-6):
    return np.stack([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(3)], -1)


@pytest.fixture
def rng():
    return np.random.default_rng(8)


def test_metric_and_christoffel(rng):
    for _ in range(20):
        x = random_point(rng, 0.95)
        assert np.allclose(G.metric(x), sl2_metric(x), rtol=1e-14, atol=0)
        fd = jacobian(sl2_metric, x).transpose(2, 0, 1)
        assert np.allclose(sl2_metric_derivative(x), fd, rtol=1e-6, atol=1e-6)
        assert np.allclose(G.christoffel(x), sl2_christoffel(x), rtol=1e-12, atol=1e-12)


def test_isometries_pull_back_the_metric(rng):
    for _ in range(20):
        g, x = random_element(rng), random_point(rng)
        J = jacobian(lambda p: sl2.act(g, p), x)
        assert np.allclose(J.T @ sl2_metric(sl2.act(g, x)) @ J, sl2_metric(x), rtol=1e-7, atol=1e-7)
        assert np.allclose(np.stack([sl2.act_tangent(g, x, e) for e in np.eye(3)], -1), J, rtol=1e-7, atol=1e-7)


def test_group_law(rng):
    for _ in range(20):
        g, h, x = random_element(rng), random_element(rng), random_point(rng)
        assert np.allclose(sl2.act(sl2.multiply(g, h), x), sl2.act(g, sl2.act(h, x)), rtol=1e-12, atol=1e-12)
        assert np.allclose(sl2.act(sl2.inverse(g), sl2.act(g, x)), x, rtol=1e-12, atol=1e-12)
        assert np.allclose(sl2.point(sl2.from_origin(x)), x, rtol=1e-14, atol=1e-15)
    # the centre: T_{2 pi} is the lift of -1 in SU(1,1), the rotation by 2 pi
    spin = sl2.Element(np.array(-1 + 0j), np.array(0j), np.array(2 * math.pi))
    x = random_point(rng)
    assert np.allclose(sl2.act(spin, x), x + [0, 0, 2 * math.pi], atol=1e-14)


def test_geodesic_random_starts(rng):
    for _ in range(20):
        x = random_point(rng)
        assert_sl2_flow(x, unit(x, rng.normal(size=3)), rng.uniform(0, 10))


def test_geodesic_fibre_rays(rng):
    for sign in (1, -1):
        x = random_point(rng)
        u = unit(x, sl2.act_tangent(sl2.from_origin(x), np.zeros(3), [0, 0, sign]))
        assert_sl2_flow(x, u, 7.0)
        assert np.allclose(G.chart_geodesic(x, u, 7.0)[0], x + [0, 0, 7.0 * sign], atol=1e-12)


@pytest.mark.parametrize("offset", [-1e-9, 0.0, 1e-9])
@pytest.mark.parametrize("sign", [1, -1])
def test_geodesic_at_the_branch_boundary(rng, offset, sign):
    """a = |c| + offset in the body frame: where the closed form's cosh turns into cos."""
    # a = |c| + offset on a^2 + c^2 = 1
    c = sign * (math.sqrt(2 - offset**2) - offset) / 2
    a = abs(c) + offset
    for _ in range(3):
        x, a0 = random_point(rng), rng.uniform(0, 2 * math.pi)
        b = [a * math.cos(a0), a * math.sin(a0), c]
        u = sl2.act_tangent(sl2.from_origin(x), np.zeros(3), sl2.body_to_chart(b))
        assert_sl2_flow(x, u, 9.0)


def test_geodesic_near_the_disk_boundary(rng):
    for _ in range(10):
        a = rng.uniform(0, 2 * math.pi)
        x = np.array([0.99 * math.cos(a), 0.99 * math.sin(a), rng.uniform(-3, 3)])
        assert_sl2_flow(x, unit(x, rng.normal(size=3)), rng.uniform(0, 3))


def test_geodesic_broadcasts_over_times(rng):
    x = random_point(rng)
    u = unit(x, rng.normal(size=3))
    ts = np.array([0.0, 1.0, 4.0])
    xs, vs = G.chart_geodesic(np.broadcast_to(x, (3, 3)), np.broadcast_to(u, (3, 3)), ts)
    for k, t in enumerate(ts):
        x1, v1 = G.chart_geodesic(x, u, t)
        assert np.allclose(xs[k], x1, rtol=0, atol=1e-15) and np.allclose(vs[k], v1, rtol=0, atol=1e-15)
    assert np.allclose(xs[0], x) and np.allclose(vs[0], u)


# --- the model, the preset and the tracer against the universal cover's elements ----------------------

SQ2 = math.sqrt(2)
KLEIN_SIDE = math.sqrt(2 * SQ2 - 2)  # the octagon's sides' Klein distance from the centre
TAU = 2 * math.pi


def side_normals():
    angles = np.arange(8) * math.pi / 4
    return np.c_[np.cos(angles), np.sin(angles)]


def lifted(k):
    """A_k in SL2~, the canonical lift (alpha real: phi_g = 0); A_k^-1 = A_{k+4}."""
    return sl2.Element(
        np.array(1 + SQ2 + 0j), np.array(math.sqrt(2 + 2 * SQ2) * np.exp(1j * k * math.pi / 4)), np.array(0.0)
    )


def identity(n):
    return sl2.Element(np.ones(n) + 0j, np.zeros(n) + 0j, np.zeros(n))


def reduce_in_cover(x, tau=TAU):
    """Chart points of the universal cover (phi continuous) carried into the domain by the lifted
    generators as docs/mathematics.md#sl2 says: while a side test fails apply A_k^-1 for the most violated
    side k, then wrap phi into [-tau/2, tau/2). Returns the points and the elements applied."""
    x = np.array(x, float)
    R = identity(len(x))
    for _ in range(64):
        w = x[:, 0] + 1j * x[:, 1]
        k = 2 * w / (1 + np.abs(w) ** 2)
        sides = np.c_[k.real, k.imag] @ side_normals().T - KLEIN_SIDE
        worst = np.argmax(sides, axis=1)
        out = sides[np.arange(len(x)), worst] > 1e-13
        if not out.any():
            break
        for j in range(8):
            rows = out & (worst == j)
            if rows.any():
                A = lifted(j + 4)
                step = sl2.Element(*(np.broadcast_to(a, rows.sum()) for a in A))
                x[rows] = sl2.act(step, x[rows])
                R = sl2.Element(*(np.array(a) for a in R))
                moved = sl2.multiply(step, sl2.Element(R.alpha[rows], R.beta[rows], R.phi[rows]))
                R.alpha[rows], R.beta[rows], R.phi[rows] = moved
    shift = -tau * np.floor((x[:, 2] + tau / 2) / tau)
    return x + np.c_[np.zeros((len(x), 2)), shift], sl2.multiply(sl2.fibre_translation(shift), R)


def cover_start(x, u):
    g = sl2.from_origin(x)
    return g, sl2.chart_to_body(sl2.act_tangent(sl2.inverse(g), x, u))


def cover_end(x, u, length):
    """Where the universal cover's geodesic from (x, u) ends, reduced into the domain."""
    g, b = cover_start(x, u)
    return reduce_in_cover(sl2.point(sl2.flow(g, b, length)[0])[None])[0][0]


def cover_hits(x, u, length, centres, outer, inner, step=0.01):
    """cover.first_hits for the cover geodesic from (x, u), marched by the cover's elements."""
    g, b = cover_start(x, u)
    t = np.arange(0.0, length + step, step)
    n = len(t)
    states = sl2.flow(sl2.Element(*(np.broadcast_to(a, n) for a in g)), np.broadcast_to(b, (n, 3)), t)[0]
    points = sl2.point(states)
    reduced, R = reduce_in_cover(points)
    piece = lambda k: sl2.Element(R.alpha[k], R.beta[k], R.phi[k])
    x_next = np.array([sl2.act(piece(k), points[k + 1]) for k in range(n - 1)])
    chart = lambda k, s: sl2.act(piece(k), sl2.point(sl2.flow(g, b, s)[0]))
    return first_hits(t, reduced, x_next, chart, centres, outer, inner)


@pytest.fixture(scope="module")
def space():
    return spaces.load("sl2")


def test_the_model_carries_the_cover_elements(space):
    """The model's chart maps and generator matrices agree with the cover's elements modulo 4 pi in
    phi, and the matrices' chart maps pull the metric back onto itself."""
    rng = np.random.default_rng(11)
    x = np.array([random_point(rng) for _ in range(20)])
    np.testing.assert_allclose(
        G.to_chart(G.to_model(x)), x - [0, 0, 4 * math.pi] * (x[:, 2:] > 2 * math.pi), atol=1e-12
    )
    for k in range(4):
        M = space.generators[k]
        for sign, element in ((1, lifted(k)), (-1, lifted(k + 4))):
            image = G.transform_points(M if sign > 0 else np.linalg.inv(M), x)
            want = sl2.act(element, x)
            d = image - want
            d[:, 2] = (d[:, 2] + 2 * math.pi) % (4 * math.pi) - 2 * math.pi
            np.testing.assert_allclose(d, 0, atol=1e-10)
        for p in x[:4] * [1, 1, 0]:
            J = jacobian(lambda q: G.transform_points(M, q), p)
            np.testing.assert_allclose(
                J.T @ sl2_metric(G.transform_points(M, p)) @ J, sl2_metric(p), rtol=1e-6, atol=1e-6
            )
    fibre = space.generators[4]
    y = np.c_[x[:, :2], np.ones(20)]  # phi = 1 + 2 pi is read back as 1 - 2 pi
    np.testing.assert_allclose(G.transform_points(fibre, y), y - [0, 0, TAU], atol=1e-12)
    assert not G.is_isometry(np.diag([2.0, 1.0, 1.0, 1.0]))
    assert not G.is_isometry(np.eye(4)[[1, 0, 2, 3]])


def test_the_preset_is_the_octagon_times_the_fibre(space):
    dom = space.domain
    assert len(dom.faces) == 10 and len(dom.vertices) == 16
    klein = 2 * np.hypot(dom.vertices[:, 0], dom.vertices[:, 1]) / (1 + np.sum(dom.vertices[:, :2] ** 2, axis=1))
    np.testing.assert_allclose(klein, math.sqrt(12 * SQ2 - 16), rtol=1e-12)
    np.testing.assert_allclose(sorted(set(np.round(dom.vertices[:, 2], 12))), [-math.pi, math.pi], rtol=1e-12)
    assert abs(space.volume - 4 * math.pi * TAU) < 1e-6 * space.volume  # the genus-2 area 4 pi times tau
    # the lifted relator is the fibre translation by -4 pi (docs/mathematics.md#sl2), the identity of the model
    word = [0, 3, 6, 1, 4, 7, 2, 5]  # A0 A3 A2^-1 A1 A0^-1 A3^-1 A2 A1^-1
    R = lifted(word[0])
    for k in word[1:]:
        R = sl2.multiply(R, lifted(k))
    np.testing.assert_allclose(sl2.act(R, np.array([0.2, -0.1, 0.5])), [0.2, -0.1, 0.5 - 4 * math.pi], atol=1e-9)
    inv = np.linalg.inv
    A = space.generators
    relator = A[0] @ A[3] @ inv(A[2]) @ A[1] @ inv(A[0]) @ inv(A[3]) @ A[2] @ inv(A[1])
    np.testing.assert_allclose(relator, np.eye(4), atol=1e-9)
    # the model's reduction agrees with the cover's (modulo nothing: both land in the domain)
    rng = np.random.default_rng(12)
    x = np.array([random_point(rng, 0.95) for _ in range(200)]) * [1, 1, 3]
    np.testing.assert_allclose(G.to_chart(space.move_inside(G.to_model(x))[0]), reduce_in_cover(x)[0], atol=1e-9)


def fibre_space(tau, covolume=None):
    path = spaces.preset_path("sl2")
    text = path.read_text().replace('face = [0, 0, 1, "-pi"]', f"face = [0, 0, 1, {-tau / 2!r}]")
    c, s = math.cos(tau / 2), math.sin(tau / 2)
    text = text.replace(
        "matrix = [[-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 0], [0, 0, 0, -1]]",
        f"matrix = [[{c!r}, {-s!r}, 0, 0], [{s!r}, {c!r}, 0, 0], [0, 0, {c!r}, {s!r}], [0, 0, {-s!r}, {c!r}]]",
    )
    text = text.replace('covolume = "8*pi**2"', f"covolume = {4 * math.pi * tau!r}")
    return spaces.from_data(tomllib.loads(text), "fibre.toml")


def test_the_fibre_period_must_be_4_pi_over_n():
    quarter = fibre_space(math.pi)  # n = 4
    assert abs(quarter.volume - 4 * math.pi**2) < 1e-5
    for tau in (2.4, 3 * math.pi / 2 * 1.1):
        with pytest.raises(spaces.SpaceError, match="not 4 pi / n"):
            fibre_space(tau)


TOLERANCE = 1e-6
CENTRES = np.array([[0.3, 0.1, 0.8], [-0.25, 0.3, -1.5], [0.05, -0.4, 2.2], [-0.35, -0.2, 0.0]])
RADIUS = 0.15
MESH = trimesh.creation.icosphere(subdivisions=3, radius=RADIUS)
INNER = float(np.min(np.abs(np.einsum("kj,kj->k", MESH.face_normals, MESH.triangles[:, 0]))))


def rays(space, rng, n, aim=0.5):
    """Starts inside the domain away from the balls, unit chart velocities (a fraction aimed at a ball)."""
    x = space._interior_points(rng, 4 * n)
    x = x[np.min(np.linalg.norm(x[:, None] - CENTRES[None], axis=-1), axis=1) > RADIUS + 0.05][:n]
    u = rng.normal(size=(n, 3))
    m = int(aim * n)
    u[:m] = CENTRES[rng.integers(len(CENTRES), size=m)] - x[:m] + 0.05 * u[:m]
    return x, np.array([unit(p, v) for p, v in zip(x, u)])


def trace(space, scene, x, u, length, tolerance=TOLERANCE):
    P = G.to_model(x)
    V = G.normalize_tangent(P, G.tangent_to_model(x, u))
    out = render.make_tracer(space, scene, light_reach=2.0).trace(
        np.ascontiguousarray(P), np.ascontiguousarray(V), length, 100000, shade=False, tolerance=tolerance
    )
    return P, V, out


def test_depth_matches_the_cover_geodesic_first_hit(space):
    scene = Scene(
        objects=[SceneObject(f"ball{i}", MESH.vertices + c, MESH.faces, (0.6, 0.6, 0.6)) for i, c in enumerate(CENTRES)]
    )
    rng = np.random.default_rng(13)
    x, u = rays(space, rng, 150, aim=0.8)
    u[:4] = [unit(p, sl2.act_tangent(sl2.from_origin(p), np.zeros(3), [0, 0, 1])) for p in x[:4]]  # fibre rays (a = 0)
    length = 5.0
    P, V, out = trace(space, scene, x, u, length)
    truth = lambda i: cover_hits(x[i], u[i], length, CENTRES, [RADIUS] * 4, [INNER] * 4)
    compared, hits = check_depths(G, space, out, P, V, length, CENTRES, [RADIUS] * 4, [INNER] * 4, truth=truth)
    assert compared >= 120 and hits >= 20, (compared, hits)
    assert np.all(np.isfinite(out["end"])) and not np.isnan(out["depth"][out["stop"] == 0]).any()


def end_errors(got, want):
    """|got - want| per row, phi compared modulo tau (the lid phi = -pi is phi = pi)."""
    d = np.asarray(got) - want
    d[:, 2] = (d[:, 2] + math.pi) % TAU - math.pi
    return np.abs(d).max(axis=1)


def test_long_rays_end_where_the_cover_geodesic_ends(space):
    """About 100 crossings, mostly through the lids (small horizontal speed keeps the cover's disk
    coordinates well conditioned), fibre rays (a = 0) and rays at a = |c| +- 1e-9, where the closed
    form turns from cosh to cos: each traced end is the cover geodesic's end, reduced."""
    rng = np.random.default_rng(14)
    n = 36
    x = space._interior_points(rng, n)
    a = rng.uniform(0.0, 0.02, n)
    a[:4] = 0.0
    c = np.sqrt(1 - a * a) * np.where(np.arange(n) % 2, 1, -1)
    for i, offset in zip(range(4, 10), (1e-9, -1e-9, 0.0) * 2):  # a = |c| + offset
        c[i] = np.sign(c[i]) * (math.sqrt(2 - offset**2) - offset) / 2
        a[i] = abs(c[i]) + offset
    angle = rng.uniform(0, 2 * math.pi, n)
    u = np.array(
        [sl2_body_direction(x[i], [a[i] * math.cos(angle[i]), a[i] * math.sin(angle[i]), c[i]]) for i in range(n)]
    )
    length = 100 * TAU
    length_at = np.where(a > 0.5, 12.0, length)  # the balanced rays cross the sides: far fewer lids per length
    ends = []
    for L in np.unique(length_at):
        rows = length_at == L
        _, _, out = trace(space, Scene(), x[rows], u[rows], float(L))
        assert np.all(out["stop"] == 1) and np.all(np.isfinite(out["end"]))
        want = np.array([cover_end(x[i], u[i], L) for i in np.flatnonzero(rows)])
        d = out["end"] - want
        d[:, 2] = (d[:, 2] + math.pi) % TAU - math.pi  # the lid phi = -pi is phi = pi
        ends.append((L, out["crossings"], np.abs(d).max(axis=1)))
    for L, crossings, err in ends:
        assert np.all(err < 1e-6), (L, err.max())
        if L == length:
            assert crossings.min() >= 99
    _, _, out = trace(space, Scene(), x[:4], u[:4], length)
    assert end_errors(out["end"], x[:4] + np.c_[np.zeros((4, 2)), np.sign(c[:4]) * length]).max() < 1e-9


def test_rays_near_the_rim_after_many_crossings_stay_finite_and_inside(space):
    """Horizontal rays (c = 0) from points near the octagon's vertices, across many sides: no NaN,
    every end inside the domain; where the cover's geodesic ends at 12 (beyond, the flow's chaos,
    e^(1.32 t), leaves float64 cover coordinates no digits to compare)."""
    rng = np.random.default_rng(15)
    n = 2000
    V0 = space.domain.vertices
    x = V0[rng.integers(len(V0), size=n)] * [0.999, 0.999, 0.0] + np.c_[np.zeros((n, 2)), rng.uniform(-3, 3, n)]
    angle = rng.uniform(0, 2 * math.pi, n)
    u = np.array([sl2_body_direction(p, [math.cos(t), math.sin(t), 0.0]) for p, t in zip(x, angle)])
    _, _, out = trace(space, Scene(), x, u, 30.0)
    assert np.all(out["stop"] == 1) and np.all(np.isfinite(out["end"]))
    assert space.domain.contains(G.to_model(out["end"]), tol=1e-9).all()
    assert out["crossings"].min() >= 8
    _, _, out = trace(space, Scene(), x[:40], u[:40], 12.0)
    want = np.array([cover_end(x[i], u[i], 12.0) for i in range(40)])
    assert end_errors(out["end"], want).max() < 1e-6


@pytest.mark.slow
def test_no_leak_at_the_octagon_vertices(space):
    """10^5 rays aimed at the prism's vertices and vertical edges (cover.assert_no_leak_at_the_prism_edges)."""
    assert_no_leak_at_the_prism_edges(space, math.pi, 0.15, seed=16)


def test_lambert_colour_is_base_power_cos_falloff(space):
    """Hits on a lid-like square phi = 0.4 lit by a light 0.6 above it, within a light reach of 2 (the
    light's other copies lie 3 or more away: the octagon's neighbours 2 x its inradius 1.53 across,
    the fibre's 2 pi along): colour = base * power * cos * falloff, with the geodesic to the light
    found here by scipy's root finder on the cover's closed form (chart_geodesic), the metric normal
    facing the ray and the falloff from central differences of the closed form (falloff_along), to
    the float32 colour's precision. Every copy along every geodesic: test_light_curved.py."""
    from scipy.optimize import fsolve

    colour, power = np.array([0.8, 0.6, 0.4]), 0.7
    grid = np.linspace(-0.35, 0.35, 8)
    X, Y = np.meshgrid(grid, grid)
    square = trimesh.Trimesh(
        np.c_[X.ravel(), Y.ravel(), np.full(64, 0.4)],
        [[i * 8 + j, i * 8 + j + 1, i * 8 + j + 9] for i in range(7) for j in range(7)]
        + [[i * 8 + j, i * 8 + j + 9, i * 8 + j + 8] for i in range(7) for j in range(7)],
    )
    light = np.array([0.05, -0.05, 1.0])
    scene = Scene(
        objects=[SceneObject("square", square.vertices, square.faces, colour)],
        lights=[PointLight(light, np.ones(3), power)],
    )
    rng = np.random.default_rng(17)
    n = 300
    x = np.c_[rng.uniform(-0.3, 0.3, (n, 2)), rng.uniform(1.2, 1.6, n)]
    u = np.array([unit(p, [rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), -1.0]) for p in x])
    P = G.to_model(x)
    V = G.normalize_tangent(P, G.tangent_to_model(x, u))
    out = render.make_tracer(space, scene, light_reach=2.0).trace(
        np.ascontiguousarray(P), np.ascontiguousarray(V), 3.0, 100, shade=True, tolerance=1e-7
    )
    rows = np.flatnonzero(out["stop"] == 0)
    assert len(rows) >= 100 and int(out["light_failures"]) == 0
    checked = 0
    for i in rows[:60]:
        h = out["position"][i]
        frame = np.linalg.inv(np.linalg.cholesky(sl2_metric(h)).T)  # columns orthonormal at h

        def miss(w):
            r = np.linalg.norm(w)
            return G.chart_geodesic(h, frame @ (w / r), r)[0] - light

        w = fsolve(miss, np.linalg.solve(frame, light - h), xtol=1e-13)
        assert np.abs(miss(w)).max() < 1e-10
        r = np.linalg.norm(w)
        to_light = frame @ (w / r)
        normal = np.linalg.solve(sl2_metric(h), [0.0, 0.0, 1.0])
        normal /= math.sqrt(normal[2])  # unit: n . g^-1 n = normal[2] for the covector (0, 0, 1)
        cos = abs(normal @ sl2_metric(h) @ to_light)  # the rays come from above, as the light
        H = G.to_model(h)
        falloff = float(G.falloff_along(H, G.normalize_tangent(H, G.tangent_to_model(h, to_light)), np.array(r)))
        want = colour * power * cos * falloff
        np.testing.assert_allclose(out["color"][i], want, rtol=2e-5)
        checked += 1
    assert checked == 60
