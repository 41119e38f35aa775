"""S2xR against independent truth.

The metric is truth.s2xr_metric (|dx|^2 / |x|^2); its derivatives are written here and checked
against finite differences, the Christoffel symbols and the geodesic equation are built from them
and integrated with DOP853 at 1e-12. Isometries are checked by pulling the metric back. Depth is checked against the first entry of the
closed-form geodesic, followed in the universal cover and carried into the shell by the group, into
chart spheres (the mesh lies between its inscribed and circumscribed spheres).
"""
import math

import numpy as np
import pytest
import trimesh

from thurston_addon import render, spaces
from thurston_addon.geometries import get
from thurston_addon.scene import Scene, SceneObject
from cover import check_depths
from truth import check_flows_against_dop853, christoffel_from, s2xr_metric, unit_in

G = get("S2xR")


def metric_derivative(x):
    """dg[l, i, j] = d g_ij / d x_l = -2 x_l delta_ij / |x|^4."""
    return -2 * np.einsum("l,ij->lij", x, np.eye(3)) / (x @ x) ** 2


def christoffel_truth(x):
    return christoffel_from(s2xr_metric(x), metric_derivative(x))


def unit(x, u):
    return unit_in(s2xr_metric, x, u)


def shell_points(rng, n, lo=-1.0, hi=2.0):
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1)[:, None] * np.exp(rng.uniform(lo, hi, n))[:, None]


def test_metric_christoffel_and_density_from_the_formula():
    rng = np.random.default_rng(1)
    for x in shell_points(rng, 20):
        np.testing.assert_allclose(G.metric(x), s2xr_metric(x), rtol=1e-14)
        h = 1e-6 * np.linalg.norm(x)
        fd = np.stack([(s2xr_metric(x + e) - s2xr_metric(x - e)) / (2 * h) for e in h * np.eye(3)])
        np.testing.assert_allclose(metric_derivative(x), fd, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(G.christoffel(x), christoffel_truth(x), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(G.volume_density(x), math.sqrt(np.linalg.det(s2xr_metric(x))), rtol=1e-12)


def geodesic_cases(rng):
    """(start, unit chart velocity, length): random, purely radial (a = 0) and purely tangential (b = 0)."""
    cases = [(x, unit(x, rng.normal(size=3)), rng.uniform(0.5, 5)) for x in shell_points(rng, 12)]
    cases += [(x, unit(x, x), 3.0) for x in shell_points(rng, 3)]
    cases += [(x, unit(x, -x), 3.0) for x in shell_points(rng, 2)]
    cases += [(x, unit(x, np.cross(x, rng.normal(size=3))), 5.0) for x in shell_points(rng, 3)]
    return cases


def test_closed_forms_match_dop853_of_the_geodesic_equation():
    check_flows_against_dop853(G, christoffel_truth, s2xr_metric, geodesic_cases(np.random.default_rng(2)),
                               speed_tol=1e-12)


def test_radial_and_tangential_geodesics_are_the_product_s_lines_and_great_circles():
    x = np.array([0.0, 0.0, 2.0])
    xt, _ = G.chart_geodesic(x, unit(x, x), 1.5)  # w grows at unit speed along the ray
    np.testing.assert_allclose(xt, [0, 0, 2 * math.exp(1.5)], rtol=1e-14)
    xt, _ = G.chart_geodesic(x, unit(x, [1.0, 0, 0]), math.pi / 2)  # a quarter of a great circle, |x| kept
    np.testing.assert_allclose(xt, [2, 0, 0], atol=1e-14)


def random_isometries(rng, n):
    out = []
    for _ in range(n):
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        out.append(G.similarity(Q, rng.uniform(-2, 2)))
    return out


def test_isometries_pull_the_metric_back_onto_itself():
    rng = np.random.default_rng(3)
    for M in random_isometries(rng, 8):
        assert G.is_isometry(M)
        for x in shell_points(rng, 5):
            A = M[:3, :3]
            np.testing.assert_allclose(A.T @ s2xr_metric(A @ x) @ A, s2xr_metric(x), rtol=1e-12, atol=1e-14 * s2xr_metric(x)[0, 0])
    shear = np.eye(4)
    shear[0, 1] = 0.5
    translation = np.eye(4)
    translation[0, 3] = 1.0
    assert not G.is_isometry(shear) and not G.is_isometry(translation)


def test_connect_distance_and_falloff_in_closed_form():
    rng = np.random.default_rng(4)
    A, B = shell_points(rng, 30), shell_points(rng, 30)
    V, r, ok = G.connect(G.to_model(A), G.to_model(B))
    assert ok.all()
    X, _ = G.geodesic(G.to_model(A), V, r)
    np.testing.assert_allclose(G.to_chart(X), B, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(G.dot(G.to_model(A), V, V), 1.0, rtol=1e-13)
    # the product distance: the angle of the directions and the difference of log|x|
    angle = np.arccos(np.clip(np.sum(A * B, 1) / np.linalg.norm(A, axis=1) / np.linalg.norm(B, axis=1), -1, 1))
    np.testing.assert_allclose(r, np.hypot(angle, np.log(np.linalg.norm(B, axis=1) / np.linalg.norm(A, axis=1))),
                               rtol=1e-9)
    # the falloff is 1 / the wavefront's area per unit solid angle (finite differences of the closed form)
    P = G.to_model(A[:5])
    for p, v, d in zip(P, V[:5], r[:5]):
        E = np.linalg.svd(np.c_[v[:3]])[0][:, 1:]  # a chart basis of v's orthogonal complement
        x = G.to_chart(p)
        frame = [e / math.sqrt(e @ s2xr_metric(x) @ e) for e in E.T]
        h = 1e-6
        end = G.to_chart(G.geodesic(p, v, d)[0])
        J = []
        for e in frame:
            w = G.normalize_tangent(p, v + h * np.r_[e, 0])
            J.append((G.to_chart(G.geodesic(p, w, d)[0]) - end) / h)
        g = s2xr_metric(end)
        area = math.sqrt(np.linalg.det(np.array([[a @ g @ b for b in J] for a in J])))
        np.testing.assert_allclose(1.0 / G.falloff_along(p, v, d), area, rtol=1e-4)


# --- the s2xs1 preset and tracing ------------------------------------------------------------------

L = 2 * math.pi


@pytest.fixture(scope="module")
def space():
    return spaces.load("s2xs1")


def test_the_preset_is_the_shell_glued_by_the_dilation(space):
    assert [f.covector.tolist() for f in space.domain.faces] == [[0, 0, 1, -L], [0, 0, -1, 0]]
    assert space.domain.faces[0].partner == 1 and space.domain.faces[1].partner == 0
    np.testing.assert_allclose(space.generators[0], np.diag([math.exp(L)] * 3 + [1.0]), rtol=1e-15)
    assert abs(space.volume - 4 * math.pi * L) < 1e-9 * space.volume
    rng = np.random.default_rng(5)
    x = space._interior_points(rng, 50)
    assert np.all((np.linalg.norm(x, axis=1) > 1) & (np.linalg.norm(x, axis=1) < math.exp(L)))
    for k in (-3, -1, 1, 2):  # e^{kL} x and a rotation of it reduce to x (the rotation stays)
        Y, _, _ = space.move_inside(G.to_model(x * math.exp(k * L)))
        np.testing.assert_allclose(G.to_chart(Y), x, rtol=1e-12)


def test_shell_faces_that_are_not_spheres_are_refused(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('geometry = "S2xR"\n[[generator]]\nmatrix = [[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]]\n'
                    'face = [1, 0, 0, -1]\n[camera]\nposition = [1.5, 0, 0]\n')
    with pytest.raises(spaces.SpaceError, match="is not a sphere"):
        spaces.load(path)


MESH = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
MESH_INNER = float(np.min(np.abs(np.einsum("kj,kj->k", MESH.face_normals, MESH.triangles[:, 0]))))
# balls of metric radius about 0.2 at w = 1, 2.5, 4 and 5.5
CENTRES = np.array([[math.exp(1.0), 0, 0], [0, math.exp(2.5), 0], [0, 0, -math.exp(4.0)], [-3.0, 3.0, math.exp(5.5)]])
SIZES = 0.2 * np.linalg.norm(CENTRES, axis=1)


def test_depth_matches_the_cover_geodesic_first_hit(space):
    """Copies e^{kL} x of the balls in the cover are what the reduction of the cover geodesic meets."""
    scene = Scene(objects=[SceneObject(f"ball{i}", s * MESH.vertices + c, MESH.faces, (0.6, 0.6, 0.6))
                           for i, (c, s) in enumerate(zip(CENTRES, SIZES))])
    tracer = render.make_tracer(space, scene)
    rng = np.random.default_rng(6)
    n, length = 100, 8.0
    x = space._interior_points(rng, 8 * n)
    x = x[np.min(np.linalg.norm(x[:, None] - CENTRES[None], axis=-1) - SIZES, axis=1) > 0.05 * np.linalg.norm(x, axis=1)][:n]
    u = rng.normal(size=(n, 3))
    u[:5] = x[:5]  # purely radial (a = 0)
    u[5:10] = np.cross(x[5:10], u[5:10])  # purely tangential (b = 0)
    P = G.to_model(x)
    V = G.normalize_tangent(P, G.tangent_to_model(x, u))
    # half of them along the connecting geodesic to a ball's centre (in the domain), turned a little
    aim = G.connect(P[n // 2:], G.to_model(CENTRES[rng.integers(len(CENTRES), size=n - n // 2)]))[0]
    V[n // 2:] = G.normalize_tangent(P[n // 2:], aim + 0.1 * np.c_[x[n // 2:] * rng.normal(size=(n - n // 2, 3)), np.zeros(n - n // 2)])
    out = tracer.trace(np.ascontiguousarray(P), np.ascontiguousarray(V), length, 10000, shade=False, tolerance=1e-6)
    compared, hits = check_depths(G, space, out, P, V, length, CENTRES, SIZES, MESH_INNER * SIZES)
    assert compared >= 70 and hits >= 20, (compared, hits)
    assert np.all(np.isfinite(out["end"]))


def test_long_rays_end_where_the_cover_geodesic_ends(space):
    """100 crossings: the traced end is the cover geodesic's end reduced (radial rays: known exactly)."""
    tracer = render.make_tracer(space, Scene())
    rng = np.random.default_rng(7)
    n = 40
    x = space._interior_points(rng, n)
    u = rng.normal(size=(n, 3))
    u[:5] = x[:5]  # purely radial
    P = G.to_model(x)
    V = G.normalize_tangent(P, G.tangent_to_model(x, u))
    b = np.sum(G.tangent_to_chart(P, V) * x, axis=1) / np.sum(x * x, axis=1)  # the speed of w
    length = 100 * L / np.abs(b)  # about 100 crossings each
    for i in range(n):
        out = tracer.trace(np.ascontiguousarray(P[i:i + 1]), np.ascontiguousarray(V[i:i + 1]), float(length[i]), 100000,
                           shade=False, tolerance=1e-6)
        assert out["stop"][0] == 1 and out["crossings"][0] >= 99
        Y, _ = G.geodesic(np.asarray(P[i], np.longdouble), np.asarray(V[i], np.longdouble), np.longdouble(length[i]))
        X, _, _ = space.move_inside(Y[None])
        want = np.asarray(G.to_chart(X[0]), float)
        assert np.linalg.norm(out["end"][0] - want) < 1e-7 * np.linalg.norm(want), (i, out["end"][0], want)
        if i < 5:
            np.testing.assert_allclose(out["end"][0], x[i], rtol=1e-9)  # 100 L along the ray: back at the start


def test_radial_and_tangential_rays_stay_finite_and_inside(space):
    """a = 0 (radial, in and out) and b = 0 (along great circles, never crossing), with and without
    a scene: no NaN, every end inside the shell, no other stop."""
    rng = np.random.default_rng(8)
    n = 20000
    x = space._interior_points(rng, n)
    u = np.where(rng.random(n)[:, None] < 0.5, 1.0, -1.0) * x
    u[n // 2:] = np.cross(x[n // 2:], rng.normal(size=(n - n // 2, 3)))
    P = G.to_model(x)
    V = G.normalize_tangent(P, G.tangent_to_model(x, u))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=5.0)
    for scene in (Scene(), Scene(objects=[SceneObject("ball", ball.vertices + [0, 0, 20.0], ball.faces, (1, 1, 1))])):
        out = render.make_tracer(space, scene).trace(np.ascontiguousarray(P), np.ascontiguousarray(V), 30.0, 1000,
                                                    shade=False, tolerance=1e-3)
        assert np.all((out["stop"] == 0) | (out["stop"] == 1)), np.bincount(out["stop"])
        assert np.all(np.isfinite(out["end"]))
        assert space.domain.contains(G.to_model(out["end"]), tol=1e-9).all()
        assert np.all(out["crossings"][: n // 2][out["stop"][: n // 2] == 1] >= 4)
        assert np.all(out["crossings"][n // 2:] == 0)
        r = np.linalg.norm(out["end"][n // 2:], axis=1)
        free = out["stop"][n // 2:] == 1
        np.testing.assert_allclose(r[free], np.linalg.norm(x[n // 2:], axis=1)[free], rtol=1e-9)  # |x| kept


def test_the_default_scene_is_shown_whole():
    """The great circles of the default scene average to the chart's missing origin: they are
    brought home by their vertices, and nothing of the scene is dropped or cut."""
    import warnings

    from thurston_addon.scene import default_scene

    space = spaces.load("s2xs1")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        render.compile_scene(space, default_scene(space))
