"""Nil and Sol against independent truth.

The metrics and their derivatives are the formulas in support/truth.py (Nil dx^2 + dy^2 +
(dz - x dy)^2, Sol e^{2z} dx^2 + e^{-2z} dy^2 + dz^2); the derivatives are checked here against
finite differences,
the Christoffel symbols and the geodesic equation are built from them, geodesics are integrated
with DOP853 at 1e-12, Nil's closed form is also evaluated in the paper's plain form in decimals
with enough digits to absorb its cancellation, and geodesic-sphere areas come from fans of
integrated geodesics.
"""

import math
from decimal import Decimal, getcontext, localcontext

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from support.truth import CURVED_METRICS, nil_sol_christoffel, nil_sol_metric_derivative

from thurston_addon.geometries import nil as nil_module
from thurston_addon.geometries import sol as sol_module
from thurston_addon.geometries.nil import Nil
from thurston_addon.geometries.sol import Sol

NAMES = ["Nil", "Sol"]
GEOMETRY = {"Nil": Nil(), "Sol": Sol()}


# --- the geodesic equation (the metrics' derivatives and Christoffel symbols: support/truth.py) ---


def integrate_geodesic(name, x0, v0, ts, scale=None):
    """DOP853 of x'' = -Gamma(x)(x', x') at rtol = atol = 1e-12 (atol times `scale` per
    coordinate, for starts where the coordinates have very different sizes)."""
    scale = np.ones(3) if scale is None else np.asarray(scale)

    def rhs(_t, y):
        return np.concatenate([y[3:], -np.einsum("kij,i,j->k", nil_sol_christoffel(name, y[:3]), y[3:], y[3:])])

    ts = np.atleast_1d(ts)
    sol = solve_ivp(
        rhs,
        (0.0, ts[-1]),
        np.concatenate([x0, v0]),
        method="DOP853",
        rtol=1e-12,
        atol=1e-12 * np.concatenate([scale, scale]),
        t_eval=ts,
    )
    assert sol.success
    return sol.y[:3].T, sol.y[3:].T


def unit_chart_vector(name, x, u):
    u = np.asarray(u, float)
    return u / math.sqrt(u @ CURVED_METRICS[name](x) @ u)


def speed2(name, x, v):
    return v @ CURVED_METRICS[name](x) @ v


def model(x, last=1.0):
    return np.append(np.asarray(x, float), last)


def fd_jacobian(f, x, h=1e-6):
    return np.stack([(np.asarray(f(x + e)) - np.asarray(f(x - e))) / (2 * h) for e in h * np.eye(3)], axis=-1)


@pytest.fixture(params=NAMES)
def name(request):
    return request.param


@pytest.fixture
def geom(name):
    return GEOMETRY[name]


@pytest.fixture
def rng(name):
    return np.random.default_rng(4321 + NAMES.index(name))


def random_points(rng, n, radius=1.5):
    return rng.uniform(-radius, radius, (n, 3))


# --- attributes, metric, Christoffel symbols -------------------------------------------------------


def test_attributes(name, geom):
    assert geom.name == name and geom.kernel == name and geom.projective is False


def test_metric_derivative_helper_matches_finite_differences(name, rng):
    for x in random_points(rng, 5):
        fd = np.stack([(CURVED_METRICS[name](x + h) - CURVED_METRICS[name](x - h)) / 2e-6 for h in 1e-6 * np.eye(3)])
        np.testing.assert_allclose(nil_sol_metric_derivative(name, x), fd, rtol=1e-8, atol=1e-8)


def test_metric_matches_the_formula_and_broadcasts(name, geom, rng):
    xs = random_points(rng, 8).reshape(2, 4, 3)
    G = geom.metric(xs)
    assert G.shape == (2, 4, 3, 3)
    for index in np.ndindex(2, 4):
        np.testing.assert_allclose(G[index], CURVED_METRICS[name](xs[index]), rtol=1e-14, atol=1e-15)


def test_christoffel_symbols_from_the_metric(name, geom, rng):
    xs = random_points(rng, 6).reshape(3, 2, 3)
    G = geom.christoffel(xs)
    assert G.shape == (3, 2, 3, 3, 3)
    for index in np.ndindex(3, 2):
        np.testing.assert_allclose(G[index], nil_sol_christoffel(name, xs[index]), rtol=1e-12, atol=1e-13)


def test_volume_density_is_sqrt_det_metric(name, geom, rng):
    for x in random_points(rng, 6):
        assert float(geom.volume_density(x)) == pytest.approx(
            math.sqrt(np.linalg.det(CURVED_METRICS[name](x))), rel=1e-12
        )


def test_dot_is_the_metric(name, geom, rng):
    for x in random_points(rng, 4):
        a, b = rng.normal(size=(2, 3))
        assert float(geom.dot(model(x), model(a, 0.0), model(b, 0.0))) == pytest.approx(
            a @ CURVED_METRICS[name](x) @ b, rel=1e-13
        )


# --- geodesics against DOP853 ----------------------------------------------------------------------


def check_geodesic_against_integration(name, geom, x0, v0, ts, tol=1e-9, scale=None):
    """Geodesic from chart point x0 with unit chart velocity v0 against DOP853, all times at once;
    errors relative to max(1, |coordinate|) (per coordinate `scale` for far starts)."""
    scale = np.ones(3) if scale is None else np.asarray(scale)
    xs, vs = integrate_geodesic(name, x0, v0, ts, scale)
    X, W = geom.geodesic(model(x0), model(v0, 0.0), np.asarray(ts))
    assert np.all(np.isfinite(X)) and np.all(np.isfinite(W))
    np.testing.assert_allclose(X[:, 3], 1.0)
    np.testing.assert_allclose(W[:, 3], 0.0)
    bound = tol * np.maximum(scale, np.abs(xs))
    assert np.all(np.abs(X[:, :3] - xs) <= bound), np.abs(X[:, :3] - xs) / np.maximum(scale, np.abs(xs))
    assert np.all(np.abs(W[:, :3] - vs) <= tol * np.maximum(scale, np.abs(vs)))
    for x, v in zip(X[:, :3], W[:, :3]):
        assert speed2(name, x, v) == pytest.approx(1.0, abs=1e-12)
    return X[:, :3], W[:, :3]


def test_geodesic_matches_numerical_integration(name, geom, rng):
    ts = [0.5, 2.0, 5.0, 10.0] + ([17.0, 25.0] if name == "Nil" else [])
    for x0 in random_points(rng, 5):
        v0 = unit_chart_vector(name, x0, rng.normal(size=3))
        check_geodesic_against_integration(name, geom, x0, v0, ts)


def test_negative_times_run_the_geodesic_backwards(name, geom, rng):
    x0 = random_points(rng, 1)[0]
    V = geom.normalize_tangent(model(x0), model(rng.normal(size=3), 0.0))
    X, W = geom.geodesic(model(x0), V, -3.0)
    Y, U = geom.geodesic(model(x0), -V, 3.0)
    np.testing.assert_allclose(X, Y, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(W, -U, rtol=1e-12, atol=1e-12)


def test_geodesic_broadcasts(name, geom, rng):
    P = geom.to_model(random_points(rng, 2)).reshape(2, 1, 4)
    V = geom.normalize_tangent(P, rng.normal(size=(1, 3, 4)))
    ts = np.array([0.3, 1.0, 4.0])
    X, W = geom.geodesic(P, V, ts)
    assert X.shape == W.shape == (2, 3, 4)
    for i, j in np.ndindex(2, 3):
        Xij, Wij = geom.geodesic(P[i, 0], V[i, j], ts[j])
        np.testing.assert_allclose(X[i, j], Xij, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(W[i, j], Wij, rtol=1e-14, atol=1e-14)


def test_chart_geodesic_normalises_the_direction(name, geom, rng):
    x0 = random_points(rng, 1)[0]
    u = rng.normal(size=3)
    x, v = geom.chart_geodesic(x0, 3.0 * u, np.array([0.0, 2.0]))
    np.testing.assert_allclose(x[0], x0, atol=1e-15)
    np.testing.assert_allclose(v[0], unit_chart_vector(name, x0, u), rtol=1e-14)
    X, W = geom.geodesic(model(x0), model(unit_chart_vector(name, x0, u), 0.0), 2.0)
    np.testing.assert_allclose(x[1], X[:3], rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(v[1], W[:3], rtol=1e-12, atol=1e-13)


def test_nil_vertical_component_is_conserved():
    geom = GEOMETRY["Nil"]
    rng = np.random.default_rng(5)
    for x0 in random_points(rng, 4):
        v0 = unit_chart_vector("Nil", x0, rng.normal(size=3))
        X, W = geom.geodesic(model(x0), model(v0, 0.0), np.linspace(0.0, 25.0, 11))
        # g(d/dz, velocity) = z' - x y' (d/dz is a Killing field)
        np.testing.assert_allclose(W[:, 2] - X[:, 0] * W[:, 1], v0[2] - x0[0] * v0[1], atol=1e-13)


def test_sol_first_integrals_are_conserved():
    geom = GEOMETRY["Sol"]
    rng = np.random.default_rng(6)
    for x0 in random_points(rng, 4):
        v0 = unit_chart_vector("Sol", x0, rng.normal(size=3))
        X, W = geom.geodesic(model(x0), model(v0, 0.0), np.linspace(0.0, 10.0, 11))
        z = X[:, 2]
        np.testing.assert_allclose(np.exp(2 * z) * W[:, 0], math.exp(2 * x0[2]) * v0[0], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(np.exp(-2 * z) * W[:, 1], math.exp(-2 * x0[2]) * v0[1], rtol=1e-13, atol=1e-15)


# --- Nil: the closed form for every vertical component ---------------------------------------------


def paper_closed_form(v, t):
    """The paper's Nil geodesic from the origin, velocity (c cos a, c sin a, w), in decimals with
    enough digits to absorb its 1/w^2 cancellation; w = 0 is the limit x + iy = c t e^{ia},
    z = c^2 t^2 sin(2a) / 4."""
    with localcontext() as ctx:
        ctx.prec = 40 + (int(-2 * math.log10(abs(v[2]))) if v[2] else 0)
        vx, vy, w, t = (Decimal(float(a)) for a in (*v, t))
        c = (vx * vx + vy * vy).sqrt()
        ca, sa = (vx / c, vy / c) if c else (Decimal(1), Decimal(0))  # c = 0: the angle is immaterial
        if w == 0:
            x, y = c * t * ca, c * t * sa
            z = c * c * t * t * 2 * sa * ca / 4
            ux, uy = vx, vy
        else:
            theta = w * t
            ct, st = decimal_cos(theta), decimal_sin(theta)
            c2t, s2t = ct * ct - st * st, 2 * st * ct
            s2a, c2a = 2 * sa * ca, ca * ca - sa * sa
            sin_ta, cos_ta = st * ca + ct * sa, ct * ca - st * sa
            x = c / w * (sin_ta - sa)
            y = -c / w * (cos_ta - ca)
            z = (
                t * (w + c * c / (2 * w))
                - c * c / (4 * w * w) * (s2t * c2a + c2t * s2a - s2a)
                + c * c / (2 * w * w) * (st * c2a + ct * s2a - s2a - st)
            )
            ux, uy = c * cos_ta, c * sin_ta
        return np.array([float(x), float(y), float(z)]), np.array([float(ux), float(uy), float(w + x * uy)])


def decimal_sin(x):
    return decimal_series(x, 1)


def decimal_cos(x):
    return decimal_series(x, 0)


def decimal_series(x, first):
    """sum_n (-1)^n x^(2n + first) / (2n + first)! at the context precision."""
    term = x if first else Decimal(1)
    total, n = term, first
    while abs(term) > Decimal(10) ** (-2 * getcontext().prec):
        term = -term * x * x / ((n + 1) * (n + 2))
        total += term
        n += 2
    return total


@pytest.mark.parametrize("w", [0.0, 1e-300, 1e-12, 1e-6, 1e-2, 0.5, 1.0])
def test_nil_closed_form_for_every_vertical_component(w):
    geom = GEOMETRY["Nil"]
    ts = np.array([1.0, 10.0, 25.0])
    for angle in (0.3, 2.0, -2.5):
        c = math.sqrt(1.0 - w * w)
        v = np.array([c * math.cos(angle), c * math.sin(angle), w])
        X, W = geom.geodesic(model([0, 0, 0]), model(v, 0.0), ts)
        for k, t in enumerate(ts):
            x_ref, v_ref = paper_closed_form(v, t)
            np.testing.assert_allclose(X[k, :3], x_ref, rtol=0, atol=1e-15 * max(1.0, np.abs(x_ref).max()))
            np.testing.assert_allclose(W[k, :3], v_ref, rtol=0, atol=1e-15 * max(1.0, np.abs(v_ref).max()))
        # the same geodesic from another point, against DOP853
        x0 = np.array([0.4, -0.3, 0.2])
        v0 = np.array([v[0], v[1], v[2] + x0[0] * v[1]])  # the differential of left multiplication by x0
        check_geodesic_against_integration("Nil", geom, x0, v0, ts)


def test_nil_series_and_direct_form_meet_continuously():
    F = nil_module.theta_minus_sin_over_square
    below = np.nextafter(nil_module.SERIES_BELOW, 0.0)
    above = nil_module.SERIES_BELOW
    for theta in (below, above, -below, -above):
        exact = paper_f(theta)
        assert float(F(np.array(theta))) == pytest.approx(exact, rel=1e-15)


def paper_f(theta):
    """(theta - sin theta) / theta^2 in 40-digit decimals."""
    with localcontext() as ctx:
        ctx.prec = 40
        th = Decimal(theta)
        return float((th - decimal_sin(th)) / (th * th))


# --- Sol: axes, near-degenerate directions, far starts, the elliptic form ---------------------------

SOL_DIRECTIONS = [
    [1, 0, 0],
    [-1, 0, 0],
    [0, 1, 0],
    [0, -1, 0],
    [0, 0, 1],
    [0, 0, -1],
    [0, 0.6, 0.8],
    [0.6, 0, -0.8],
    [1e-9, 0.6, 0.8],
    [0.6, -1e-9, 0.8],
    [1e-12, 1, 0],
    [1, 1, 0],
    [1, -1, 1e-7],
]


@pytest.mark.parametrize("z0", [0.0, 20.0, -20.0])
def test_sol_axes_planes_and_far_starts(z0):
    geom = GEOMETRY["Sol"]
    x0 = np.array([0.3, -0.7, z0])
    # coordinate sizes near the start: unit displacements in the metric move x by e^{-z}, y by e^{z}
    scale = np.array([math.exp(-z0), math.exp(z0), 1.0])
    for direction in SOL_DIRECTIONS:
        v0 = unit_chart_vector("Sol", x0, scale * np.asarray(direction, float))
        check_geodesic_against_integration("Sol", geom, x0, v0, [1.0, 4.0, 8.0], scale=scale)


def sol_direction_with_product(rng, q):
    """A unit direction at the origin with p_x p_y = q: (p_x +- p_y)^2 = r2 +- 2q for a random
    p_x^2 + p_y^2 = r2 >= 2 |q|, random signs."""
    r2 = rng.uniform(2 * abs(q), 1.0)
    total, difference = (rng.choice([-1, 1]) * math.sqrt(r2 + sign * 2 * q) for sign in (1, -1))
    return np.array([(total + difference) / 2, (total - difference) / 2, rng.choice([-1, 1]) * math.sqrt(1 - r2)])


def test_sol_elliptic_form_matches_integration_away_from_the_guards():
    geom = GEOMETRY["Sol"]
    rng = np.random.default_rng(8)
    ts = [0.7, 3.0, 6.0, 10.0]
    starts = random_points(rng, 6)
    directions = [sol_direction_with_product(rng, q) for q in (0.01, -0.05, 0.2, -0.3, 0.45, -0.499)]
    for x0, p in zip(starts, directions):
        v0 = np.array([math.exp(-x0[2]) * p[0], math.exp(x0[2]) * p[1], p[2]])  # frame at x0
        xs, vs = integrate_geodesic("Sol", x0, v0, ts)
        X, W = geom.geodesic_elliptic(model(x0), model(v0, 0.0), np.array(ts))
        Xi, Wi = geom.geodesic(model(x0), model(v0, 0.0), np.array(ts))
        np.testing.assert_allclose(X[:, :3], xs, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(W[:, :3], vs, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(X, Xi, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(W, Wi, rtol=1e-10, atol=1e-10)


def test_sol_elliptic_form_falls_back_at_the_guards():
    geom = GEOMETRY["Sol"]
    h = 1 / math.sqrt(2)
    near_guards = np.array(
        [
            [1, 0, 0],
            [0, 1, 0],
            [0, 0, 1],
            [0.6, 0, 0.8],
            [1e-5, 0.6, 0.8],
            [h, h, 0],
            [h, -h, 0],
            [h, h * (1 - 1e-10), 1e-5],
        ]
    )
    ts = np.array([2.0, 7.0])
    for p in near_guards:
        v0 = p / np.linalg.norm(p)
        q = abs(v0[0] * v0[1])
        assert (
            q < sol_module.ELLIPTIC_MIN_PRODUCT
            or math.sqrt(max(0.0, 1 - 4 * q * q)) < sol_module.ELLIPTIC_MIN_MODULUS_GAP
        )
        X, W = geom.geodesic_elliptic(model([0, 0, 0]), model(v0, 0.0), ts)
        Xi, Wi = geom.geodesic(model([0, 0, 0]), model(v0, 0.0), ts)
        np.testing.assert_allclose(X, Xi, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(W, Wi, rtol=1e-14, atol=1e-15)
        xs, _ = integrate_geodesic("Sol", np.zeros(3), v0, ts)
        np.testing.assert_allclose(X[:, :3], xs, rtol=1e-9, atol=1e-9)


# --- isometries ------------------------------------------------------------------------------------


def nil_product(p, q):
    return np.array([p[0] + q[0], p[1] + q[1], p[2] + q[2] + p[0] * q[1]])


def some_isometries(name, geom, rng):
    if name == "Nil":
        return [geom.left_multiplication(p) for p in random_points(rng, 4, radius=3.0)]
    out = [geom.swap(), geom.flip(-1, 1), geom.flip(1, -1), geom.flip(-1, -1)]
    for a, b, c in random_points(rng, 3, radius=2.0):
        T = geom.translation(a, b, c)
        out += [T, T @ geom.swap(), geom.swap() @ T @ geom.flip(-1, 1)]
    return out


def test_isometries_pull_back_the_metric(name, geom, rng):
    g = CURVED_METRICS[name]
    for M in some_isometries(name, geom, rng):
        for x in random_points(rng, 3):
            D = fd_jacobian(lambda p: geom.transform_points(M, p), x)
            np.testing.assert_allclose(D.T @ g(geom.transform_points(M, x)) @ D, g(x), rtol=1e-7, atol=1e-7)
        assert geom.is_isometry(M)


def test_nil_group_laws():
    geom = GEOMETRY["Nil"]
    rng = np.random.default_rng(9)
    for p, q, r in random_points(rng, 9, radius=3.0).reshape(3, 3, 3):
        np.testing.assert_allclose(nil_module.multiply(p, q), nil_product(p, q), rtol=1e-15)
        np.testing.assert_allclose(nil_product(nil_product(p, q), r), nil_product(p, nil_product(q, r)), rtol=1e-14)
        np.testing.assert_allclose(
            geom.left_multiplication(p) @ geom.left_multiplication(q),
            geom.left_multiplication(nil_product(p, q)),
            rtol=1e-14,
            atol=1e-14,
        )
        np.testing.assert_allclose(geom.transform_points(geom.left_multiplication(p), q), nil_product(p, q), rtol=1e-14)
        np.testing.assert_allclose(nil_product(p, nil_module.inverse(p)), 0.0, atol=1e-14)


def test_sol_translations_compose():
    geom = GEOMETRY["Sol"]
    rng = np.random.default_rng(10)
    for (a, b, c), (d, e, f) in random_points(rng, 6, radius=2.0).reshape(3, 2, 3):
        expected = geom.translation(math.exp(-c) * d + a, math.exp(c) * e + b, c + f)
        np.testing.assert_allclose(
            geom.translation(a, b, c) @ geom.translation(d, e, f), expected, rtol=1e-14, atol=1e-14
        )
        x = rng.normal(size=3)
        np.testing.assert_allclose(
            geom.transform_points(geom.translation(a, b, c), x),
            [math.exp(-c) * x[0] + a, math.exp(c) * x[1] + b, x[2] + c],
            rtol=1e-14,
        )
    np.testing.assert_allclose(geom.transform_points(geom.swap(), [1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    np.testing.assert_allclose(geom.transform_points(geom.flip(-1, 1), [1.0, 2.0, 3.0]), [-1.0, 2.0, 3.0])


def test_isometries_map_geodesics_to_geodesics(name, geom, rng):
    ts = np.array([0.5, 3.0, 7.0])
    for M in some_isometries(name, geom, rng):
        P = model(random_points(rng, 1)[0])
        V = geom.normalize_tangent(P, model(rng.normal(size=3), 0.0))
        X, W = geom.geodesic(P, V, ts)
        Y, U = geom.geodesic(M @ P, M @ V, ts)
        np.testing.assert_allclose(X @ M.T, Y, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(W @ M.T, U, rtol=1e-10, atol=1e-10)


def test_is_isometry_rejects_non_isometries(name, geom):
    scaled = np.eye(4)
    scaled[0, 0] = 1.01
    projective = np.eye(4)
    projective[3, 0] = 0.5
    shifted_z = np.eye(4)
    shifted_z[2, 3] = 1.0  # Sol: z + 1 without rescaling x, y
    paper_nil = np.eye(4)
    paper_nil[0, 3] = 1.0  # the paper's (x + 1, y, z)
    candidates = [scaled, projective, np.full((4, 4), np.nan), np.eye(3)]
    candidates += [paper_nil] if name == "Nil" else [shifted_z]
    for M in candidates:
        assert not geom.is_isometry(M)
    assert geom.is_isometry(np.eye(4))


def test_reorthonormalize_repairs_a_perturbed_isometry(name, geom, rng):
    for M0 in some_isometries(name, geom, rng):
        np.testing.assert_allclose(geom.reorthonormalize(M0), M0, rtol=1e-15, atol=1e-15)
        M = M0 + 1e-7 * rng.normal(size=(4, 4))
        assert not geom.is_isometry(M)
        R = geom.reorthonormalize(M)
        assert geom.is_isometry(R, tol=1e-13)
        assert np.abs(R - M0).max() < 1e-6 * max(1.0, np.abs(M0).max())


def test_nil_reorthonormalize_leaves_other_isometries_unchanged():
    """(x, y, z) -> (-x, -y, z) (a half-turn about the z axis) is an isometry, not a left
    multiplication."""
    geom = GEOMETRY["Nil"]
    half_turn = np.diag([-1.0, -1.0, 1.0, 1.0])
    for x in random_points(np.random.default_rng(11), 3):
        D = half_turn[:3, :3]
        np.testing.assert_allclose(D.T @ CURVED_METRICS["Nil"](D @ x) @ D, CURVED_METRICS["Nil"](x), atol=1e-15)
    assert geom.is_isometry(half_turn)
    np.testing.assert_array_equal(geom.reorthonormalize(half_turn), half_turn)


# --- connect, distance -----------------------------------------------------------------------------


def test_connect_reaches_nearby_points(name, geom, rng):
    a = random_points(rng, 12)
    b = a + rng.uniform(-1.0, 1.0, a.shape)
    A, B = geom.to_model(a), geom.to_model(b)
    V, r, ok = geom.connect(A, B)
    assert ok.all()
    for Ak, Vk in zip(A, V):
        assert speed2(name, Ak[:3], Vk[:3]) == pytest.approx(1.0, abs=1e-12)
    X, _ = geom.geodesic(A, V, r)
    np.testing.assert_allclose(X, B, rtol=1e-11, atol=1e-11)
    # independently: the integrated geodesic with that start reaches B too
    for k in range(3):
        xs, _ = integrate_geodesic(name, a[k], V[k, :3], [r[k]])
        np.testing.assert_allclose(xs[0], b[k], rtol=1e-9, atol=1e-9)


def test_distance_is_symmetric_and_the_length_of_short_geodesics(name, geom, rng):
    a = random_points(rng, 8)
    A = geom.to_model(a)
    V = geom.normalize_tangent(A, np.concatenate([rng.normal(size=(8, 3)), np.zeros((8, 1))], axis=1))
    t = rng.uniform(0.1, 1.0, 8)
    B, _ = geom.geodesic(A, V, t)
    np.testing.assert_allclose(geom.distance(A, B), t, rtol=1e-11)
    np.testing.assert_allclose(geom.distance(B, A), t, rtol=1e-11)


def test_connect_same_point_and_failure(name, geom):
    A = model([0.2, -0.4, 0.7])
    V, r, ok = geom.connect(A, A)
    assert ok and r == 0.0 and speed2(name, A[:3], V[:3]) == pytest.approx(1.0)
    V, r, ok = geom.connect(A, model([1.5, 1.0, -2.0]), max_iterations=0)
    assert not ok and np.isnan(r) and np.all(np.isnan(V))


# --- point-light falloff ---------------------------------------------------------------------------


def orthonormal_frame(name, x, v):
    """v and two unit vectors completing it to an orthonormal frame of the metric at x."""
    g = CURVED_METRICS[name](x)
    frame = [v]
    for e in np.eye(3)[np.argsort(np.abs(v))[:2]]:
        for f in frame:
            e = e - (e @ g @ f) * f
        frame.append(e / math.sqrt(e @ g @ e))
    return frame


def fan_area_density(name, x0, v0, r, eps=1e-4):
    """Area of the geodesic sphere per unit solid angle at r along (x0, v0): the Gram determinant
    of the spread of integrated geodesics tilted by +-eps towards the frame vectors e1, e2."""
    _, e1, e2 = orthonormal_frame(name, x0, v0)
    spread = []
    for e in (e1, e2):
        ends = [
            integrate_geodesic(name, x0, math.cos(eps) * v0 + sign * math.sin(eps) * e, [r])[0][0] for sign in (1, -1)
        ]
        spread.append((ends[0] - ends[1]) / (2 * math.sin(eps)))
    end = integrate_geodesic(name, x0, v0, [r])[0][0]
    gram = np.array([[a @ CURVED_METRICS[name](end) @ b for b in spread] for a in spread])
    return math.sqrt(np.linalg.det(gram))


@pytest.mark.parametrize("r", [0.3, 1.5, 4.0])
def test_falloff_is_the_inverse_area_density_of_the_geodesic_sphere(name, geom, rng, r):
    x0 = random_points(rng, 1)[0]
    v0 = unit_chart_vector(name, x0, rng.normal(size=3))
    falloff = float(geom.falloff_along(model(x0), model(v0, 0.0), r))
    assert falloff == pytest.approx(1.0 / fan_area_density(name, x0, v0, r), rel=1e-6)


def test_falloff_tends_to_inverse_square_and_is_the_same_from_both_ends(name, geom, rng):
    P = geom.to_model(random_points(rng, 6))
    V = geom.normalize_tangent(P, np.concatenate([rng.normal(size=(6, 3)), np.zeros((6, 1))], axis=1))
    for r in (1e-4, 1e-3):
        np.testing.assert_allclose(geom.falloff_along(P, V, r) * r * r, 1.0, rtol=10 * r * r)
    for r in (0.5, 2.0, 5.0):
        Q, U = geom.geodesic(P, V, r)
        np.testing.assert_allclose(geom.falloff_along(P, V, r), geom.falloff_along(Q, -U, r), rtol=1e-8)


# --- charts and tangent vectors --------------------------------------------------------------------


def test_chart_model_round_trip(name, geom, rng):
    xs = random_points(rng, 10, radius=5.0)
    X = geom.to_model(xs)
    np.testing.assert_array_equal(X[:, 3], 1.0)
    np.testing.assert_array_equal(geom.to_chart(X), xs)
    np.testing.assert_allclose(geom.to_chart(3.0 * X), xs, rtol=1e-15)
    np.testing.assert_allclose(geom.normalize_point(2.0 * X), X, rtol=1e-15)
    assert np.all(geom.in_chart(xs))
    assert not geom.in_chart([np.nan, 0, 0]) and not geom.in_chart([0, np.inf, 0])


def test_tangent_maps_are_mutually_inverse(name, geom, rng):
    for x in random_points(rng, 4):
        u = rng.normal(size=3)
        V = geom.tangent_to_model(x, u)
        np.testing.assert_array_equal(V, model(u, 0.0))
        np.testing.assert_allclose(geom.tangent_to_chart(geom.to_model(x), V), u, rtol=1e-15)
        # the differential of to_chart on a homogeneous curve (X(s) scaled by lambda(s))
        X = 2.0 * geom.to_model(x)
        W = rng.normal(size=4)
        fd = (geom.to_chart(X + 1e-6 * W) - geom.to_chart(X - 1e-6 * W)) / 2e-6
        np.testing.assert_allclose(geom.tangent_to_chart(X, W), fd, rtol=1e-7, atol=1e-8)


def test_normalize_tangent_gives_unit_metric_length(name, geom, rng):
    for x in random_points(rng, 6):
        V = geom.normalize_tangent(model(x), rng.normal(size=4))
        assert V[3] == 0.0
        assert speed2(name, x, V[:3]) == pytest.approx(1.0, abs=1e-14)


def test_normalization_keeps_extended_precision(name, geom):
    X = np.array([0.1, 0.2, 0.3, 1.0], dtype=np.longdouble) / 3
    assert geom.normalize_point(X).dtype == np.longdouble
    V = geom.normalize_tangent(geom.normalize_point(X), np.array([1, 2, 3, 0], dtype=np.longdouble))
    assert V.dtype == np.longdouble
    assert geom.normalize_point(X)[3] == 1
