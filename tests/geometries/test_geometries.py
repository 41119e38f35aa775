"""Geometry kernels (E3, S3, H3) against independent truth.

Everything the kernels compute is checked here against something written in the test itself: the
chart metrics are the textbook formulas (E3: identity; S3 gnomonic: I/(1+r^2) - x x^T/(1+r^2)^2;
H3 Klein: I/(1-r^2) + x x^T/(1-r^2)^2), their Christoffel symbols are derived here, geodesics are
integrated numerically with a tight DOP853, distances are arclengths by quadrature, and sphere
areas come from integrating the volume density.
"""

import math

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq
from support.truth import AMBIENT, chart_metric

from thurston_addon import geometries

NAMES = ["E3", "S3", "H3"]
ORIGIN = np.array([0.0, 0.0, 0.0, 1.0])
SIGN = {"E3": 0, "S3": 1, "H3": -1}


# --- the chart metrics, written from the textbook formulas ---------------------------------------


def chart_metric_derivative(name, x):
    """dg[l, i, j] = d g_ij / d x_l, analytically, for g = A(s) I + B(s) x x^T with s = |x|^2."""
    x = np.asarray(x, float)
    s = x @ x
    if name == "E3":
        return np.zeros((3, 3, 3))
    k = SIGN[name]
    B = -k / (1 + k * s) ** 2
    dA = -k / (1 + k * s) ** 2
    dB = 2 * k * k / (1 + k * s) ** 3
    eye = np.eye(3)
    return (
        2 * dA * np.einsum("l,ij->lij", x, eye)
        + 2 * dB * np.einsum("l,i,j->lij", x, x, x)
        + B * (np.einsum("il,j->lij", eye, x) + np.einsum("i,jl->lij", x, eye))
    )


def geodesic_rhs(name):
    def rhs(_t, y):
        x, v = y[:3], y[3:]
        g = chart_metric(name, x)
        dg = chart_metric_derivative(name, x)
        # lowered Christoffel symbols contracted with v v: dg[i,l,j] v_i v_j - 1/2 dg[l,i,j] v_i v_j
        gam = np.einsum("ilj,i,j->l", dg, v, v) - 0.5 * np.einsum("lij,i,j->l", dg, v, v)
        return np.concatenate([v, -np.linalg.solve(g, gam)])

    return rhs


def integrate_geodesic(name, x0, u0, ts):
    v0 = u0 / math.sqrt(u0 @ chart_metric(name, x0) @ u0)
    sol = solve_ivp(
        geodesic_rhs(name),
        (0.0, ts[-1]),
        np.concatenate([x0, v0]),
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
        t_eval=ts,
        dense_output=True,
    )
    assert sol.success
    return sol


def model_distance(name, A, B):
    """Closed-form distances between model points (not the kernel's formula)."""
    if name == "E3":
        return float(np.linalg.norm(A[:3] / A[3] - B[:3] / B[3]))
    D = A - B
    if name == "S3":  # chord |A - B| = 2 sin(d / 2)
        return float(2 * np.arcsin(min(1.0, np.linalg.norm(D) / 2)))
    # Minkowski chord <A - B, A - B> = 4 sinh^2(d / 2)
    return float(2 * np.arcsinh(math.sqrt(max(0.0, D[:3] @ D[:3] - D[3] ** 2)) / 2))


def random_chart_points(rng, n, name, radius=None):
    radius = radius if radius is not None else {"E3": 2.0, "S3": 1.5, "H3": 0.9}[name]
    pts = []
    while len(pts) < n:
        p = rng.uniform(-radius, radius, 3)
        if np.linalg.norm(p) < radius:
            pts.append(p)
    return np.array(pts)


def jacobian(f, x, h=1e-6):
    x = np.asarray(x, float)
    cols = []
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        cols.append((np.asarray(f(x + e)) - np.asarray(f(x - e))) / (2 * h))
    return np.stack(cols, axis=-1)


@pytest.fixture(params=NAMES)
def name(request):
    return request.param


@pytest.fixture
def geom(name):
    return geometries.get(name)


@pytest.fixture
def rng(name):
    return np.random.default_rng(1234 + NAMES.index(name))


# --- sanity of the test's own derivative formula ----------------------------------------------------


def test_metric_derivative_helper_matches_finite_differences(name, rng):
    for x in random_chart_points(rng, 5, name, radius=0.8):
        fd = np.stack([(chart_metric(name, x + h) - chart_metric(name, x - h)) / 2e-6 for h in 1e-6 * np.eye(3)])
        np.testing.assert_allclose(chart_metric_derivative(name, x), fd, atol=1e-7)


def test_get_unknown_geometry():
    with pytest.raises(ValueError, match="'SL3'; known: E3, S3, H3, Nil, Sol, H2xR, S2xR, SL2, graph"):
        geometries.get("SL3")


# --- metric -----------------------------------------------------------------------------------------


def test_metric_is_pullback_of_ambient_form(name, geom, rng):
    J = AMBIENT[name]
    for x in random_chart_points(rng, 8, name):
        D = jacobian(geom.to_model, x)  # 4x3
        pulled = D.T @ J @ D
        np.testing.assert_allclose(geom.metric(x), pulled, rtol=1e-7, atol=1e-8)
        np.testing.assert_allclose(geom.metric(x), chart_metric(name, x), rtol=1e-13, atol=1e-14)


def test_metric_broadcasts(name, geom, rng):
    xs = random_chart_points(rng, 6, name).reshape(2, 3, 3)
    G = geom.metric(xs)
    assert G.shape == (2, 3, 3, 3)
    for i in range(2):
        for j in range(3):
            np.testing.assert_allclose(G[i, j], chart_metric(name, xs[i, j]), rtol=1e-13, atol=1e-14)


def test_volume_density_is_sqrt_det_metric(name, geom, rng):
    for x in random_chart_points(rng, 8, name):
        assert geom.volume_density(x) == pytest.approx(math.sqrt(np.linalg.det(chart_metric(name, x))), rel=1e-12)


# --- geodesic flow ----------------------------------------------------------------------------------


def test_chart_geodesic_matches_numerical_integration(name, geom, rng):
    ts = np.array([0.25, 0.6, 1.0] + ([2.0] if name == "E3" else []))
    starts = random_chart_points(rng, 4, name, radius=0.5)
    for x0 in starts:
        u0 = rng.normal(size=3)
        sol = integrate_geodesic(name, x0, u0, ts)
        for k, t in enumerate(ts):
            x_num, v_num = sol.y[:3, k], sol.y[3:, k]
            x_cf, v_cf = geom.chart_geodesic(x0, u0, t)
            np.testing.assert_allclose(x_cf, x_num, atol=1e-9)
            np.testing.assert_allclose(v_cf, v_num, atol=1e-9)
            # unit speed (arclength parametrisation), along the numerical and the closed-form solution
            assert v_num @ chart_metric(name, x_num) @ v_num == pytest.approx(1.0, abs=1e-10)
            assert v_cf @ chart_metric(name, x_cf) @ v_cf == pytest.approx(1.0, abs=1e-10)
        # speed at intermediate times of the numerical solution
        for t in np.linspace(0.05, ts[-1], 7):
            y = sol.sol(t)
            assert y[3:] @ chart_metric(name, y[:3]) @ y[3:] == pytest.approx(1.0, abs=1e-9)


def test_chart_geodesic_broadcasts_over_times(name, geom):
    x0 = np.array([0.1, -0.2, 0.3])
    u0 = np.array([0.3, 0.5, -0.2])
    ts = np.array([0.1, 0.4, 0.8])
    xs, vs = geom.chart_geodesic(x0, u0, ts)
    assert xs.shape == (3, 3) and vs.shape == (3, 3)
    for k, t in enumerate(ts):
        x1, v1 = geom.chart_geodesic(x0, u0, t)
        np.testing.assert_allclose(xs[k], x1, atol=1e-14)
        np.testing.assert_allclose(vs[k], v1, atol=1e-14)


def test_geodesic_model_closed_form_stays_on_model(name, geom, rng):
    J = AMBIENT[name]
    for x in random_chart_points(rng, 4, name, radius=0.5):
        X = geom.to_model(x)
        V = geom.normalize_tangent(X, geom.tangent_to_model(x, rng.normal(size=3)))
        for t in (0.3, 1.1, 2.5):
            Xt, Vt = geom.geodesic(X, V, t)
            if name != "E3":
                assert Xt @ J @ Xt == pytest.approx(SIGN[name], abs=1e-12)
                assert Xt @ J @ Vt == pytest.approx(0.0, abs=1e-12)
            assert Vt @ J @ Vt == pytest.approx(1.0, abs=1e-12)
            assert model_distance(name, X, Xt) == pytest.approx(t, abs=1e-7)


# --- distance ---------------------------------------------------------------------------------------


def chord_arclength(name, a, b):
    """Length of the straight chart segment a -> b (a geodesic in these projective charts)."""
    d = b - a
    val, err = quad(
        lambda s: math.sqrt(d @ chart_metric(name, a + s * d) @ d), 0.0, 1.0, epsabs=0.0, epsrel=1e-13, limit=200
    )
    return val


def test_distance_equals_arclength_of_numerical_geodesic(name, geom, rng):
    for x0 in random_chart_points(rng, 3, name, radius=0.5):
        u0 = rng.normal(size=3)
        ts = np.array([0.2, 0.9])
        sol = integrate_geodesic(name, x0, u0, ts)
        for k, t in enumerate(ts):
            d = geom.distance(geom.to_model(x0), geom.to_model(sol.y[:3, k]))
            assert d == pytest.approx(t, abs=1e-9)


def test_distance_equals_chord_arclength(name, geom, rng):
    pts = random_chart_points(rng, 10, name, radius={"E3": 2.0, "S3": 1.5, "H3": 0.95}[name])
    for a, b in zip(pts[:5], pts[5:]):
        d = geom.distance(geom.to_model(a), geom.to_model(b))
        assert d == pytest.approx(chord_arclength(name, a, b), rel=1e-10, abs=1e-12)


@pytest.mark.parametrize("eps", [1e-9, 1e-12])
def test_tiny_distances_are_accurate(name, geom, rng, eps):
    for x in random_chart_points(rng, 4, name, radius=0.8):
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        expected = eps * math.sqrt(u @ chart_metric(name, x) @ u)
        d = geom.distance(geom.to_model(x), geom.to_model(x + eps * u))
        assert d == pytest.approx(expected, rel=1e-5)


def test_s3_distance_near_pi():
    geom = geometries.get("S3")
    rng = np.random.default_rng(7)
    for _ in range(5):
        A = rng.normal(size=4)
        A /= np.linalg.norm(A)
        V = rng.normal(size=4)
        V -= (V @ A) * A
        V /= np.linalg.norm(V)
        for delta in (1e-3, 1e-6, 1e-8):
            t = math.pi - delta
            B = math.cos(t) * A + math.sin(t) * V
            assert geom.distance(A, B) == pytest.approx(t, abs=1e-12)
        assert geom.distance(A, -A) == pytest.approx(math.pi, abs=1e-15)


def test_h3_large_distances():
    geom = geometries.get("H3")
    for t in (5.0, 10.0, 15.0):
        B = np.array([math.sinh(t), 0, 0, math.cosh(t)])
        assert geom.distance(ORIGIN, B) == pytest.approx(t, rel=1e-9)


def test_distance_is_zero_on_the_diagonal(name, geom, rng):
    for x in random_chart_points(rng, 4, name):
        X = geom.to_model(x)
        assert abs(geom.distance(X, X)) < 1e-7


# --- isometries -------------------------------------------------------------------------------------


def ambient_isometry_check(name, M, tol=1e-12):
    M = np.asarray(M)
    if name == "E3":
        R = M[:3, :3]
        return np.allclose(M[3], [0, 0, 0, 1], atol=tol) and np.allclose(R.T @ R, np.eye(3), atol=tol)
    J = AMBIENT[name]
    return np.allclose(M.T @ J @ M, J, atol=tol * max(1.0, np.abs(M).max() ** 2)) and M[3, 3] > 0


def some_isometries(geom, rng, n=4, max_shift=0.8):
    out = []
    for _ in range(n):
        T = geom.translation(rng.normal(size=3), rng.uniform(0.1, max_shift))
        R = geom.rotation(rng.normal(size=3), rng.uniform(-math.pi, math.pi))
        out += [T, R, T @ R]
    return out


def test_translation_and_rotation_are_isometries(name, geom, rng):
    for M in some_isometries(geom, rng):
        assert geom.is_isometry(M)
        assert ambient_isometry_check(name, M)


def test_isometries_preserve_the_chart_metric(name, geom, rng):
    for M in some_isometries(geom, rng, n=2, max_shift=0.7):
        for x in random_chart_points(rng, 3, name, radius=0.3):
            y = geom.transform_points(M, x)
            D = jacobian(lambda p: geom.transform_points(M, p), x)
            np.testing.assert_allclose(D.T @ chart_metric(name, y) @ D, chart_metric(name, x), rtol=1e-7, atol=1e-8)


@pytest.mark.parametrize("d", [1e-6, 0.3, 1.0, 1.4])
def test_translation_moves_origin_by_exactly_d(name, geom, rng, d):
    n = rng.normal(size=3)
    n /= np.linalg.norm(n)
    M = geom.translation(n, d)
    image = M @ ORIGIN
    assert model_distance(name, ORIGIN, image) == pytest.approx(d, rel=1e-9)
    # along the chart ray of n, at chart radius d, tan d, tanh d
    rho = {"E3": d, "S3": math.tan(d), "H3": math.tanh(d)}[name]
    np.testing.assert_allclose(image[:3] / image[3], rho * n, rtol=1e-12, atol=1e-15)


def test_translations_form_a_one_parameter_group(name, geom):
    n = np.array([0.3, -0.4, 1.2])
    np.testing.assert_allclose(
        geom.translation(n, 0.3) @ geom.translation(n, 0.5), geom.translation(n, 0.8), atol=1e-13
    )
    np.testing.assert_allclose(geom.translation(n, 0.7) @ geom.translation(n, -0.7), np.eye(4), atol=1e-13)


def test_rotation_is_right_handed_about_the_axis(name, geom):
    M = geom.rotation([0, 0, 2.0], math.pi / 2)
    np.testing.assert_allclose(geom.transform_points(M, [0.3, 0, 0]), [0, 0.3, 0], atol=1e-15)
    np.testing.assert_allclose(geom.transform_points(M, [0, 0, 0.4]), [0, 0, 0.4], atol=1e-15)
    a = np.array([1.0, 2.0, -0.5])
    p = 0.2 * a / np.linalg.norm(a)
    np.testing.assert_allclose(geom.transform_points(geom.rotation(a, 1.234), p), p, atol=1e-15)


def test_reorthonormalize_repairs_a_perturbed_isometry(name, geom, rng):
    for M0 in some_isometries(geom, rng, n=3):
        np.testing.assert_allclose(geom.reorthonormalize(M0), M0, atol=1e-12)
        M = M0 + 1e-7 * rng.normal(size=(4, 4))
        if name == "E3":
            M[3] = [0, 0, 0, 1]
        R = geom.reorthonormalize(M)
        assert ambient_isometry_check(name, R, tol=1e-12)
        assert geom.is_isometry(R, tol=1e-12)
        assert np.abs(R - M0).max() < 1e-5


# Group elements that the spaces use move the origin by at most ~6 (Seifert-Weber's neighbourhood);
# at d = 10 the rotation part of a Lorentz matrix with entries ~e^10 is itself known only to ~1e-8.
@pytest.mark.parametrize("d", [0.5, 3.0, 6.0])
def test_h3_reorthonormalize_keeps_large_isometries_accurate(d):
    """An exact isometry must come back (numerically) unchanged: applied to a point at distance d
    it should bring it back as accurately as the matrix itself does."""
    geom = geometries.get("H3")
    n = np.array([0.3, 0.5, 0.8])
    x = np.array([0.1, 0.2, 0.3])
    T = geom.translation(n, d) @ geom.rotation([1.0, 2.0, 3.0], 0.7)
    P = np.linalg.solve(T, geom.to_model(x))  # the point T maps onto x, at distance ~d
    err_T = np.abs(geom.to_chart(T @ P) - x).max()  # rounding of T itself
    R = geom.reorthonormalize(T)
    assert np.abs(geom.to_chart(R @ P) - x).max() < max(1e-9, 100 * err_T)


@pytest.mark.parametrize("mirrored", [False, True])
def test_h3_reorthonormalize_keeps_far_isometries_to_their_rounding(mirrored, rng):
    """Far isometries (entries up to 10^6, as the walks through a genus-3 surface's cover reach
    them in H2xR's disk) come back from a perturbation of 1e-15 of each entry to within 1e-12 of
    their size, orientation-reversing ones too: a repair that computes the rotation part from the
    matrix (T^-1 M, Gram-Schmidt) errs by eps |M|^2, 10^-4 here. The isometries are built in
    closed form: a translation by d after a rotation (and a mirror)."""
    geom = geometries.get("H3")
    for d in (3.0, 8.0, 14.0):
        T = geom.translation([0.3, -0.5, 0.8], d) @ geom.rotation([1.0, 2.0, 3.0], 0.7)
        if mirrored:
            T = T @ np.diag([1.0, -1.0, 1.0, 1.0])
        R = geom.reorthonormalize(T * (1 + 1e-15 * rng.normal(size=(4, 4))))
        assert np.abs(R - T).max() <= 1e-12 * np.abs(T).max()
        assert geom.is_isometry(R, tol=1e-12)


def test_is_isometry_rejects_non_isometries(name, geom):
    M = np.eye(4)
    M[0, 0] = 1.01
    assert not geom.is_isometry(M)
    if name == "H3":
        assert not geom.is_isometry(-np.eye(4))  # swaps the sheets of the hyperboloid
    if name == "E3":
        M = np.eye(4)
        M[3, 0] = 0.5
        assert not geom.is_isometry(M)


def test_s3_is_isometry_accepts_every_orthogonal_matrix():
    geom = geometries.get("S3")
    M = geom.translation([1.0, 0, 0], 2.0)
    assert np.allclose(M.T @ M, np.eye(4))
    assert geom.is_isometry(M)
    assert geom.is_isometry(-np.eye(4))  # the antipodal map, an element of the Poincare group


def test_bisector_is_the_equidistant_plane(name, geom, rng):
    for q in random_chart_points(rng, 4, name, radius={"E3": 2.0, "S3": 1.0, "H3": 0.7}[name]):
        Q = geom.to_model(q)
        c = geom.bisector(Q)
        assert c @ ORIGIN < 0 < c @ Q
        n, c3 = c[:3], c[3]
        checked = 0
        for p in random_chart_points(rng, 30, name, radius={"E3": 3.0, "S3": 1.5, "H3": 0.95}[name]):
            x = p - (n @ p + c3) * n / (n @ n)  # projection onto the chart plane n.x + c3 = 0
            if name == "H3" and x @ x >= 0.97:
                continue
            X = geom.to_model(x)
            assert abs(c @ X) < 1e-12 * np.abs(c).max()
            assert model_distance(name, ORIGIN, X) == pytest.approx(model_distance(name, Q, X), abs=1e-9)
            checked += 1
        assert checked >= 10


# --- charts and tangent vectors --------------------------------------------------------------------


def test_chart_model_round_trip(name, geom, rng):
    J = AMBIENT[name]
    xs = random_chart_points(rng, 10, name)
    X = geom.to_model(xs)
    np.testing.assert_allclose(geom.to_chart(X), xs, atol=1e-14)
    if name == "E3":
        np.testing.assert_allclose(X[:, 3], 1.0)
    else:
        np.testing.assert_allclose(np.einsum("ni,ij,nj->n", X, J, X), SIGN[name], atol=1e-13)
        assert np.all(X[:, 3] > 0)
    assert np.all(geom.in_chart(xs))


def test_in_chart(name, geom):
    assert not geom.in_chart([np.nan, 0, 0])
    assert not geom.in_chart([np.inf, 0, 0])
    assert geom.in_chart([0.99, 0, 0])
    assert bool(geom.in_chart([1.0, 0.2, 0])) == (name != "H3")


def test_tangent_maps_are_differentials_and_mutually_inverse(name, geom, rng):
    J = AMBIENT[name]
    for x in random_chart_points(rng, 6, name, radius=0.8):
        u = rng.normal(size=3)
        X = geom.to_model(x)
        V = geom.tangent_to_model(x, u)
        h = 1e-6
        fd = (geom.to_model(x + h * u) - geom.to_model(x - h * u)) / (2 * h)
        np.testing.assert_allclose(V, fd, rtol=1e-7, atol=1e-8)
        np.testing.assert_allclose(geom.tangent_to_chart(X, V), u, rtol=1e-12, atol=1e-13)
        if name != "E3":
            assert X @ J @ V == pytest.approx(0.0, abs=1e-13)
        # metric length of u equals the ambient length of its image
        assert V @ J @ V == pytest.approx(u @ chart_metric(name, x) @ u, rel=1e-12)
        # tangent_to_chart of the model differential of a chart curve is the chart velocity
        W = rng.normal(size=4)
        Wt = W - (SIGN[name] * (X @ J @ W)) * X if name != "E3" else np.append(W[:3], 0.0)
        np.testing.assert_allclose(geom.tangent_to_model(x, geom.tangent_to_chart(X, Wt)), Wt, rtol=1e-11, atol=1e-12)


def test_normalize_tangent_gives_unit_metric_length(name, geom, rng):
    J = AMBIENT[name]
    for x in random_chart_points(rng, 6, name):
        X = geom.to_model(x)
        W = rng.normal(size=4)
        V = geom.normalize_tangent(X, W)
        assert V @ J @ V == pytest.approx(1.0, abs=1e-13)
        if name != "E3":
            assert X @ J @ V == pytest.approx(0.0, abs=1e-13)
        u = geom.tangent_to_chart(X, V)
        assert u @ chart_metric(name, x) @ u == pytest.approx(1.0, rel=1e-11)


# --- point-light falloff ---------------------------------------------------------------------------


def sphere_area_from_density(name, geom, r):
    """Area of the geodesic sphere of radius r about the origin, as d/dr of the volume of the ball,
    with the volume integrated from the chart's volume density and the chart radius of the sphere
    found from the radial arclength of the test's metric."""
    e = np.array([1.0, 0.0, 0.0])
    radial_speed = lambda s: math.sqrt(chart_metric(name, s * e)[0, 0])
    geodesic_radius = lambda rho: quad(radial_speed, 0.0, rho, epsabs=0.0, epsrel=1e-13, limit=200)[0]
    top = {"E3": 50.0, "S3": 1e3, "H3": 0.9999}[name]

    def ball_volume(R):
        rho = brentq(lambda p: geodesic_radius(p) - R, 0.0, top, xtol=1e-15, rtol=1e-15)
        return quad(
            lambda s: 4 * math.pi * s * s * float(geom.volume_density(s * e)),
            0.0,
            rho,
            epsabs=0.0,
            epsrel=1e-13,
            limit=200,
        )[0]

    h = 1e-4 * r
    return (ball_volume(r + h) - ball_volume(r - h)) / (2 * h)


@pytest.mark.parametrize("r", [0.1, 0.5, 1.0, 1.4])
def test_falloff_is_inverse_geodesic_sphere_area(name, geom, r):
    area = sphere_area_from_density(name, geom, r)
    assert float(geom.falloff(r)) == pytest.approx(4 * math.pi / area, rel=1e-6)


def test_falloff_h3_far():
    name, geom = "H3", geometries.get("H3")
    area = sphere_area_from_density(name, geom, 2.5)
    assert float(geom.falloff(2.5)) == pytest.approx(4 * math.pi / area, rel=1e-6)


# --- dihedral angles --------------------------------------------------------------------------------


def chart_dihedral(name, c1, c2, p):
    """Interior angle at chart point p (on both planes) between the half-spaces c.(x,1) <= 0:
    pi minus the angle between the outward metric normals g^-1 grad(c.(x,1))."""
    g = chart_metric(name, p)
    gi = np.linalg.inv(g)
    a1, a2 = c1[:3], c2[:3]
    cos = (a1 @ gi @ a2) / math.sqrt((a1 @ gi @ a1) * (a2 @ gi @ a2))
    return math.pi - math.acos(max(-1.0, min(1.0, cos)))


def test_dihedral_angle_matches_direct_computation(name, geom, rng):
    for _ in range(8):
        cs = []
        for _ in range(2):
            n = rng.normal(size=3)
            n /= np.linalg.norm(n)
            cs.append(np.append(n, rng.uniform(-0.3, 0.3)) * rng.uniform(0.5, 2.0))
        c1, c2 = cs
        A = np.array([c1[:3], c2[:3]])
        p0 = np.linalg.lstsq(A, -np.array([c1[3], c2[3]]), rcond=None)[0]  # least-norm point on the line
        d = np.cross(c1[:3], c2[:3])
        d /= np.linalg.norm(d)
        expected = [chart_dihedral(name, c1, c2, p0 + s * d) for s in (0.0, 0.2)]
        # totally geodesic planes: the angle is the same all along the common line
        assert expected[0] == pytest.approx(expected[1], abs=1e-12)
        assert float(geom.dihedral_angle(c1, c2)) == pytest.approx(expected[0], abs=1e-12)


def test_dihedral_angle_of_cube_faces(name, geom):
    # the coordinate planes x = 0, y = 0 meet at right angles in every geometry
    assert float(geom.dihedral_angle(np.array([1.0, 0, 0, 0]), np.array([0, 1.0, 0, 0]))) == pytest.approx(math.pi / 2)
    # half-spaces x <= 0 and -x - y <= 0: interior angle 3 pi / 4 at the origin
    c2 = np.array([-1.0, -1.0, 0, 0])
    assert float(geom.dihedral_angle(np.array([1.0, 0, 0, 0]), c2)) == pytest.approx(math.pi / 4)


def test_plane_distance(name, geom, rng):
    for _ in range(5):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        h = rng.uniform(0.05, 0.9)
        c = np.append(n, -h) * 3.0
        # foot of the perpendicular from the origin is the chart point h n
        assert float(geom.plane_distance(c)) == pytest.approx(
            model_distance(name, ORIGIN, geom.to_model(h * n)), rel=1e-12
        )
