"""Direct light along every geodesic in Nil, Sol and SL2 against independent truth.

The truth is the geodesic equation built from the metrics' formulas (Christoffel symbols from the
metric and its derivatives, checked against support/truth.py's), integrated by
DOP853, many geodesics at once: every geodesic from h to a point T no longer than a reach is found
by a scan (geodesics from h in 1000 directions, each's closest approach to T over its length; a
geodesic through T makes a local minimum of that miss over the directions) and damped Newton on
the integrated exponential map from those minima (rtol 1e-8), the distinct solutions polished at
rtol 1e-12. Falloffs: 1 / (r^2 |det d exp|) in orthonormal frames, d exp by central differences of
the integrated map. SL2's model (SU(1,1)) identifies phi with phi + 4 pi, so the tracer's geodesics
to a lift l are those of the universal cover to l + (0, 0, 4 pi k) for every k."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import thurston_core
from scipy.integrate import solve_ivp
from scipy.spatial import cKDTree
from support.lit_ball import GLOW, RHO, ball_scene, shade_one
from support.truth import (
    christoffel_from,
    nil_metric,
    nil_sol_christoffel,
    nil_sol_metric_derivative,
    sl2_christoffel,
    sl2_metric,
    sl2_metric_derivative,
    sol_metric,
)

from thurston_addon import render, spaces

# --- the truth --------------------------------------------------------------------------------------


def metric(name, x):
    """g_ij (..., 3, 3) at chart points x (..., 3): Nil dx^2 + dy^2 + (dz - x dy)^2, Sol e^{2z} dx^2 +
    e^{-2z} dy^2 + dz^2, SL2 lam^2 (dx^2 + dy^2) + (dphi + lam (x dy - y dx))^2, lam = 2 / (1 - |w|^2)."""
    x = np.asarray(x, float)
    X, Y, Z = x[..., 0], x[..., 1], x[..., 2]
    one, zero = np.ones_like(X), np.zeros_like(X)
    if name == "Nil":
        form = np.stack([zero, -X, one], -1)
        return np.diag([1.0, 1.0, 0.0]) + form[..., :, None] * form[..., None, :]
    if name == "Sol":
        g = np.zeros(x.shape + (3,))
        g[..., 0, 0], g[..., 1, 1], g[..., 2, 2] = np.exp(2 * Z), np.exp(-2 * Z), 1.0
        return g
    lam = 2 / (1 - X * X - Y * Y)
    form = np.stack([-lam * Y, lam * X, one], -1)
    g = form[..., :, None] * form[..., None, :]
    g[..., 0, 0] += lam**2
    g[..., 1, 1] += lam**2
    return g


def metric_derivative(name, x):
    """dg[..., l, i, j] = d_l g_ij, from the same formulas."""
    x = np.asarray(x, float)
    X, Y, Z = x[..., 0], x[..., 1], x[..., 2]
    dg = np.zeros(x.shape + (3, 3))
    if name == "Nil":
        dg[..., 0, 1, 1] = 2 * X
        dg[..., 0, 1, 2] = dg[..., 0, 2, 1] = -1.0
    elif name == "Sol":
        dg[..., 2, 0, 0] = 2 * np.exp(2 * Z)
        dg[..., 2, 1, 1] = -2 * np.exp(-2 * Z)
    else:  # d_l lam = lam^2 x_l; the form f = (-lam y, lam x, 1)
        lam = 2 / (1 - X * X - Y * Y)
        f = np.stack([-lam * Y, lam * X, np.ones_like(X)], -1)
        df = np.zeros(x.shape + (3,))  # df[..., l, i] = d_l f_i
        df[..., 0, 0], df[..., 0, 1] = -(lam**2) * X * Y, lam + lam**2 * X * X
        df[..., 1, 0], df[..., 1, 1] = -lam - lam**2 * Y * Y, lam**2 * X * Y
        dg = df[..., :, :, None] * f[..., None, None, :] + f[..., None, :, None] * df[..., :, None, :]
        dg[..., 0, 0, 0] += 2 * lam**3 * X
        dg[..., 0, 1, 1] += 2 * lam**3 * X
        dg[..., 1, 0, 0] += 2 * lam**3 * Y
        dg[..., 1, 1, 1] += 2 * lam**3 * Y
    return dg


def christoffel(name, x):
    """Gamma^k_ij (..., k, i, j) of these metrics at chart points x (..., 3)."""
    return christoffel_from(metric(name, x), metric_derivative(name, x))


def test_the_vectorised_truth_is_the_formulas_of_the_other_tests():
    rng = np.random.default_rng(3)
    for x in np.c_[rng.uniform(-0.7, 0.7, (5, 2)), rng.uniform(-2, 2, 5)]:
        np.testing.assert_allclose(christoffel("Nil", x), nil_sol_christoffel("Nil", x), rtol=1e-13, atol=1e-14)
        np.testing.assert_allclose(christoffel("SL2", x), sl2_christoffel(x), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(metric("Nil", x), nil_metric(x), rtol=1e-14)
        np.testing.assert_allclose(metric("Sol", x), sol_metric(x), rtol=1e-14)
        np.testing.assert_allclose(metric("SL2", x), sl2_metric(x), rtol=1e-14)
        for name in ("Nil", "Sol"):
            np.testing.assert_allclose(
                metric_derivative(name, x), nil_sol_metric_derivative(name, x), rtol=1e-14, atol=1e-14
            )
        np.testing.assert_allclose(metric_derivative("SL2", x), sl2_metric_derivative(x), rtol=1e-13, atol=1e-13)


def geodesic_equation(name, n):
    """x'' = -Gamma(x)(x', x') for n geodesics at once, the state (x, v) flattened, for solve_ivp."""

    def rhs(_s, y):
        x, v = y.reshape(2, n, 3)
        return np.concatenate([v, -np.einsum("nkij,ni,nj->nk", christoffel(name, x), v, v)]).ravel()

    return rhs


def exp_map(name, h, W, rtol=1e-12):
    """exp_h(W) for chart tangent vectors W (n, 3) at h: x'' = -Gamma(x)(x', x') over s in [0, 1]
    from x'(0) = W (the geodesic at speed |W|), all rows in one DOP853 integration."""
    W = np.atleast_2d(W)
    n = len(W)
    sol = solve_ivp(
        geodesic_equation(name, n),
        (0.0, 1.0),
        np.concatenate([np.broadcast_to(h, (n, 3)), W]).ravel(),
        method="DOP853",
        rtol=rtol,
        atol=rtol,
    )
    assert sol.success
    return sol.y[:, -1].reshape(2, n, 3)[0]


def fibonacci_sphere(n):
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    a = math.pi * (1 + math.sqrt(5)) * i
    return np.stack([np.sqrt(1 - z * z) * np.cos(a), np.sqrt(1 - z * z) * np.sin(a), z], -1)


DIRECTIONS, SAMPLES = 1000, 500


def scan_seeds(name, h, targets, reach, most=None):
    """(rows, seeds): for each target (K, 3), the tangent vectors t u (u unit at h, t <= reach the
    arclength of the geodesic's closest chart approach to the target) where that miss is a local
    minimum over u's 8 nearest directions (the `most` smallest such minima, or all), and the
    target's index of each."""
    sphere = fibonacci_sphere(DIRECTIONS)
    U = sphere @ np.linalg.inv(np.linalg.cholesky(metric(name, h)).T).T  # unit in the metric at h
    n = len(U)
    ts = np.linspace(0.0, reach, SAMPLES)
    sol = solve_ivp(
        geodesic_equation(name, n),
        (0.0, reach),
        np.concatenate([np.broadcast_to(h, (n, 3)), U]).ravel(),
        method="DOP853",
        rtol=1e-6,
        atol=1e-6,
        t_eval=ts,
    )
    assert sol.success
    path = sol.y.reshape(2, n, 3, SAMPLES)[0]
    _, near = cKDTree(sphere).query(sphere, k=9)
    rows, seeds = [], []
    for k, T in enumerate(np.atleast_2d(targets)):
        miss = np.linalg.norm(path - T[None, :, None], axis=1)
        at = np.argmin(miss, axis=1)
        best = np.where((at > 0) & (at < SAMPLES - 1), miss[np.arange(n), at], np.inf)  # not an end
        local = np.flatnonzero(np.isfinite(best) & np.all(best[:, None] <= best[near], axis=1))
        local = local[np.argsort(best[local])][:most]
        seeds.append(U[local] * ts[at[local]][:, None])
        rows += [k] * len(local)
    return np.array(rows, int), np.concatenate(seeds)


def newton(name, h, T, W, iterations, rtol, tolerance, longest):
    """exp_h(W) = T row by row (targets T (n, 3)) by Newton's method with forward differences, each
    step halved until the miss shrinks (three times at most), a row dropped where it comes within
    1e-3 of another's W for the same target; (W, converged)."""
    W, T = W.copy(), np.array(T, float)
    live = np.ones(len(W), bool)
    F = exp_map(name, h, W, rtol) - T
    g = metric(name, h)
    for _ in range(iterations):
        for target in np.unique(T, axis=0):  # rows that meet lead to the same geodesic
            rows = np.flatnonzero(live & np.all(T == target, axis=1))
            close = np.linalg.norm(W[rows, None] - W[None, rows], axis=2) < 1e-3 * (1 + np.linalg.norm(W[rows], axis=1))
            live[rows[np.any(np.triu(close, 1), axis=0)]] = False
        todo = np.flatnonzero(live & (np.linalg.norm(F, axis=1) >= tolerance))
        if not len(todo):
            break
        Wl = W[todo]
        step = 1e-6 * (1 + np.linalg.norm(Wl, axis=1))[:, None]
        X = exp_map(name, h, np.concatenate([Wl + step * e for e in np.eye(3)]), rtol).reshape(3, len(todo), 3)
        J = np.stack([(X[k] - T[todo] - F[todo]) / step for k in range(3)], -1)
        ok = np.all(np.isfinite(J), axis=(1, 2)) & (np.abs(np.linalg.det(J)) > 1e-300)
        live[todo[~ok]] = False
        dW = np.zeros_like(Wl)
        dW[ok] = np.linalg.solve(J[ok], F[todo][ok][..., None])[..., 0]
        pending = np.flatnonzero(ok)
        for _ in range(4):
            if not len(pending):
                break
            trial = Wl[pending] - dW[pending]
            Ft = np.full_like(trial, np.inf)
            inside = np.sqrt(np.einsum("ni,ij,nj->n", trial, g, trial)) <= longest
            if inside.any():
                Ft[inside] = exp_map(name, h, trial[inside], rtol) - T[todo[pending[inside]]]
            better = np.linalg.norm(Ft, axis=1) < np.linalg.norm(F[todo[pending]], axis=1)
            W[todo[pending[better]]], F[todo[pending[better]]] = trial[better], Ft[better]
            dW[pending[~better]] /= 2
            pending = pending[~better]
        live[todo[pending]] = False
    return W, live & (np.linalg.norm(F, axis=1) < tolerance)


def geodesics_to(name, h, targets, reach, most=None):
    """Per target (K, 3): every geodesic from h to it no longer than reach, as chart tangent vectors
    W at h (|W| = its length), distinct (from the `most` best seeds of each, or all)."""
    targets = np.atleast_2d(targets)
    rows, W = scan_seeds(name, h, targets, reach, most)
    scale = (1 + np.linalg.norm(targets, axis=1))[rows]
    W, ok = newton(name, h, targets[rows], W, 12, 1e-8, 1e-6 * scale, 1.5 * reach + 1)
    found = []
    g = metric(name, h)
    for k in range(len(targets)):
        distinct = []
        for w in W[ok & (rows == k)]:
            if not any(np.linalg.norm(w - d) < 1e-3 * (1 + np.linalg.norm(w)) for d in distinct):
                distinct.append(w)
        if distinct:
            T = np.repeat(targets[k][None], len(distinct), axis=0)
            polished, ok2 = newton(
                name, h, T, np.array(distinct), 6, 1e-12, 1e-10 * (1 + np.linalg.norm(targets[k])), 1.5 * reach + 1
            )
            assert ok2.all()
            distinct = [w for w in polished if math.sqrt(w @ g @ w) <= reach]
        found.append(distinct)
    return found


def falloff(name, h, W):
    """1 / (r^2 |det d exp_h(W)|) in orthonormal frames: the chart Jacobian (central differences of
    the integrated map) times sqrt(det g) at its end over that at h."""
    step = 1e-5 * (1 + np.linalg.norm(W))
    X = exp_map(name, h, np.array([W + s * step * e for e in np.eye(3) for s in (1, -1)] + [W]))
    J = np.stack([(X[2 * k] - X[2 * k + 1]) / (2 * step) for k in range(3)], -1)
    frames = math.sqrt(np.linalg.det(metric(name, X[-1])) / np.linalg.det(metric(name, h)))
    r2 = W @ metric(name, h) @ W
    return 1.0 / (r2 * abs(np.linalg.det(J)) * frames)


def sl2_lifts(x, turns=(-1, 0, 1)):
    """The universal cover's points over the model's chart points x (n, 3): phi + 4 pi k, k by k."""
    return np.concatenate([np.atleast_2d(x) + [0.0, 0.0, 4 * math.pi * k] for k in turns])


# --- every geodesic between two points --------------------------------------------------------------

PAIRS = {  # (geometry, h, l, reach, geodesics within the reach)
    "nil near": ("Nil", [0.3, -0.2, 0.1], [1.1, 0.4, 0.9], 3.0, 1),
    # l = h (0.05, 0.02, 9): nearly above h, past 2 pi: branch 0 and both of branch 1
    "nil above": ("Nil", [0.1, 0.2, 0.0], [0.15, 0.22, 9.002], 10.0, 3),
    "sol near": ("Sol", [0.2, -0.1, 0.15], [0.9, 0.4, 0.5], 3.0, 1),
    # along a geodesic of |p_x p_y| near 1/2 for 4.9, past its period (about pi sqrt 2 = 4.44)
    "sol beyond a period": ("Sol", [0.2, -0.1, 0.15], [-3.20091639, 3.44292606, 0.11985047], 6.0, 3),
    "sl2 near": ("SL2", [0.2, -0.1, 0.3], [-0.3, 0.25, 1.4], 3.0, 1),
    # near the fibre through h, 9 up: component 0 and both of component 1 (lengths over 2 pi), and
    # component 0 of the lift 4 pi down
    "sl2 along the fibre": ("SL2", [0.1, -0.05, 0.2], [0.2, -0.05, 9.2], 10.0, 4),
}


@pytest.mark.parametrize("case", PAIRS)
def test_every_connecting_geodesic_and_its_falloff(case):
    """The tracer's connecting geodesics (count, lengths, initial directions, falloffs) are the
    enumeration's: lengths to 1e-9, unit chart directions to 1e-8, falloffs to 1e-7 (Sol's, whose
    Jacobian the tracer takes by forward differences of its flow, to 3e-4; 8e-5 measured)."""
    name, h, l, reach, count = PAIRS[case]
    h, l = np.array(h), np.array(l)
    directions, lengths, falloffs, missed = thurston_core.Connections(name, reach)(h, l)
    assert missed == 0
    targets = sl2_lifts(l) if name == "SL2" else l[None]
    truth = [w for found in geodesics_to(name, h, targets, reach) for w in found]
    assert len(truth) == len(lengths) == count
    g = metric(name, h)
    matched = []
    for w in truth:
        r = math.sqrt(w @ g @ w)
        k = int(np.argmin(np.abs(lengths - r)))
        assert lengths[k] == pytest.approx(r, rel=1e-9)
        np.testing.assert_allclose(directions[k], w / r, atol=1e-8)
        assert falloffs[k] == pytest.approx(falloff(name, h, w), rel=3e-4 if name == "Sol" else 1e-7)
        matched.append(k)
    assert sorted(matched) == list(range(count))  # each traced geodesic is one of the truth's, none twice


# --- the lit colour: every copy of the light along every geodesic -------------------------------------


def may_reach(name, h, x, reach, fibre=True):
    """Whether a point x may lie within reach of h (necessary conditions): no curve outruns its
    projection to Nil's (x, y) plane, SL2's hyperbolic plane or Sol's z axis; in SL2 (where `fibre`:
    the universal cover's chart, not the model's) phi' = c - lam Im(conj(w) w') changes at most by
    |c| + |w| a < sqrt 2 per unit length (a, c the body speeds, a^2 + c^2 = 1); in Nil a curve of
    length L rises by at most L + L^2 / pi in the symmetric height z - x y / 2 seen from its start
    (its vertical part, and the area its shadow encloses with the chord, isoperimetric); in Sol, at
    arclength s of a curve of length L ending dz above its start, z - z_h lies between
    max(-s, dz - (L - s)) and min(s, dz + (L - s)), so |x'| <= e^{-z} and |y'| <= e^z keep |dx| and
    |dy| below the integrals of the bounds' exponentials."""
    x = np.atleast_2d(x)
    d = x - h
    if name == "Nil":
        height = d[:, 2] - h[0] * d[:, 1] - 0.5 * d[:, 0] * d[:, 1]
        return (np.hypot(d[:, 0], d[:, 1]) <= reach) & (np.abs(height) <= reach + reach**2 / math.pi)
    if name == "Sol":
        s = np.linspace(0.0, reach, 2001)[:, None]
        below = np.maximum(-s, d[:, 2] - (reach - s))  # z - z_h: the curve's lowest at s
        above = np.minimum(s, d[:, 2] + (reach - s))
        # trapezoids overestimate the integrals of the exponentials' convex pieces (1% to spare at the kink)
        spread_x = 1.01 * np.trapz(np.exp(-below), s, axis=0) * math.exp(-h[2])
        spread_y = 1.01 * np.trapz(np.exp(above), s, axis=0) * math.exp(h[2])
        return (np.abs(d[:, 2]) <= reach) & (np.abs(d[:, 0]) <= spread_x) & (np.abs(d[:, 1]) <= spread_y)
    w, v = h[0] + 1j * h[1], x[:, 0] + 1j * x[:, 1]
    along = np.abs(d[:, 2]) <= math.sqrt(2) * reach if fibre else True
    return along & (2 * np.arctanh(np.abs((v - w) / (1 - np.conj(w) * v))) <= reach)


def group_copies(space, L, h, reach, margin):
    """The chart points of the copies w L of the model point L (w words in the space file's
    generators and their inverses) that may lie within reach of h: a breadth-first search over the
    words whose copies may lie within reach + margin (a copy within reach is reached through copies
    of its words' suffixes, each within reach + the domain's diameter of h), then those within reach."""
    g = space.geometry
    letters = [*space.generators, *(np.linalg.inv(M) for M in space.generators)]
    seen, points = set(), []
    frontier = [np.eye(4)]
    while frontier:
        following = []
        for M in frontier:
            x = np.asarray(g.to_chart(g.normalize_point(M @ L)), float)
            key = tuple(np.round(x, 7))
            if key in seen or not may_reach(g.name, h, x, reach + margin, fibre=False)[0]:
                continue
            seen.add(key)
            points.append(x)
            following += [A @ M for A in letters]
        frontier = following
    points = np.array(points)
    return points[may_reach(g.name, h, points, reach, fibre=False)]


SCENES = {  # space: (light, ball centre, the ray's start offset, the domain's diameter at most)
    "nil": ([0.2, -0.1, 0.3], [-0.15, 0.25, -0.2], [0.0, -0.3, 0.1], 3.0),
    "sol": ([0.15, 0.2, 0.25], [-0.1, -0.15, -0.2], [0.0, -0.1, 0.03], 3.0),
    # the light and the point near opposite lids: one of the copies the model identifies (phi and
    # phi + 4 pi) lights the point along a geodesic to its lift 4 pi on
    "sl2": ([-0.50, 0.13, -0.74], [0.53, 0.014, 2.86], [-0.2, 0.0, -0.1], 5.0),
}


@pytest.mark.slow
@pytest.mark.parametrize("space_id", SCENES)
def test_lit_colour_sums_every_copy_along_every_geodesic(space_id):
    """A point of a small emissive ball (which casts no shadow on the light) at the default light
    reach: colour = glow + base * sum over the light's copies in the universal cover and the
    geodesics to each within the reach of max(0, cos) * power * falloff, the copies from the space
    file's generators (group_copies, times SL2's 4 pi along the fibre), the geodesics and falloffs from the
    enumeration (from the 3 best seeds of each copy: below 2 pi in Nil and SL2, and the period pi sqrt 2
    in Sol, a copy has one geodesic within the reach, as test_every_connecting_geodesic_and_its_falloff
    finds); the trace's path count and energy too. Each term exceeds the tolerance 20 times over, so a
    missing copy fails it; missing further geodesics fail test_second_geodesics_light_too."""
    space = spaces.load(space_id)
    g, name = space.geometry, space.geometry.name
    light, centre, offset, margin = (np.array(v, float) if isinstance(v, list) else v for v in SCENES[space_id])
    power, reach = 0.6, render.default_light_reach(space)
    colour, H, N, out = shade_one(space, ball_scene(centre, light, power), centre + offset, centre, reach)
    x, n = np.asarray(g.to_chart(H), float), np.asarray(g.tangent_to_chart(H, N), float)
    L, _, _ = space.bring_inside(g.to_model(light))
    copies = group_copies(space, L, x, reach, margin)
    turned = np.zeros(len(copies), bool)
    if name == "SL2":
        turned = np.repeat([True, False, True], len(copies))
        copies = sl2_lifts(copies)
        near = may_reach(name, x, copies, reach)
        copies, turned = copies[near], turned[near]
    found = geodesics_to(name, x, copies, reach, most=3)
    if name == "SL2":
        assert any(f for f, t in zip(found, turned) if t)  # the model's other lift lights it
    G = metric(name, x)
    terms, energy = [], 0.0
    for w in (w for f in found for w in f):
        r = math.sqrt(w @ G @ w)
        fall = falloff(name, x, w)
        energy += power * fall * (n @ G @ w > 0)  # (the paths to the point's front are counted)
        terms.append(max(n @ G @ w / r, 0.0) * power * fall)
    terms = np.array(terms)
    rtol = 3e-4 if name == "Sol" else 2e-5  # Sol's falloffs; else the float32 colour
    assert out["light_paths"] == np.count_nonzero(terms) >= 2
    assert float(out["light_energy"]) == pytest.approx(energy, rel=rtol)
    np.testing.assert_allclose(colour, GLOW + RHO * terms.sum(), rtol=rtol)
    print(f"{len(terms)} geodesics; smallest term / colour", RHO * terms[terms > 0].min() / colour.max())
    assert RHO * terms[terms > 0].min() > 20 * rtol * colour.max()


WIDE_NIL = """name = "wide Heisenberg manifold"
description = "Nil / the integer Heisenberg group dilated by 12 (the automorphism (12 x, 12 y, 144 z))"
geometry = "Nil"
covolume = 20736
max_distance = 20
max_crossings = 64

[[generator]]
name = "x"
matrix = [[1, 0, 0, 12], [0, 1, 0, 0], [0, 12, 1, 0], [0, 0, 0, 1]]
face = [1, 0, 0, -6]

[[generator]]
name = "y"
matrix = [[1, 0, 0, 0], [0, 1, 0, 12], [0, 0, 1, 0], [0, 0, 0, 1]]
face = [0, 1, 0, -6]

[[generator]]
name = "z"
matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 144], [0, 0, 0, 1]]
face = [0, 0, 1, -72]
"""


def test_second_geodesics_light_too(tmp_path):
    """Nil with a lattice wide enough that within a reach of 8.2 a point sees one copy of the light
    (the others lie 11.5 or more away across, 136 or more up or down: may_reach), the light 8 above
    the point, a little aside: three geodesics reach it, of branch 0 and both of branch 1 (turning
    by more than 2 pi), and the colour is the sum over the three; each term exceeds the tolerance 20
    times over, so a missing second geodesic fails it."""
    path = tmp_path / "wide_nil.toml"
    path.write_text(WIDE_NIL)
    space = spaces.load(path)
    g, reach, power = space.geometry, 8.2, 0.6
    centre, light = np.array([0.0, 0.0, -4.0]), np.array([0.25, 0.1, 4.0])
    colour, H, N, out = shade_one(space, ball_scene(centre, light, power), centre + [0.0, -0.3, 0.1], centre, reach)
    x, n = np.asarray(g.to_chart(H), float), np.asarray(g.tangent_to_chart(H, N), float)
    neighbours = np.array(
        [
            g.to_chart(g.left_multiplication(np.array(k, float) * [12, 12, 144]) @ g.to_model(light))
            for k in itertools.product((-1, 0, 1), repeat=3)
        ]
    )
    assert np.count_nonzero(may_reach("Nil", x, neighbours, reach)) == 1
    (found,) = geodesics_to("Nil", x, light, reach)
    assert len(found) == 3
    G = metric("Nil", x)
    terms = np.array([max(n @ G @ w, 0.0) / math.sqrt(w @ G @ w) * power * falloff("Nil", x, w) for w in found])
    assert out["light_paths"] == 3
    np.testing.assert_allclose(colour, GLOW + RHO * terms.sum(), rtol=2e-5)
    assert RHO * terms.min() > 20 * 2e-5 * colour.max()


# --- the bounds the copies of a light are found by ------------------------------------------------------


def domain_points(space, n, rng):
    """n points of the domain (its vertices first): convex combinations of the vertices of Nil's and
    Sol's chart polyhedra; SL2's octagon (convex in the Klein disk) times its fibre interval."""
    V = space.domain.vertices
    if space.geometry.name != "SL2":
        return np.concatenate([V, rng.dirichlet(np.ones(len(V)), n - len(V)) @ V])
    C = space.domain.covectors()
    sides = C[C[:, 2] == 0][:, [0, 1, 3]]
    k = rng.uniform(-1, 1, (20 * n, 2))
    k = k[np.all(np.c_[k, np.ones(len(k))] @ sides.T <= 0, axis=1)][: n - len(V)]
    w = k / (1 + np.sqrt(1 - np.sum(k * k, axis=1)))[:, None]
    return np.concatenate([V, np.c_[w, rng.uniform(-math.pi, math.pi, len(w))]])


@pytest.mark.parametrize("space_id", ["nil", "sol", "sl2"])
def test_the_bounds_of_distances_hold(space_id):
    """What render.cover_copies relies on to miss no copy of a light: domain_distance at most the
    distance from a point to the domain, farthest_distance at least the distance from a point of
    the domain to its farthest one (SL2's walk is in H^2: there it is the disk's, exact at a
    vertex), and distance_bound at least the distance (an emitter's copies reach as far as its
    points' do); distances being the shortest connecting geodesics (whose enumeration
    test_every_connecting_geodesic_and_its_falloff checks), between 300 points of the domain and
    points of it and of its neighbouring copies."""
    rng = np.random.default_rng(11)
    space = spaces.load(space_id)
    g = space.geometry
    inside = domain_points(space, 300, rng)
    letters = [*space.generators, *(np.linalg.inv(M) for M in space.generators)]
    outside = [
        np.asarray(g.to_chart(g.normalize_point(letters[i] @ g.to_model(p))), float)
        for p, i in zip(inside[-12:], rng.integers(0, len(letters), 12))
    ]
    connect = thurston_core.Connections(g.name, 8.0)

    def distances(x):
        return np.array([min(connect(x, q)[1], default=0.0 if np.array_equal(x, q) else np.inf) for q in inside])

    for x in [*inside[:8], *inside[-4:], *outside]:
        d = distances(x)
        X = g.to_model(x)
        assert np.all(np.isfinite(d))
        assert g.domain_distance(X, space.domain) <= d.min() + 1e-9
        assert np.all(np.asarray(g.distance_bound(X, g.to_model(inside)), float) >= d - 1e-9)
        if g.name != "SL2":
            assert g.farthest_distance(X, space.domain) >= d.max() - 1e-9
    assert max(float(g.domain_distance(g.to_model(x), space.domain)) for x in outside) > 0.3


@pytest.mark.parametrize(
    "geometry, reach, message",
    [
        ("Nil", -1.0, "reach"),
        ("Sol", math.nan, "reach"),
        ("SL2", math.inf, "reach"),
        ("E3", 1.0, "no marching flow"),
        ("Heisenberg", 1.0, "unknown geometry"),
    ],
)
def test_bad_connections_are_one_clear_error(geometry, reach, message):
    with pytest.raises(ValueError, match=message):
        thurston_core.Connections(geometry, reach)
