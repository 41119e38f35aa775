"""Independent truth shared by the tests: the chart metrics written from the textbook formulas,
not taken from the library, their derivatives and Christoffel symbols, and the checks of the
library's flows against DOP853 on them."""

import math

import numpy as np

AMBIENT = {"E3": np.diag([1.0, 1.0, 1.0, 0.0]), "S3": np.eye(4), "H3": np.diag([1.0, 1.0, 1.0, -1.0])}


def chart_metric(name, x):
    x = np.asarray(x, float)
    r2 = x @ x
    if name == "E3":
        return np.eye(3)
    if name == "S3":
        return np.eye(3) / (1 + r2) - np.outer(x, x) / (1 + r2) ** 2
    if name == "H3":
        return np.eye(3) / (1 - r2) + np.outer(x, x) / (1 - r2) ** 2
    raise ValueError(name)


def nil_metric(x):
    """Nil: dx^2 + dy^2 + (dz - x dy)^2, the square of the 1-form dz - x dy = (0, -x, 1) added."""
    form = np.array([0.0, -x[0], 1.0])
    return np.diag([1.0, 1.0, 0.0]) + np.outer(form, form)


def sol_metric(x):
    """Sol: e^{2z} dx^2 + e^{-2z} dy^2 + dz^2."""
    return np.diag([np.exp(2 * x[2]), np.exp(-2 * x[2]), 1.0])


CURVED_METRICS = {"Nil": nil_metric, "Sol": sol_metric}


def h2xr_metric(x):
    """H2xR: the Klein disk's (dx^2 + dy^2) / (1 - r^2) + (x dx + y dy)^2 / (1 - r^2)^2, plus dz^2."""
    p = np.array([x[0], x[1], 0.0])
    q = 1.0 - p @ p
    return np.diag([1.0 / q, 1.0 / q, 1.0]) + np.outer(p, p) / q**2


def s2xr_metric(x):
    """S2xR: |dx|^2 / |x|^2 on R^3 minus the origin (x = e^w u: dw^2 + the unit sphere's metric)."""
    return np.eye(3) / (np.asarray(x, float) @ x)


def nil_sol_metric_derivative(name, x):
    """dg[l, i, j] = d g_ij / d x_l from the formulas (Nil: g_yy = 1 + x^2, g_yz = -x;
    Sol: g_xx = e^{2z}, g_yy = e^{-2z})."""
    dg = np.zeros((3, 3, 3))
    if name == "Nil":
        dg[0, 1, 1] = 2 * x[0]
        dg[0, 1, 2] = dg[0, 2, 1] = -1.0
    else:
        dg[2, 0, 0] = 2 * math.exp(2 * x[2])
        dg[2, 1, 1] = -2 * math.exp(-2 * x[2])
    return dg


def nil_sol_christoffel(name, x):
    return christoffel_from(CURVED_METRICS[name](x), nil_sol_metric_derivative(name, x))


def sl2_metric(x):
    """SL2 (model D x R): lam^2 (dx^2 + dy^2) + (dphi + lam (x dy - y dx))^2, lam = 2 / (1 - |w|^2)."""
    lam = 2 / (1 - x[0] ** 2 - x[1] ** 2)
    form = np.array([-lam * x[1], lam * x[0], 1.0])
    return np.diag([lam**2, lam**2, 0.0]) + np.outer(form, form)


def sl2_metric_derivative(x):
    """dg[l, i, j] = d_l g_ij: with d_l lam = lam^2 x_l (l = x, y), the disk block gives
    2 lam^3 x_l delta_ij and the form f = (-lam y, lam x, 1) gives d_l f_i f_j + f_i d_l f_j."""
    X, Y = x[0], x[1]
    lam = 2 / (1 - X * X - Y * Y)
    f = np.array([-lam * Y, lam * X, 1.0])
    df = np.zeros((3, 3))  # df[l, i] = d_l f_i
    df[0] = [-(lam**2) * X * Y, lam + lam**2 * X * X, 0.0]
    df[1] = [-lam - lam**2 * Y * Y, lam**2 * X * Y, 0.0]
    dg = np.einsum("li,j->lij", df, f) + np.einsum("i,lj->lij", f, df)
    for l, xl in enumerate((X, Y)):
        dg[l, 0, 0] += 2 * lam**3 * xl
        dg[l, 1, 1] += 2 * lam**3 * xl
    return dg


def sl2_christoffel(x):
    return christoffel_from(sl2_metric(x), sl2_metric_derivative(x))


def sl2_body_direction(x, b):
    """The unit chart velocity at x of body velocity b (carried from the origin by from_origin(x))."""
    from thurston_addon.geometries import sl2

    return sl2.act_tangent(sl2.from_origin(x), np.zeros(3), sl2.body_to_chart(b))


def assert_sl2_flow(x, u, t, tol=1e-9):
    """SL2's Python and C++ closed forms against DOP853."""
    from thurston_addon.geometries import sl2

    check_flows_against_dop853(sl2.SL2(), sl2_christoffel, sl2_metric, [(x, u, t)], tol=tol)


def christoffel_from(g, dg):
    """Gamma^k_ij = 1/2 g^kl (d_i g_lj + d_j g_li - d_l g_ij), (..., k, i, j), from the metric
    g (..., i, j) and its derivatives dg[..., l, i, j] = d_l g_ij, for one point or many; g^-1 by
    cofactors (the rows of a symmetric g's inverse are the cross products of its other rows over
    det g: for stacks of points far faster than np.linalg.inv)."""
    g, dg = np.asarray(g), np.asarray(dg)
    r0, r1, r2 = g[..., 0, :], g[..., 1, :], g[..., 2, :]
    inverse = np.stack([np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)], -2)
    inverse /= np.einsum("...i,...i->...", r0, inverse[..., 0, :])[..., None, None]
    lowered = 0.5 * (np.einsum("...ilj->...lij", dg) + np.einsum("...jli->...lij", dg) - dg)
    return np.einsum("...kl,...lij->...kij", inverse, lowered)


def dop853(christoffel, x0, v0, t):
    """Chart position and velocity at t along x'' = -Gamma(x)(x', x'), DOP853 at rtol = atol = 1e-12."""
    from scipy.integrate import solve_ivp

    def rhs(_t, y):
        return np.concatenate([y[3:], -np.einsum("kij,i,j->k", christoffel(y[:3]), y[3:], y[3:])])

    sol = solve_ivp(rhs, (0.0, t), np.concatenate([x0, v0]), method="DOP853", rtol=1e-12, atol=1e-12)
    assert sol.success
    return sol.y[:3, -1], sol.y[3:, -1]


def flows_against_dop853(G, christoffel, x, v, t):
    """(reference, flows): DOP853's chart position and velocity at t from (x, v), and those of the
    geometry's Python closed form and of the C++ core's flow."""
    import thurston_core

    xc, vc = thurston_core.geodesic_flow(G.name, x[None].copy(), v[None].copy(), np.array([t]))
    return dop853(christoffel, x, v, t), [G.chart_geodesic(x, v, t), (xc[0], vc[0])]


def check_flows_against_dop853(G, christoffel, metric, cases, tol=1e-9, speed_tol=1e-10):
    """For each case (x, v, t): the Python and the C++ flows' position and velocity equal DOP853's
    within tol (relative, and absolute on the scale 1 + |reference|), finite, at unit speed in
    `metric` to speed_tol."""
    for x, v, t in cases:
        (x_ref, v_ref), ((xp, vp), (xc, vc)) = flows_against_dop853(G, christoffel, x, v, t)
        for got, want in ((xp, x_ref), (vp, v_ref), (xc, x_ref), (vc, v_ref)):
            assert np.all(np.isfinite(got)), (x, v, t)
            assert np.all(np.abs(got - want) <= tol * (1 + np.abs(want)) + tol * np.abs(want)), (x, v, t, got, want)
        assert abs(vp @ metric(xp) @ vp - 1) < speed_tol, (x, v, t)


def unit_in(metric, x, u):
    """The chart vector u at x scaled to unit length in metric(x)."""
    u = np.asarray(u, float)
    return u / np.sqrt(u @ metric(x) @ u)
