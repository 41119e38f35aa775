"""SL2~ (model D x R) against independent truth.

The metric is written here from lam^2 (dx^2 + dy^2) + (dphi + lam (x dy - y dx))^2, lam = 2 / (1 - |w|^2);
its derivatives by hand, checked against finite differences; the Christoffel symbols and the geodesic
equation are built from them (truth.christoffel_from) and integrated with DOP853 at 1e-12.
"""
import math

import numpy as np
import pytest

from thurston_addon.geometries import sl2
from truth import christoffel_from, dop853, unit_in

G = sl2.SL2()


def metric_truth(x):
    lam = 2 / (1 - x[0] ** 2 - x[1] ** 2)
    form = np.array([-lam * x[1], lam * x[0], 1.0])
    return np.diag([lam**2, lam**2, 0.0]) + np.outer(form, form)


def metric_derivative(x):
    """dg[l, i, j] = d_l g_ij: with d_l lam = lam^2 x_l (l = x, y), the disk block gives
    2 lam^3 x_l delta_ij and the form f = (-lam y, lam x, 1) gives d_l f_i f_j + f_i d_l f_j."""
    X, Y = x[0], x[1]
    lam = 2 / (1 - X * X - Y * Y)
    f = np.array([-lam * Y, lam * X, 1.0])
    df = np.zeros((3, 3))  # df[l, i] = d_l f_i
    df[0] = [-lam**2 * X * Y, lam + lam**2 * X * X, 0.0]
    df[1] = [-lam - lam**2 * Y * Y, lam**2 * X * Y, 0.0]
    dg = np.einsum("li,j->lij", df, f) + np.einsum("i,lj->lij", f, df)
    for l, xl in enumerate((X, Y)):
        dg[l, 0, 0] += 2 * lam**3 * xl
        dg[l, 1, 1] += 2 * lam**3 * xl
    return dg


def christoffel_truth(x):
    return christoffel_from(metric_truth(x), metric_derivative(x))


def unit(x, u):
    return unit_in(metric_truth, x, u)


def random_point(rng, radius=0.8):
    r, a = radius * math.sqrt(rng.random()), rng.uniform(0, 2 * math.pi)
    return np.array([r * math.cos(a), r * math.sin(a), rng.uniform(-3, 3)])


def random_element(rng):
    return sl2.multiply(sl2.fibre_translation(rng.uniform(-5, 5)), sl2.from_origin(random_point(rng)))


def jacobian(f, x, h=1e-6):
    return np.stack([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(3)], -1)


def assert_flow(x, u, t, tol=1e-9):
    x_ref, v_ref = dop853(christoffel_truth, x, u, t)
    xp, vp = G.chart_geodesic(x, u, t)
    for got, want in ((xp, x_ref), (vp, v_ref)):
        assert np.all(np.abs(got - want) <= tol * (1 + np.abs(want))), (x, u, t, got, want)
    assert abs(vp @ metric_truth(xp) @ vp - 1) < 1e-10


@pytest.fixture
def rng():
    return np.random.default_rng(8)


def test_metric_and_christoffel(rng):
    for _ in range(20):
        x = random_point(rng, 0.95)
        assert np.allclose(G.metric(x), metric_truth(x), rtol=1e-14, atol=0)
        fd = jacobian(metric_truth, x).transpose(2, 0, 1)
        assert np.allclose(metric_derivative(x), fd, rtol=1e-6, atol=1e-6)
        assert np.allclose(G.christoffel(x), christoffel_truth(x), rtol=1e-12, atol=1e-12)


def test_isometries_pull_back_the_metric(rng):
    for _ in range(20):
        g, x = random_element(rng), random_point(rng)
        J = jacobian(lambda p: sl2.act(g, p), x)
        assert np.allclose(J.T @ metric_truth(sl2.act(g, x)) @ J, metric_truth(x), rtol=1e-7, atol=1e-7)
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
        assert_flow(x, unit(x, rng.normal(size=3)), rng.uniform(0, 10))


def test_geodesic_fibre_rays(rng):
    for sign in (1, -1):
        x = random_point(rng)
        u = unit(x, sl2.act_tangent(sl2.from_origin(x), np.zeros(3), [0, 0, sign]))
        assert_flow(x, u, 7.0)
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
        assert_flow(x, u, 9.0)


def test_geodesic_near_the_disk_boundary(rng):
    for _ in range(10):
        a = rng.uniform(0, 2 * math.pi)
        x = np.array([0.99 * math.cos(a), 0.99 * math.sin(a), rng.uniform(-3, 3)])
        assert_flow(x, unit(x, rng.normal(size=3)), rng.uniform(0, 3))


def test_geodesic_broadcasts_over_times(rng):
    x = random_point(rng)
    u = unit(x, rng.normal(size=3))
    ts = np.array([0.0, 1.0, 4.0])
    xs, vs = G.chart_geodesic(np.broadcast_to(x, (3, 3)), np.broadcast_to(u, (3, 3)), ts)
    for k, t in enumerate(ts):
        x1, v1 = G.chart_geodesic(x, u, t)
        assert np.allclose(xs[k], x1, rtol=0, atol=1e-15) and np.allclose(vs[k], v1, rtol=0, atol=1e-15)
    assert np.allclose(xs[0], x) and np.allclose(vs[0], u)
