"""S2xR against independent truth.

The metric is truth.s2xr_metric (|dx|^2 / |x|^2); its derivatives are written here and checked
against finite differences, the Christoffel symbols and the geodesic equation are built from them
and integrated with DOP853 at 1e-12. Isometries are checked by pulling the metric back.
"""
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import thurston_core
from thurston_addon.geometries import get
from truth import s2xr_metric

G = get("S2xR")


def metric_derivative(x):
    """dg[l, i, j] = d g_ij / d x_l = -2 x_l delta_ij / |x|^4."""
    return -2 * np.einsum("l,ij->lij", x, np.eye(3)) / (x @ x) ** 2


def christoffel_truth(x):
    dg = metric_derivative(x)
    lowered = 0.5 * (np.einsum("ilj->lij", dg) + np.einsum("jli->lij", dg) - dg)
    return np.einsum("kl,lij->kij", np.linalg.inv(s2xr_metric(x)), lowered)


def dop853(x0, v0, t):
    def rhs(_t, y):
        return np.concatenate([y[3:], -np.einsum("kij,i,j->k", christoffel_truth(y[:3]), y[3:], y[3:])])
    sol = solve_ivp(rhs, (0.0, t), np.concatenate([x0, v0]), method="DOP853", rtol=1e-12, atol=1e-12)
    assert sol.success
    return sol.y[:3, -1], sol.y[3:, -1]


def unit(x, u):
    u = np.asarray(u, float)
    return u / math.sqrt(u @ s2xr_metric(x) @ u)


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
    rng = np.random.default_rng(2)
    for x, v, t in geodesic_cases(rng):
        x_ref, v_ref = dop853(x, v, t)
        xp, vp = G.chart_geodesic(x, v, t)
        xc, vc = thurston_core.geodesic_flow("S2xR", x[None].copy(), v[None].copy(), np.array([t]))
        for got, want in ((xp, x_ref), (vp, v_ref), (xc[0], x_ref), (vc[0], v_ref)):
            assert np.all(np.isfinite(got))
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())
        assert abs(vp @ s2xr_metric(xp) @ vp - 1) < 1e-12


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
