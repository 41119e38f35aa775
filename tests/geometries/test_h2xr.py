"""H2xR and the genus2xs1 preset against independent truth.

The metric is truth.h2xr_metric (Klein disk x R); its derivatives are written here and checked
against finite differences, the Christoffel symbols and the geodesic equation are built from them
and integrated with DOP853 at 1e-12. Depth is checked against the first entry of the closed-form
geodesic, followed in the universal cover and carried into the domain by the group, into chart
spheres inside the domain (the mesh lies between its inscribed and circumscribed spheres).
"""

import math

import numpy as np
import pytest
import trimesh
from support.cover import assert_no_leak_at_the_prism_edges, check_depths
from support.truth import check_flows_against_dop853, christoffel_from, h2xr_metric, unit_in

from thurston_addon import render, spaces
from thurston_addon.geometries import get
from thurston_addon.scenes import Scene, SceneObject

G = get("H2xR")
SQ2 = math.sqrt(2.0)
PERIOD = math.acosh(5 + 4 * SQ2)  # L = 2 r_in
SIDE = math.sqrt(2 * SQ2 - 2)  # Klein distance of the octagon's sides


@pytest.fixture(scope="module")
def space():
    return spaces.load("genus2xs1")


def metric_derivative(x):
    """dg[l, i, j] = d g_ij / d x_l of the Klein block: with q = 1 - r^2,
    d_l (delta_ij / q + x_i x_j / q^2) = 2 x_l delta_ij / q^2 + (delta_il x_j + x_i delta_jl) / q^2 + 4 x_l x_i x_j / q^3."""
    p = np.array([x[0], x[1], 0.0])
    q = 1.0 - p @ p
    flat = np.diag([1.0, 1.0, 0.0])
    dg = 2 * np.einsum("l,ij->lij", p, flat) / q**2
    dg += (np.einsum("il,j->lij", flat, p) + np.einsum("i,jl->lij", p, flat)) / q**2
    dg += 4 * np.einsum("l,i,j->lij", p, p, p) / q**3
    return dg


def christoffel_truth(x):
    return christoffel_from(h2xr_metric(x), metric_derivative(x))


def unit(x, u):
    return unit_in(h2xr_metric, x, u)


def disk_points(rng, n, radius=0.95, height=2.0):
    r = radius * np.sqrt(rng.random(n))
    a = rng.uniform(0, 2 * math.pi, n)
    return np.c_[r * np.cos(a), r * np.sin(a), rng.uniform(-height, height, n)]


def test_metric_christoffel_and_density_from_the_formula():
    rng = np.random.default_rng(1)
    for x in disk_points(rng, 20):
        np.testing.assert_allclose(G.metric(x), h2xr_metric(x), rtol=1e-14)
        h = 1e-6
        fd = np.stack([(h2xr_metric(x + e) - h2xr_metric(x - e)) / (2 * h) for e in h * np.eye(3)])
        np.testing.assert_allclose(metric_derivative(x), fd, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(G.christoffel(x), christoffel_truth(x), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(G.volume_density(x), math.sqrt(np.linalg.det(h2xr_metric(x))), rtol=1e-12)


def geodesic_cases(rng):
    """(start, unit chart velocity, length): random, near the disk's boundary, purely vertical and
    purely horizontal."""
    cases = [(x, unit(x, rng.normal(size=3)), rng.uniform(0.5, 4)) for x in disk_points(rng, 12)]
    cases += [
        (x, unit(x, rng.normal(size=3)), 2.0)
        for x in disk_points(rng, 4, radius=0.999)[:, :] * [1, 1, 1]
        if np.hypot(x[0], x[1]) > 0.5
    ]
    cases += [(x, np.array([0.0, 0.0, 1.0]), 3.0) for x in disk_points(rng, 3)]
    cases += [(x, unit(x, np.r_[rng.normal(size=2), 0.0]), 3.0) for x in disk_points(rng, 3)]
    return cases


def test_closed_forms_match_dop853_of_the_geodesic_equation():
    # unit speed to 1e-10: rounding where the metric is 1e7 (r = 0.995)
    check_flows_against_dop853(G, christoffel_truth, h2xr_metric, geodesic_cases(np.random.default_rng(2)))


def some_isometries(space, rng):
    words = [*space.generators, *(np.linalg.inv(M) for M in space.generators)]
    out = list(words)
    for _ in range(6):
        W = np.eye(4)
        for k in rng.integers(0, len(words), 3):
            W = W @ words[k]
        out.append(W)
    return out


def chart_map(M, x):
    """The chart image and Jacobian of M = A (+) e^c written out: (x, y) -> the projective image
    (A (x, y, 1))[:2] / (A (x, y, 1))[2] by the quotient rule, z -> z + c."""
    A = M[np.ix_([0, 1, 3], [0, 1, 3])]
    h = A @ np.array([x[0], x[1], 1.0])
    y = np.array([h[0] / h[2], h[1] / h[2], x[2] + math.log(M[2, 2])])
    J = np.eye(3)
    J[:2, :2] = (A[:2, :2] - np.outer(y[:2], A[2, :2])) / h[2]
    return y, J


def test_isometries_pull_back_the_metric(space):
    """J^T g(M x) J = g(x) for the generators, their inverses and words of them."""
    rng = np.random.default_rng(3)
    for M in some_isometries(space, rng):
        for x in disk_points(rng, 4, radius=0.6):
            y, J = chart_map(M, x)
            np.testing.assert_allclose(G.transform_points(M, x), y, atol=1e-12)
            np.testing.assert_allclose(
                J.T @ h2xr_metric(y) @ J, h2xr_metric(x), rtol=1e-6, atol=1e-7
            )  # words: entries ~1e3
    assert not G.is_isometry(np.diag([2.0, 1.0, 1.0, 1.0]))
    coupled = np.eye(4)
    coupled[2, 0] = 0.1
    assert not G.is_isometry(coupled)


def test_the_preset_is_the_octagon_times_the_period(space):
    dom = space.domain
    assert len(dom.faces) == 10 and len(dom.vertices) == 16
    r = np.hypot(dom.vertices[:, 0], dom.vertices[:, 1])
    np.testing.assert_allclose(r, math.sqrt(12 * SQ2 - 16), rtol=1e-12)
    np.testing.assert_allclose(sorted(set(np.round(dom.vertices[:, 2], 12))), [-PERIOD / 2, PERIOD / 2], rtol=1e-12)
    assert abs(space.volume - 4 * math.pi * PERIOD) < 1e-6 * space.volume
    A = space.generators
    inv = np.linalg.inv
    relator = A[0] @ A[3] @ inv(A[2]) @ A[1] @ inv(A[0]) @ inv(A[3]) @ A[2] @ inv(A[1])
    np.testing.assert_allclose(relator, np.eye(4), atol=1e-9)
    # A_k maps the side s_{k+4} onto s_k: the Klein side points at angle (k+4) pi / 4 to angle k pi / 4
    for k in range(4):
        a = (k + 4) * math.pi / 4
        p = G.transform_points(A[k], np.array([SIDE * math.cos(a), SIDE * math.sin(a), 0.3]))
        np.testing.assert_allclose(
            p, [SIDE * math.cos(k * math.pi / 4), SIDE * math.sin(k * math.pi / 4), 0.3], atol=1e-12
        )
    # unique reduction: points and their images under words reduce to one point
    rng = np.random.default_rng(4)
    x = space._interior_points(rng, 50)
    for W in some_isometries(space, rng):
        Y, _, _ = space.move_inside(G.to_model(x) @ W.T)
        np.testing.assert_allclose(G.to_chart(Y), x, atol=1e-7)  # rounding of 3-letter words (entries ~1e3)


def test_connect_and_falloff_in_closed_form():
    rng = np.random.default_rng(5)
    A, B = G.to_model(disk_points(rng, 50)), G.to_model(disk_points(rng, 50))
    V, r, ok = G.connect(A, B)
    assert ok.all()
    X, _ = G.geodesic(A, V, r)
    np.testing.assert_allclose(G.to_chart(X), G.to_chart(B), atol=1e-10)
    # the falloff is 1 / (r^2 det d exp) by central differences of the closed form, in orthonormal frames
    for P, v, rr in zip(A[:5], V[:5], r[:5]):
        x = G.to_chart(P)
        L = np.linalg.cholesky(h2xr_metric(x))
        frame = np.linalg.inv(L.T)  # columns orthonormal at x
        w = np.linalg.solve(frame, G.tangent_to_chart(P, v)) * rr
        expo = lambda w: G.chart_geodesic(x, frame @ w, np.linalg.norm(w))[0]
        h = 1e-6
        J = np.stack([(expo(w + e) - expo(w - e)) / (2 * h) for e in h * np.eye(3)], -1)
        y = expo(w)
        det = np.linalg.det(np.linalg.cholesky(h2xr_metric(y)).T @ J)
        np.testing.assert_allclose(G.falloff_along(P, v, rr), 1 / (rr * rr * det), rtol=1e-6)


# --- tracing -----------------------------------------------------------------------------------

CENTRES = np.array([[0.45, 0.1, 0.5], [-0.3, 0.4, -0.7], [0.05, -0.55, 1.0], [-0.5, -0.3, 0.2]])
RADIUS = 0.14
TOLERANCE = 1e-6


MESH = trimesh.creation.icosphere(subdivisions=3, radius=RADIUS)
INNER = float(np.min(np.abs(np.einsum("kj,kj->k", MESH.face_normals, MESH.triangles[:, 0]))))
OUTER = RADIUS


def test_depth_matches_the_cover_geodesic_first_hit(space):
    scene = Scene(
        objects=[SceneObject(f"ball{i}", MESH.vertices + c, MESH.faces, (0.6, 0.6, 0.6)) for i, c in enumerate(CENTRES)]
    )
    tracer = render.make_tracer(space, scene)
    rng = np.random.default_rng(6)
    n, length = 120, 6.0
    x = space._interior_points(rng, 4 * n)
    x = x[np.min(np.linalg.norm(x[:, None] - CENTRES[None], axis=-1), axis=1) > RADIUS + 0.05][:n]
    u = rng.normal(size=(n, 3))
    u[: n // 2] = CENTRES[rng.integers(len(CENTRES), size=n // 2)] - x[: n // 2] + 0.1 * u[: n // 2]  # towards a ball
    u[:5] = [0, 0, 1]  # purely vertical
    u[5:10, 2] = 0  # purely horizontal
    P = G.to_model(x)
    V = G.normalize_tangent(P, G.tangent_to_model(x, u))
    out = tracer.trace(
        np.ascontiguousarray(P), np.ascontiguousarray(V), length, 10000, shade=False, tolerance=TOLERANCE
    )
    compared, hits = check_depths(G, space, out, P, V, length, CENTRES, [OUTER] * len(CENTRES), [INNER] * len(CENTRES))
    assert compared >= 80 and hits >= 20, (compared, hits)
    assert np.all(np.isfinite(out["end"])) and not np.isnan(out["depth"][out["stop"] == 0]).any()


def test_long_rays_end_where_the_cover_geodesic_ends(space):
    """About 100 crossings (mostly through the lids; the horizontal speed is kept small so that the
    cover's coordinates stay well conditioned): the traced end is the cover geodesic's end reduced."""
    tracer = render.make_tracer(space, Scene())
    rng = np.random.default_rng(7)
    n = 40
    x = space._interior_points(rng, n)
    a = rng.uniform(0.0, 0.03, n)
    a[:5] = 0.0  # purely vertical: the end is known exactly
    angle = rng.uniform(0, 2 * math.pi, n)
    u = np.c_[a * np.cos(angle), a * np.sin(angle), np.sqrt(1 - a * a)]
    P = G.to_model(x)
    V = G.normalize_tangent(P, G.tangent_to_model(x, np.array([frame_direction(x[i], u[i]) for i in range(n)])))
    length = 100 * PERIOD
    out = tracer.trace(
        np.ascontiguousarray(P), np.ascontiguousarray(V), length, 100000, shade=False, tolerance=TOLERANCE
    )
    assert np.all(out["stop"] == 1) and np.all(out["crossings"] >= 99)
    Y, _ = G.geodesic(np.asarray(P, np.longdouble), np.asarray(V, np.longdouble), np.longdouble(length))
    X, _, _ = space.move_inside(Y)
    want = np.asarray(G.to_chart(X), float)
    err = np.linalg.norm(out["end"] - want, axis=1)
    assert np.all(err < 1e-6), err.max()
    z = (x[:5, 2] + length + PERIOD / 2) % PERIOD - PERIOD / 2
    np.testing.assert_allclose(out["end"][:5], np.c_[x[:5, :2], z], atol=1e-9)


def frame_direction(x, u):
    """The chart vector at x whose components in the orthonormal frame (the Klein metric's
    Cholesky frame) are u."""
    L = np.linalg.cholesky(h2xr_metric(x))
    return np.linalg.solve(L.T, u)


def test_horizontal_rays_and_points_near_the_boundary_stay_finite_and_inside(space):
    """Horizontal rays across many sides, from points near the octagon's vertices (r up to 0.985):
    no NaN, every end inside the domain."""
    tracer = render.make_tracer(space, Scene())
    rng = np.random.default_rng(8)
    n = 2000
    V0 = space.domain.vertices
    corner = V0[rng.integers(len(V0), size=n)]
    x = corner * [0.999, 0.999, 0.0] + np.c_[np.zeros((n, 2)), rng.uniform(-1, 1, n)]
    u = rng.normal(size=(n, 3))
    u[: n // 2, 2] = 0.0
    P = G.to_model(x)
    V = G.normalize_tangent(P, G.tangent_to_model(x, u))
    out = tracer.trace(np.ascontiguousarray(P), np.ascontiguousarray(V), 40.0, 100000, shade=False, tolerance=TOLERANCE)
    assert np.all(out["stop"] == 1)
    assert np.all(np.isfinite(out["end"]))
    assert space.domain.contains(G.to_model(out["end"]), tol=1e-9).all()
    assert out["crossings"][: n // 2].min() >= 10


def test_no_leak_at_the_octagon_vertices(space):
    """10^5 rays aimed at the prism's vertices and vertical edges (cover.assert_no_leak_at_the_prism_edges)."""
    assert_no_leak_at_the_prism_edges(space, PERIOD / 2, 0.2, seed=9)
