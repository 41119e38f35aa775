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
from support.cover import check_depths, first_hits
from support.truth import check_flows_against_dop853, christoffel_from, s2xr_metric, unit_in

from thurston_addon import render, spaces
from thurston_addon.geometries import get
from thurston_addon.scenes import Scene, SceneObject

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
    check_flows_against_dop853(
        G, christoffel_truth, s2xr_metric, geodesic_cases(np.random.default_rng(2)), speed_tol=1e-12
    )


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
            np.testing.assert_allclose(
                A.T @ s2xr_metric(A @ x) @ A, s2xr_metric(x), rtol=1e-12, atol=1e-14 * s2xr_metric(x)[0, 0]
            )
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
    np.testing.assert_allclose(
        r, np.hypot(angle, np.log(np.linalg.norm(B, axis=1) / np.linalg.norm(A, axis=1))), rtol=1e-9
    )
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
    path.write_text(
        'geometry = "S2xR"\n[[generator]]\nmatrix = [[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]]\n'
        "face = [1, 0, 0, -1]\n[camera]\nposition = [1.5, 0, 0]\n"
    )
    with pytest.raises(spaces.SpaceError, match="is not a sphere"):
        spaces.load(path)


MESH = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
MESH_INNER = float(np.min(np.abs(np.einsum("kj,kj->k", MESH.face_normals, MESH.triangles[:, 0]))))
# balls of metric radius about 0.2 at w = 1, 2.5, 4 and 5.5
CENTRES = np.array([[math.exp(1.0), 0, 0], [0, math.exp(2.5), 0], [0, 0, -math.exp(4.0)], [-3.0, 3.0, math.exp(5.5)]])
SIZES = 0.2 * np.linalg.norm(CENTRES, axis=1)


def test_depth_matches_the_cover_geodesic_first_hit(space):
    """Copies e^{kL} x of the balls in the cover are what the reduction of the cover geodesic meets."""
    scene = Scene(
        objects=[
            SceneObject(f"ball{i}", s * MESH.vertices + c, MESH.faces, (0.6, 0.6, 0.6))
            for i, (c, s) in enumerate(zip(CENTRES, SIZES))
        ]
    )
    tracer = render.make_tracer(space, scene)
    rng = np.random.default_rng(6)
    n, length = 100, 8.0
    x = space._interior_points(rng, 8 * n)
    x = x[
        np.min(np.linalg.norm(x[:, None] - CENTRES[None], axis=-1) - SIZES, axis=1) > 0.05 * np.linalg.norm(x, axis=1)
    ][:n]
    u = rng.normal(size=(n, 3))
    u[:5] = x[:5]  # purely radial (a = 0)
    u[5:10] = np.cross(x[5:10], u[5:10])  # purely tangential (b = 0)
    P = G.to_model(x)
    V = G.normalize_tangent(P, G.tangent_to_model(x, u))
    # half of them along the connecting geodesic to a ball's centre (in the domain), turned a little
    aim = G.connect(P[n // 2 :], G.to_model(CENTRES[rng.integers(len(CENTRES), size=n - n // 2)]))[0]
    V[n // 2 :] = G.normalize_tangent(
        P[n // 2 :], aim + 0.1 * np.c_[x[n // 2 :] * rng.normal(size=(n - n // 2, 3)), np.zeros(n - n // 2)]
    )
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
        out = tracer.trace(
            np.ascontiguousarray(P[i : i + 1]),
            np.ascontiguousarray(V[i : i + 1]),
            float(length[i]),
            100000,
            shade=False,
            tolerance=1e-6,
        )
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
    u[n // 2 :] = np.cross(x[n // 2 :], rng.normal(size=(n - n // 2, 3)))
    P = G.to_model(x)
    V = G.normalize_tangent(P, G.tangent_to_model(x, u))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=5.0)
    for scene in (Scene(), Scene(objects=[SceneObject("ball", ball.vertices + [0, 0, 20.0], ball.faces, (1, 1, 1))])):
        out = render.make_tracer(space, scene).trace(
            np.ascontiguousarray(P), np.ascontiguousarray(V), 30.0, 1000, shade=False, tolerance=1e-3
        )
        assert np.all((out["stop"] == 0) | (out["stop"] == 1)), np.bincount(out["stop"])
        assert np.all(np.isfinite(out["end"]))
        assert space.domain.contains(G.to_model(out["end"]), tol=1e-9).all()
        assert np.all(out["crossings"][: n // 2][out["stop"][: n // 2] == 1] >= 4)
        assert np.all(out["crossings"][n // 2 :] == 0)
        r = np.linalg.norm(out["end"][n // 2 :], axis=1)
        free = out["stop"][n // 2 :] == 1
        np.testing.assert_allclose(r[free], np.linalg.norm(x[n // 2 :], axis=1)[free], rtol=1e-9)  # |x| kept


def test_the_default_scene_is_shown_whole():
    """The great circles of the default scene average to the chart's missing origin: they are
    brought home by their vertices, and nothing of the scene is dropped or cut."""
    import warnings

    from thurston_addon.scenes import default_scene

    space = spaces.load("s2xs1")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        render.compile_scene(space, default_scene(space))


# --- RP^3 # RP^3: the shell with each sphere glued to itself antipodally ------------------------------


@pytest.fixture(scope="module")
def folded():
    return spaces.load("rp3_rp3")


def reflected_ball(c, s):
    """The inner sphere's antipodal reflection y -> -y / |y|^2 of the chart ball |y - c| <= s (not
    holding the origin), written out: inversions map spheres to spheres, this one to the ball of
    centre -c / (|c|^2 - s^2) and radius s / (|c|^2 - s^2)."""
    q = c @ c - s * s
    return -c / q, s / q


def rp3_cover_balls(centres, sizes, inner_ratio):
    """The balls' copies in the universal cover R^3 minus the origin under RP^3 # RP^3's deck group:
    the dilations by e^{4 pi k} and the reflections of those (centres, circumscribed and inscribed
    radii: a mesh between its spheres maps between their images)."""
    out = []
    for c, s in zip(centres, sizes):
        for k in range(-2, 3):
            d = math.exp(4 * math.pi * k)
            out.append((d * c, d * s, d * s * inner_ratio))
            rc, rs = reflected_ball(d * c, d * s)
            _, ri = reflected_ball(d * c, d * s * inner_ratio)
            out.append((rc, rs, ri))
    centres, outer, inner = map(np.array, zip(*out))
    return centres, outer, inner


def test_rp3_rp3_is_the_shell_glued_to_itself(folded):
    assert folded.radii == (1.0, pytest.approx(math.exp(L)))
    assert abs(folded.volume - 4 * math.pi * L) < 1e-6 * folded.volume
    assert folded.inradius == pytest.approx(L / 2)
    # the tracer's domain is the double cover's: the shell doubled by the inner reflection
    w = sorted(-f.covector[3] / f.covector[2] for f in folded.domain.faces)
    np.testing.assert_allclose(w, [-L, L], atol=1e-12)
    x = np.array([[0.3, -2.0, 5.0], [40.0, 1.0, -7.0]])
    back, _ = folded.unfolded(-x / np.sum(x * x, axis=1)[:, None])
    np.testing.assert_allclose(back, x, rtol=1e-12)


@pytest.mark.parametrize(
    "change, message",
    [
        (
            (
                'antipodal = true\nface = [0, 0, 1, "-2*pi"]',
                'matrix = [[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]]\nface = [0, 0, 1, "-2*pi"]',
            ),
            "every generator is 'antipodal = true'",
        ),
        (("face = [0, 0, -1, 0]", "face = [1, 0, 0, -1]"), "is not a sphere"),
        (("face = [0, 0, -1, 0]", "face = [0, 0, 1, -1]"), "do not bound a shell"),
        (
            (
                "antipodal = true\nface = [0, 0, -1, 0]",
                "antipodal = true\nmatrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], "
                "[0, 0, 0, 1]]\nface = [0, 0, -1, 0]",
            ),
            "has no matrix",
        ),
    ],
)
def test_bad_folded_shells_are_one_clear_error(tmp_path, change, message):
    text = spaces.preset_path("rp3_rp3").read_text()
    assert change[0] in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(change[0], change[1], 1))
    with pytest.raises(spaces.SpaceError, match=message):
        spaces.load(path)


def test_rp3_rp3_depth_matches_the_cover_geodesic_first_hit(folded):
    """The universal cover R^3 minus the origin holds the balls' copies under the deck group (the
    dilations by e^{4 pi k} and the inner sphere's antipodal reflection of those, written out here):
    the traced depth is the first entry of the closed-form geodesic into one of them."""
    sizes = 0.1 * np.linalg.norm(CENTRES, axis=1)
    scene = Scene(
        objects=[
            SceneObject(f"ball{i}", s * MESH.vertices + c, MESH.faces, (0.6, 0.6, 0.6))
            for i, (c, s) in enumerate(zip(CENTRES, sizes))
        ]
    )
    inner_ratio = 1 - 2 * (1 - MESH_INNER)  # the reflected flat triangles dip a little deeper
    centres, outer, inner = rp3_cover_balls(CENTRES, sizes, inner_ratio)
    tracer = render.make_tracer(folded, scene)
    rng = np.random.default_rng(16)
    n, length, step = 100, 8.0, 0.01
    x = shell_points(rng, 8 * n, 0.2, L - 0.2)
    x = x[
        np.min(np.linalg.norm(x[:, None] - CENTRES[None], axis=-1) - sizes, axis=1) > 0.05 * np.linalg.norm(x, axis=1)
    ][:n]
    P = G.to_model(x)
    # a third along the connecting geodesic to a ball's centre, a third to a reflected one's (beyond
    # the inner sphere), turned a little; the rest at random
    targets = np.vstack([CENTRES, [reflected_ball(c, s)[0] for c, s in zip(CENTRES, sizes)]])
    aim = rng.integers(len(CENTRES), size=n) + np.where(np.arange(n) < n // 3, 0, len(CENTRES))
    V = G.connect(P, G.to_model(targets[aim]))[0]
    V = V + 0.05 * np.c_[x * rng.normal(size=(n, 3)), np.zeros(n)]
    V[2 * n // 3 :] = G.tangent_to_model(x[2 * n // 3 :], rng.normal(size=(n - 2 * n // 3, 3)))
    V = G.normalize_tangent(P, V)
    u = G.tangent_to_chart(P, V)
    out = tracer.trace(np.ascontiguousarray(P), np.ascontiguousarray(V), length, 10000, shade=False, tolerance=1e-6)
    t = np.arange(0.0, length + step, step)

    def truth(i):
        path = np.array(G.chart_geodesic(np.broadcast_to(x[i], (len(t), 3)), np.broadcast_to(u[i], (len(t), 3)), t)[0])
        chart = lambda k, s: G.chart_geodesic(x[i], u[i], s)[0]
        return first_hits(t, path, path[1:], chart, centres, outer, inner)

    compared, hits = check_depths(G, folded, out, P, V, length, centres, outer, inner, truth=truth)
    assert compared >= 70 and hits >= 20, (compared, hits)
    beyond = (out["stop"] == 0) & (np.sum(out["position"] ** 2, axis=1) < 1)
    assert beyond.sum() >= 10  # hits in the double cover's other half: on the balls' reflected copies


def reduce_rp3(x):
    """A point of the universal cover into the shell 1 <= |x| <= e^L by the deck group, written
    out: w = log|x| modulo 2 L by the dilations, then the outer reflection where w > L."""
    r = np.linalg.norm(x, axis=-1)
    w = np.log(r) % (2 * L)
    u = x / r[..., None]
    flip = w > L
    w = np.where(flip, 2 * L - w, w)
    return np.where(flip[..., None], -u, u) * np.exp(w)[..., None]


def test_rp3_rp3_long_rays_end_where_the_cover_geodesic_ends(folded):
    """About 100 crossings of the double cover's spheres: the traced end, brought into the file's
    shell, is the cover geodesic's end reduced by the deck group (radial rays: known exactly)."""
    tracer = render.make_tracer(folded, Scene())
    rng = np.random.default_rng(17)
    n = 30
    x = shell_points(rng, n, 0.2, L - 0.2)
    u = rng.normal(size=(n, 3))
    u[:5] = x[:5]
    P = G.to_model(x)
    V = G.normalize_tangent(P, G.tangent_to_model(x, u))
    b = np.sum(G.tangent_to_chart(P, V) * x, axis=1) / np.sum(x * x, axis=1)
    length = 100 * 2 * L / np.abs(b)
    for i in range(n):
        out = tracer.trace(
            np.ascontiguousarray(P[i : i + 1]),
            np.ascontiguousarray(V[i : i + 1]),
            float(length[i]),
            100000,
            shade=False,
            tolerance=1e-6,
        )
        assert out["stop"][0] == 1 and out["crossings"][0] >= 99
        Y, _ = G.geodesic(np.asarray(P[i], np.longdouble), np.asarray(V[i], np.longdouble), np.longdouble(length[i]))
        want = np.asarray(reduce_rp3(np.asarray(G.to_chart(Y), np.longdouble)), float)
        got, _ = folded.unfolded(out["end"])
        assert np.linalg.norm(got[0] - want) < 1e-7 * np.linalg.norm(want), (i, got[0], want)
