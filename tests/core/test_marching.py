"""The Nil and Sol tracing (src/core/march.hpp, nil.hpp, sol.hpp through Embree) against truth
that this file builds on its own:

- the geodesic equation from the metrics of truth.py, with Christoffel symbols derived here
  (complex-step derivatives of the metric), integrated by DOP853 at rtol = atol = 1e-12;
- orthonormal frames written from the metrics (Nil: the coframe dx, dy, dz - x dy; Sol:
  e^z dx, e^-z dy, dz), not taken from the library;
- the reduction of a point of the universal cover into the domain by the lattice, in closed form
  and extended precision (Nil: the integer Heisenberg group; Sol: the monodromy power, then the
  lattice of u1, u2), finished by Space.move_inside;
- first hits of the densely sampled reference geodesic (the Python closed form / integrator,
  itself checked against DOP853 in test 1) with the copies of triangulated spheres, found by a
  Moeller-Trumbore segment test written here on short straight pieces (coarse, then fine);
- light: the connecting geodesic and falloff of the Python reference (connect, falloff_along),
  the metric normal written from the metric, shadows by the segment test along that geodesic.

Nothing is compared with output of the code saved earlier. Errors are chart units unless said.
Tables of the measured errors are printed (run with -s to see them).
"""

import math

import numpy as np
import pytest
import thurston_core
import trimesh
from scipy.integrate import solve_ivp
from support.lattice import SOL_PERIOD, SOL_U1, SOL_U2, into_domain, ld
from support.report import report
from support.truth import CURVED_METRICS as METRIC
from support.truth import christoffel_from

from thurston_addon import cli, render, scenes
from thurston_addon.geometries import get
from thurston_addon.scenes import PointLight, Scene, SceneObject, default_scene

TOLERANCE = 1e-6  # the fine tracing tolerance (chart units)


# --- truth: metrics, frames, the geodesic equation ----------------------------------------------

COMPLEX_STEP = 1e-30


def christoffel(name, x):
    """Gamma^k_ij = 1/2 g^kl (d_i g_lj + d_j g_li - d_l g_ij), with d g by complex steps of the
    truth metric (exact to rounding for these analytic metrics)."""
    metric = METRIC[name]
    x = np.asarray(x, float)
    dg = np.array([np.imag(metric(x + 1j * COMPLEX_STEP * e)) / COMPLEX_STEP for e in np.eye(3)])
    return christoffel_from(metric(x), dg)


def dop853(name, x0, v0, length, scale=(1.0, 1.0, 1.0)):
    """Position and velocity after `length` along x'' = -Gamma(x)(x', x'), DOP853 at
    rtol = atol = 1e-12 (atol times `scale` per coordinate)."""

    def rhs(_t, y):
        return np.concatenate([y[3:], -np.einsum("kij,i,j->k", christoffel(name, y[:3]), y[3:], y[3:])])

    scale = np.asarray(scale, float)
    sol = solve_ivp(
        rhs,
        (0.0, float(length)),
        np.concatenate([x0, v0]),
        method="DOP853",
        rtol=1e-12,
        atol=1e-12 * np.concatenate([scale, scale]),
    )
    assert sol.success
    return sol.y[:3, -1], sol.y[3:, -1]


def chart_velocity(name, p, e):
    """The chart velocity at chart points p (..., 3) with components e (..., 3) in the
    orthonormal frame of the metric there (Nil: dual to dx, dy, dz - x dy; Sol: to e^z dx,
    e^-z dy, dz)."""
    p, e = np.broadcast_arrays(np.asarray(p), np.asarray(e))
    if name == "Nil":
        return np.stack([e[..., 0], e[..., 1], e[..., 2] + p[..., 0] * e[..., 1]], -1)
    return np.stack([np.exp(-p[..., 2]) * e[..., 0], np.exp(p[..., 2]) * e[..., 1], e[..., 2]], -1)


def metric_norm(name, x, d):
    """|d| in the truth metric at x, rows."""
    g = np.array([METRIC[name](xi) for xi in np.asarray(x, float)])
    return np.sqrt(np.maximum(np.einsum("ni,nij,nj->n", d, g, d), 0.0))


def unit_rows(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def image_distance(space, A, B):
    """Chart distance between chart points A (n, 3) in the domain and the nearest copy g(B),
    g in space.neighbourhood(1), of points B (n, 3) near it (points on a face have two images)."""
    B4 = np.concatenate([np.asarray(B, ld), np.ones((len(B), 1), ld)], axis=1)
    best = np.full(len(A), np.inf)
    for N in space.neighbourhood(1):
        C = B4 @ np.asarray(N, ld).T
        d = np.asarray(C[:, :3] / C[:, 3:] - np.asarray(A, ld), float)
        best = np.minimum(best, np.linalg.norm(d, axis=1))
    return best


def interior_points(space, rng, n, margin=0.0, avoid=(), avoid_radius=0.0):
    """Random chart points inside the domain, `margin` from its faces and `avoid_radius` from the
    points `avoid`."""
    C = space.domain.covectors()
    C = C / np.linalg.norm(C[:, :3], axis=1)[:, None]
    lo, hi = space.domain.vertices.min(0), space.domain.vertices.max(0)
    out = np.zeros((0, 3))
    while len(out) < n:
        x = rng.uniform(lo, hi, (4 * n, 3))
        ok = np.all(np.c_[x, np.ones(len(x))] @ C.T < -margin, axis=1)
        for c in avoid:
            ok &= np.linalg.norm(x - c, axis=1) > avoid_radius
        out = np.vstack([out, x[ok]])
    return out[:n]


def empty_tracer(space):
    return render.make_tracer(space, Scene())


def trace(tracer, P, V, length, tolerance=TOLERANCE, shade=False, max_crossings=100000):
    out = tracer.trace(
        np.ascontiguousarray(P, float),
        np.ascontiguousarray(V, float),
        float(length),
        max_crossings,
        shade=shade,
        tolerance=tolerance,
    )
    return out


# --- 1. the C++ flow, the Python reference and DOP853 on the same rays ------------------------

NIL_W = [0.0, 1e-300, 1e-12, 1e-6, 1.0]


def flow_cases(name, rng, n=1000):
    """Starts, chart velocities (unit in the metric) and lengths: random, plus Nil's vertical
    components w (the frame's third component) from NIL_W, Sol's frame axes, directions near
    the planes p_x = 0 and p_y = 0, starts on and near the planes x = 0 and y = 0, and |z| up
    to 20."""
    p = rng.uniform(-2, 2, (n, 3))
    e = unit_rows(rng, n)
    if name == "Nil":
        L = rng.uniform(0, 20, n)
        p[: n // 10] *= 10  # far from the origin too
        for k, w in enumerate(NIL_W):  # 40 rays each: (c cos a, c sin a, w), c^2 + w^2 = 1
            rows = slice(100 + 40 * k, 140 + 40 * k)
            a = rng.uniform(0, 2 * np.pi, 40)
            c = math.sqrt(1 - w * w)
            e[rows] = np.stack([c * np.cos(a), c * np.sin(a), np.full(40, w)], -1)
            e[rows][::2, 2] *= -1
    else:
        L = rng.uniform(0, 10, n)
        p[:, 2] = rng.uniform(-20, 20, n)
        p[: n // 10, 2] = rng.choice([-20.0, 20.0], n // 10)
        axes = np.concatenate([np.eye(3), -np.eye(3)])
        e[100:400] = axes[rng.integers(0, 6, 300)]
        near = rng.choice([1e-300, 1e-12, 1e-9, 1e-6], 200) * rng.choice([-1, 1], 200)
        e[400:500, 0] = near[:100]  # near the plane p_x = 0
        e[500:600, 1] = near[100:]  # near the plane p_y = 0
        e[400:600] /= np.linalg.norm(e[400:600], axis=1)[:, None]
        p[600:650, 0] = rng.choice([0.0, 1e-300, 1e-12, -1e-9], 50)  # starts near x = 0
        p[650:700, 1] = rng.choice([0.0, 1e-300, 1e-12, -1e-9], 50)  # and y = 0
    return p, chart_velocity(name, p, e), L


def flow_error(name, x, x_ref):
    """The metric length at the reference of the difference, and the floor float64 puts under
    it there: the metric length of the coordinates' rounding."""
    err = metric_norm(name, x_ref, x - x_ref)
    floor = metric_norm(name, x_ref, np.finfo(float).eps * np.abs(x_ref))
    return err, floor


@pytest.mark.parametrize("name", ["Nil", "Sol"])
def test_cpp_flow_matches_python_reference(name):
    """thurston_core.geodesic_flow against the Python reference geodesic on 1000 rays: the
    positions agree to within 1e-11 in the metric, or to a few units of the coordinates'
    rounding where float64 cannot resolve 1e-11 (Sol far from z = 0: a unit of the last place
    of x is e^z times longer there); velocities likewise; nothing is NaN or inf."""
    g = get(name)
    rng = np.random.default_rng(11 if name == "Nil" else 12)
    p, v, L = flow_cases(name, rng)
    xc, vc = thurston_core.geodesic_flow(name, np.ascontiguousarray(p), np.ascontiguousarray(v), L)
    assert np.all(np.isfinite(xc)) and np.all(np.isfinite(vc))
    X, V = g.geodesic(g.to_model(p), np.c_[v, np.zeros(len(v))], L)
    assert np.all(np.isfinite(X)) and np.all(np.isfinite(V))
    err, floor = flow_error(name, xc, X[:, :3])
    verr = metric_norm(name, X[:, :3], vc - V[:, :3])
    speed = metric_norm(name, xc, vc)
    bound = 1e-11 + 8 * floor
    report(
        f"{name}: C++ flow vs Python reference, 1000 rays",
        ["max err", "median", "max err/bnd", "max verr", "max |1-|v||"],
        [[err.max(), float(np.median(err)), (err / bound).max(), verr.max(), np.abs(speed - 1).max()]],
    )
    worst = int(np.argmax(err / bound))
    assert np.all(err <= bound), (p[worst], v[worst], L[worst], err[worst], floor[worst])
    assert np.all(verr <= 1e-11 + 8 * floor), verr.max()
    assert np.all(np.abs(speed - 1) < 1e-12)


def dop853_cases(name, rng):
    """About 40 rays: random, and the extremes (Nil's w, Sol's axes, near-plane directions,
    |z| = 20)."""
    cases = []
    if name == "Nil":
        for w in NIL_W:
            for sign in (1, -1):
                a = rng.uniform(0, 2 * np.pi)
                c = math.sqrt(1 - w * w)
                p = rng.uniform(-1.5, 1.5, 3)
                cases.append((p, chart_velocity(name, p, [c * math.cos(a), c * math.sin(a), sign * w]), 8.0))
        for _ in range(20):
            p = rng.uniform(-3, 3, 3)
            cases.append((p, chart_velocity(name, p, unit_rows(rng, 1)[0]), rng.uniform(1, 12)))
    else:
        for z in (0.0, 20.0, -20.0):
            for e in ([1, 0, 0], [0, -1, 0], [0, 0, 1], [1e-9, 0.6, 0.8], [0.6, -1e-12, -0.8], [0.6, 0.8, 0.0]):
                p = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), z])
                cases.append((p, chart_velocity(name, p, np.asarray(e) / np.linalg.norm(e)), 6.0))
        for _ in range(20):
            p = rng.uniform(-1.5, 1.5, 3)
            cases.append((p, chart_velocity(name, p, unit_rows(rng, 1)[0]), rng.uniform(1, 8)))
    return cases


@pytest.mark.slow
@pytest.mark.parametrize("name", ["Nil", "Sol"])
def test_flows_match_dop853_of_the_geodesic_equation(name):
    """Both flows against DOP853 of the geodesic equation from the truth metric's Christoffel
    symbols: the same rays reach the same points (to the integration's own accuracy, ~1e-10 in
    the metric over these lengths) and the same velocities."""
    g = get(name)
    rng = np.random.default_rng(21 if name == "Nil" else 22)
    rows = []
    for p, v, L in dop853_cases(name, rng):
        scale = [1.0, 1.0, 1.0] if name == "Nil" else [math.exp(-p[2]), math.exp(p[2]), 1.0]
        xt, vt = dop853(name, p, v, L, scale)
        xc, vc = thurston_core.geodesic_flow(name, p[None].copy(), v[None].copy(), np.array([L]))
        X, V = g.geodesic(g.to_model(p), np.append(v, 0.0), L)
        for label, x, u in (("C++", xc[0], vc[0]), ("Python", X[:3], V[:3])):
            assert np.all(np.isfinite(x)) and np.all(np.isfinite(u))
            err, floor = flow_error(name, x[None], xt[None])
            verr = metric_norm(name, xt[None], (u - vt)[None])
            rows.append((label, float(err[0]), float(floor[0]), float(verr[0])))
            assert err[0] <= 1e-9 + 1e3 * floor[0], (label, p, v, L, x, xt)
            assert verr[0] <= 1e-9 + 1e3 * floor[0], (label, p, v, L, u, vt)
    rows = np.array([r[1:] for r in rows]).reshape(-1, 2, 3)  # ray, (C++, Python), (err, floor, verr)
    resolved = rows[:, 0, 1] < 1e-12  # where float64 resolves 1e-12 in the metric
    report(
        f"{name}: flows vs DOP853 (1e-12), {len(rows)} rays (err: metric distance; floor: the coordinates' rounding)",
        ["C++ max", "Python max", "C++ max/flr", "Py max/flr", "C++ vmax", "Python vmax"],
        [
            [
                rows[resolved, 0, 0].max(),
                rows[resolved, 1, 0].max(),
                (rows[~resolved, 0, 0] / rows[~resolved, 0, 1]).max(),
                (rows[~resolved, 1, 0] / rows[~resolved, 1, 1]).max(),
                rows[:, 0, 2].max(),
                rows[:, 1, 2].max(),
            ]
        ]
        if (~resolved).any()
        else [[rows[:, 0, 0].max(), rows[:, 1, 0].max(), 0.0, 0.0, rows[:, 0, 2].max(), rows[:, 1, 2].max()]],
    )


# --- 2. across many crossings: the traced end against the cover geodesic reduced ----------------

# geodesic lengths giving about 1, 10, 100 and 1000 face crossings, and the rays traced at each
CROSSING_LEVELS = [(0.7, 200), (6.0, 200), (60.0, 200), (650.0, 48)]
PERTURBATION = 1e-8


def reference_end(space, X, V, L):
    """The end of the reference geodesic (Python, in the universal cover: Nil's closed form in
    extended precision, Sol's integrator in float64, whose own error here is below 2e-10) after
    L from (X, V), reduced into the domain."""
    g = space.geometry
    dtype = ld if space.id == "nil" else float
    Y, _ = g.geodesic(np.asarray(X, dtype), np.asarray(V, dtype), np.full(len(X), L, dtype))
    return np.asarray(into_domain(space, Y)[0][:, :3], ld)


def conditioning(space, X, V, L, end, rng, draws=3):
    """How much the reduced end moves per unit of a perturbation of the start (position and
    direction, random unit 6-vectors, the largest of `draws`): the factor by which any error
    made on the way can grow."""
    g = space.geometry
    kappa = np.zeros(len(X))
    for _ in range(draws):
        d = rng.normal(size=(len(X), 6))
        d *= PERTURBATION / np.linalg.norm(d, axis=1)[:, None]
        Xp = np.asarray(X, ld).copy()
        Xp[:, :3] += d[:, :3]
        Vp = np.asarray(V, ld).copy()
        Vp[:, :3] += d[:, 3:]
        Vp = g.normalize_tangent(Xp, Vp)
        moved = reference_end(space, Xp, Vp, L)
        kappa = np.maximum(kappa, image_distance(space, np.asarray(end, float), moved) / PERTURBATION)
    return kappa


_crossing_runs = {}


def crossing_run(space, L, n):
    """Rays from random points of the domain in random directions, traced for L with an empty
    scene (tolerance 1e-6), and their reference ends: (out, err, kappa)."""
    key = (space.id, L)
    if key not in _crossing_runs:
        g = space.geometry
        rng = np.random.default_rng(int(31 + L))
        x = interior_points(space, rng, n)
        X = g.to_model(x)
        V = g.normalize_tangent(X, g.tangent_to_model(x, chart_velocity(g.name, x, unit_rows(rng, n))))
        out = trace(empty_tracer(space), X, V, L)
        end = reference_end(space, X, V, L)
        err = image_distance(space, out["end"], end)
        kappa = conditioning(space, X, V, L, out["end"], rng)
        _crossing_runs[key] = (out, err, kappa)
    return _crossing_runs[key]


def conditioned_bound(sid, kappa, crossings, tolerance=TOLERANCE):
    """What the conditioning makes of the per-step errors the walk allows itself, four times:
    up to 3e-13 at each crossing (the nudge off the face, kOnFace in march.hpp, and roundings),
    and for Sol 0.05 * tolerance for each stretch of flow (the integrator's accuracy relative
    to the tolerance; Nil's closed form is exact to rounding)."""
    flow = 0.05 * tolerance if sid == "sol" else 0.0
    return 4 * kappa * (crossings + 1) * (3e-13 + flow)


@pytest.mark.slow
@pytest.mark.parametrize("sid", ["nil", "sol"])
def test_empty_space_ends_where_the_cover_geodesic_ends(space_of, sid):
    """A ray through an empty scene stops at max_distance L (stop 1) at the point where the
    reference geodesic from its start ends in the universal cover, reduced into the domain: for
    1 to ~1000 crossings, within what the conditioning of the geodesic makes of the walk's
    per-step errors (this is the check that crossings carry rays correctly however many there
    are; test_..._within_the_tolerance asks for the tolerance itself)."""
    space = space_of(sid)
    rows = []
    for L, n in CROSSING_LEVELS:
        out, err, kappa = crossing_run(space, L, n)
        c = out["crossings"]
        assert np.all(out["stop"] == 1), np.bincount(out["stop"])
        assert np.allclose(out["distance"], L)
        assert np.all(np.isfinite(out["end"]))
        assert np.all(space.domain.contains(space.geometry.to_model(out["end"]), tol=1e-9))
        ratio = err / conditioned_bound(sid, kappa, c)
        rows.append(
            [
                L,
                int(c.min()),
                float(c.mean()),
                int(c.max()),
                err.max(),
                float(np.median(err)),
                float(np.quantile(err, 0.9)),
                float(np.median(kappa)),
                kappa.max(),
                ratio.max(),
            ]
        )
        worst = int(np.argmax(ratio))
        assert np.all(ratio <= 1), (L, err[worst], kappa[worst], c[worst])
    report(
        f"{sid}: traced end vs reduced cover geodesic (empty scene, tolerance {TOLERANCE:g})",
        [
            "length",
            "min cross",
            "mean cross",
            "max cross",
            "max err",
            "median err",
            "p90 err",
            "median kappa",
            "max kappa",
            "max err/bnd",
        ],
        rows,
    )
    assert rows[-1][1] >= 500 and rows[-1][2] >= 900, "the last level makes about 1000 crossings"


@pytest.mark.parametrize(
    "sid, L", [("nil", 0.7), ("nil", 6.0), ("nil", 60.0), ("nil", 650.0), ("sol", 0.7), ("sol", 6.0)]
)
def test_empty_space_ends_within_the_tolerance(space_of, sid, L):
    """The end of a miss is within the tolerance of the reference end, however many crossings,
    where the geodesics do not amplify the flow's errors beyond it. (Sol's do: nearby geodesics
    separate like e^t, so over 60 and 650 its flow's errors of tolerance / 20 per stretch grow to
    1.6e-5 and 6.5e-4 at tolerance 1e-6; test_empty_space_ends_where_the_cover_geodesic_ends
    bounds them by the conditioning, as the per-ray error estimate does.)"""
    space = space_of(sid)
    out, err, _ = crossing_run(space, L, dict(CROSSING_LEVELS)[L])
    assert err.max() <= TOLERANCE, f"max error {err.max():.3g} after {out['crossings'].mean():.0f} crossings"


# --- 3. depth against the first hit of the reference geodesic on the lattice copies of spheres --

SPHERE_RADIUS = 0.1
SPHERE_SUBDIVISIONS = 4
# sphere centres: Nil in chart coordinates, Sol as (s, t, z) with (x, y) = s u1 + t u2; each at
# least 0.12 inside every face
SPHERE_CENTRES = {
    "nil": [(0.25, 0.2, 0.1), (-0.22, -0.25, -0.2), (0.1, -0.26, 0.26)],
    "sol": [(0.25, 0.2, 0.1), (-0.22, -0.25, -0.2), (0.1, -0.26, 0.24)],
}
HIT_LENGTH = 6.0
HIT_RAYS = 400
COARSE_STEP = 0.01  # pieces of the reference curve: sagitta ~ K h^2 / 8 ~ 1e-5
FINE_PIECES = 64  # the hit piece again in 64: sagitta ~ 3e-9
GRAZE = 2e-3  # rays passing this close to a sphere they do not enter are left out
APPROACH = 20  # pieces before a hit that belong to its approach


def sphere_centres(sid):
    c = np.array(SPHERE_CENTRES[sid], float)
    if sid == "sol":
        u1, u2 = np.asarray(SOL_U1, float), np.asarray(SOL_U2, float)
        c = np.c_[c[:, :1] * u1 + c[:, 1:2] * u2, c[:, 2]]
    return c


def segment_hits(A, B, tri):
    """Moeller-Trumbore: the parameter u in [0, 1] at which the segments A -> B (P, 3) first
    meet the triangles tri (K, 3, 3), (P, K), inf where they do not."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    D = B - A
    h = np.cross(D[:, None, :], e2[None])
    a = np.einsum("kj,pkj->pk", e1, h)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = 1.0 / a
        s = A[:, None, :] - tri[None, :, 0]
        u = f * np.einsum("pkj,pkj->pk", s, h)
        q = np.cross(s, e1[None])
        v = f * np.einsum("pj,pkj->pk", D, q)
        t = f * np.einsum("kj,pkj->pk", e2, q)
    ok = (np.abs(a) > 1e-300) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)
    return np.where(ok, t, np.inf)


def segment_distance(A, B, c):
    """Distance from the points c (K, 3) to the segments A -> B (P, 3): (P, K)."""
    D = B - A
    w = c[None] - A[:, None, :]
    s = np.clip(np.einsum("pj,pkj->pk", D, w) / np.maximum(np.einsum("pj,pj->p", D, D), 1e-300)[:, None], 0, 1)
    return np.linalg.norm(w - s[..., None] * D[:, None, :], axis=-1)


class SphereWorld:
    """The spheres of a space, their copies near the domain (chart meshes g(sphere)), the tracer
    of the scene, the rays and their true first hits."""

    def __init__(self, space):
        self.space = space
        g = self.g = space.geometry
        mesh = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=SPHERE_RADIUS)
        self.centres = sphere_centres(space.id)
        self.objects = [
            SceneObject(f"ball{i}", mesh.vertices + c, mesh.faces, (0.5, 0.6, 0.7)) for i, c in enumerate(self.centres)
        ]
        # copies g(sphere), g around the domain, that reach near it
        lo, hi = space.domain.vertices.min(0) - 0.05, space.domain.vertices.max(0) + 0.05
        self.copies = []  # (object, centre, inner radius, outer radius, triangles (K, 3, 3))
        for i, obj in enumerate(self.objects):
            for N in space.neighbourhood(1):
                V = g.transform_points(N, obj.vertices)
                if np.any(V.max(0) < lo) or np.any(V.min(0) > hi):
                    continue
                tri = V[obj.triangles]
                centre = g.transform_points(N, self.centres[i])
                n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
                n /= np.linalg.norm(n, axis=1)[:, None]
                inner = np.min(np.abs(np.einsum("kj,kj->k", n, tri[:, 0] - centre)))
                outer = np.max(np.linalg.norm(V - centre, axis=1))
                self.copies.append((i, centre, inner, outer, tri))
        self.scene = Scene(objects=self.objects)
        self.tracer = render.make_tracer(space, self.scene)
        rng = np.random.default_rng(41 if space.id == "nil" else 42)
        x = interior_points(space, rng, HIT_RAYS, avoid=self.centres, avoid_radius=SPHERE_RADIUS + 0.05)
        self.P = g.to_model(x)
        self.V = g.normalize_tangent(self.P, g.tangent_to_model(x, chart_velocity(g.name, x, unit_rows(rng, HIT_RAYS))))
        self._truth()

    def _curve(self, rows, t):
        """The reference geodesic of the rays `rows` at arclengths t (len(rows), m): model
        points and velocities in the cover."""
        P = np.repeat(self.P[rows], t.shape[1], axis=0)
        V = np.repeat(self.V[rows], t.shape[1], axis=0)
        return self.g.geodesic(P, V, t.ravel())

    def _truth(self):
        """First hits of the reference curves: straight pieces of COARSE_STEP, each carried into
        the domain by the isometry that brings its start there; the pieces that cross the shell
        of a copy are tested against its triangles; the first piece that hits is cut into
        FINE_PIECES and tested again against the triangles near the coarse hit."""
        n, space = len(self.P), self.space
        m = int(round(HIT_LENGTH / COARSE_STEP))
        t = np.broadcast_to(np.linspace(0.0, HIT_LENGTH, m + 1), (n, m + 1))
        Y, _ = self._curve(np.arange(n), t)
        _, _, M = into_domain(space, Y[np.arange(n * (m + 1)).reshape(n, m + 1)[:, :-1].ravel()])
        M = np.asarray(M, float).reshape(n, m, 4, 4)
        Y = Y.reshape(n, m + 1, 4)
        A = np.einsum("nkij,nkj->nki", M, Y[:, :-1])[..., :3]
        B = np.einsum("nkij,nkj->nki", M, Y[:, 1:])[..., :3]
        A, B = A.reshape(-1, 3), B.reshape(-1, 3)
        centres = np.array([c[1] for c in self.copies])
        dist = segment_distance(A, B, centres).reshape(n, m, -1)  # piece to copy centre
        first = np.full(n, m)  # the first piece that hits
        first_u = np.full(n, np.inf)
        first_copy = np.full(n, -1)
        for k, (_, centre, inner, outer, tri) in enumerate(self.copies):
            far = np.maximum(np.linalg.norm(A - centre, axis=1), np.linalg.norm(B - centre, axis=1))
            cand = np.flatnonzero((dist.reshape(-1, len(self.copies))[:, k] <= outer) & (far >= inner))
            if not len(cand):
                continue
            u = segment_hits(A[cand], B[cand], tri).min(axis=1)
            hit = cand[np.isfinite(u)][::-1]  # latest pieces first: the earliest is written last
            u = u[np.isfinite(u)][::-1]
            ray, piece = hit // m, hit % m
            better = piece < first[ray]
            first[ray[better]] = piece[better]
            first_u[ray[better]] = u[better]
            first_copy[ray[better]] = k
        hit_rays = np.flatnonzero(first < m)
        # near-grazing: before its first hit, a ray passes within GRAZE of the shell of a copy
        # (of the copy it hits: earlier than APPROACH pieces before, which for a cosine of
        # incidence > 0.3 are farther than that from its shell)
        outer = np.array([c[3] for c in self.copies])
        pieces = np.arange(m)
        before = pieces[None, :, None] < first[:, None, None] - np.where(
            np.arange(len(self.copies))[None, None, :] == first_copy[:, None, None], APPROACH, 0
        )
        close = dist <= outer[None, None, :] + GRAZE
        self.grazing = np.any(close & before, axis=(1, 2))
        # fine pass over the hit piece
        self.hit = np.zeros(n, bool)
        self.depth = np.full(n, np.inf)
        self.point = np.full((n, 3), np.nan)
        self.cosine = np.full(n, np.nan)
        self.object = np.full(n, -1)
        if not len(hit_rays):
            return
        k0 = first[hit_rays]
        s = (k0[:, None] + np.linspace(0, 1, FINE_PIECES + 1)[None, :]) * COARSE_STEP
        Yf, Vf = self._curve(hit_rays, s)
        Mk = M[hit_rays, k0]
        Yf = np.einsum("nij,nkj->nki", Mk, Yf.reshape(len(hit_rays), -1, 4))[..., :3]
        Vf = np.einsum("nij,nkj->nki", Mk, Vf.reshape(len(hit_rays), -1, 4))[..., :3]
        for j, ray in enumerate(hit_rays):
            obj, centre, _, _, tri = self.copies[first_copy[ray]]
            coarse = A[ray * m + k0[j]] + first_u[ray] * (B[ray * m + k0[j]] - A[ray * m + k0[j]])
            near = tri[np.linalg.norm(tri.mean(axis=1) - coarse, axis=1) < 0.02]
            u = segment_hits(Yf[j, :-1], Yf[j, 1:], near)
            piece, which = np.unravel_index(np.argmin(u), u.shape)
            if not np.isfinite(u[piece, which]):  # the curve itself misses: grazing
                self.grazing[ray] = True
                continue
            uu = u[piece, which]
            self.hit[ray] = True
            self.object[ray] = obj
            self.depth[ray] = s[j, piece] + uu * (s[j, piece + 1] - s[j, piece])
            x = Yf[j, piece] + uu * (Yf[j, piece + 1] - Yf[j, piece])
            self.point[ray] = x
            normal = np.cross(near[which, 1] - near[which, 0], near[which, 2] - near[which, 0])
            v = Vf[j, piece] + uu * (Vf[j, piece + 1] - Vf[j, piece])
            ginv = np.linalg.inv(METRIC[self.g.name](x))
            self.cosine[ray] = (
                abs(normal @ v) / math.sqrt(normal @ ginv @ normal) / math.sqrt(v @ METRIC[self.g.name](x) @ v)
            )

    def compared(self):
        """Rays whose true first hit is well inside a sphere's silhouette (cosine of incidence
        > 0.3, before HIT_LENGTH - 0.01, no near graze before it), and rays that pass every copy
        by more than GRAZE."""
        hits = self.hit & ~self.grazing & (self.cosine > 0.3) & (self.depth < HIT_LENGTH - 0.01)
        misses = ~self.hit & ~self.grazing
        return hits, misses

    def trace(self, tolerance):
        return trace(self.tracer, self.P, self.V, HIT_LENGTH, tolerance=tolerance)


_worlds = {}


def sphere_world(space):
    if space.id not in _worlds:
        _worlds[space.id] = SphereWorld(space)
    return _worlds[space.id]


def stopped_at_chord_end(tracer, P, V, rows, length, tolerance):
    """Which of the hit rays `rows` report as their hit point an end of one of their own chords
    (within 1e-9; traced again one by one with record_segments): what the hit refinement did
    when find_root returned an end of its bracket instead of the root (fixed in 9ede661; see
    test_hit_refinement_finds_the_plane_on_straight_rays)."""
    flags = np.zeros(len(rows), bool)
    for k, i in enumerate(rows):
        out = tracer.trace(
            np.ascontiguousarray(P[i : i + 1]),
            np.ascontiguousarray(V[i : i + 1]),
            float(length),
            100000,
            shade=False,
            tolerance=tolerance,
            record_segments=True,
        )
        ends = np.concatenate([out["segment_starts"], out["segment_ends"]])
        flags[k] = out["stop"][0] == 0 and np.min(np.linalg.norm(ends - out["position"][0], axis=1)) < 1e-9
    return flags


def assert_within(world, rows, err, bound, tolerance, label):
    """err <= bound on the compared rays `rows`; a failure says how many of the rays beyond the
    bound stopped at an end of their own chord (the signature of a refinement that did not
    refine)."""
    failing = np.flatnonzero(err > bound)
    if len(failing):
        at_end = stopped_at_chord_end(world.tracer, world.P, world.V, rows[failing], HIT_LENGTH, tolerance)
        worst = failing[np.argmax(err[failing] / bound[failing])]
        raise AssertionError(
            f"{label}: {len(failing)} rays beyond the bound ({int(at_end.sum())} of them hit at an "
            f"end of their own chord), worst ray {rows[worst]}: {err[worst]:.3g} > {bound[worst]:.3g}"
        )


@pytest.mark.slow
@pytest.mark.parametrize("sid", ["nil", "sol"])
def test_depth_matches_first_hit_of_the_reference_geodesic(space_of, sid):
    """Rays from random points of the domain, traced at tolerance 1e-6 through the scene of three
    spheres, hit the copy that the reference geodesic hits first (same object; no hit where the
    reference passes every copy), at its arclength and point: within 2 tolerance / cos of
    incidence (plus 1e-8 for the truth's own sagitta)."""
    world = sphere_world(space_of(sid))
    hits, misses = world.compared()
    assert hits.sum() >= 100 and misses.sum() >= 100, (hits.sum(), misses.sum())
    out = world.trace(TOLERANCE)
    assert np.all(out["stop"][hits] == 0), f"{np.sum(out['stop'][hits] != 0)} rays missed the sphere they hit"
    assert np.all(out["object"][hits] == world.object[hits])
    assert np.all(out["stop"][misses] == 1), np.bincount(out["stop"][misses])
    assert np.all(np.isinf(out["depth"][misses])) and np.all(np.isnan(out["error"][misses]))
    rows = np.flatnonzero(hits)
    depth_err = np.abs(out["depth"][rows] - world.depth[rows])
    pos_err = image_distance(world.space, out["position"][rows], world.point[rows])
    bound = (2 * TOLERANCE + 1e-8) / world.cosine[rows]
    c = out["crossings"][rows]
    table = []
    for lo, hi in ((0, 1), (1, 5), (5, 100)):
        sel = (c >= lo) & (c < hi)
        if sel.any():
            table.append(
                [
                    f"{lo}-{hi - 1}",
                    int(sel.sum()),
                    depth_err[sel].max(),
                    float(np.median(depth_err[sel])),
                    pos_err[sel].max(),
                    (depth_err[sel] / bound[sel]).max(),
                ]
            )
    report(
        f"{sid}: depth vs first hit of the reference, tolerance {TOLERANCE:g} ({hits.sum()} hits, {misses.sum()} "
        "misses)",
        ["crossings", "rays", "max depth err", "median", "max pos err", "max err/bnd"],
        table,
    )
    assert_within(world, rows, depth_err, bound, TOLERANCE, "depth")
    assert_within(world, rows, pos_err, bound, TOLERANCE, "position")


@pytest.mark.parametrize("sid", ["nil", "sol"])
def test_tolerance_trades_chords_for_error(space_of, sid):
    """The same rays at tolerance 1e-2 and 1e-6: the Embree queries rise, and the per-ray estimate
    `error` bounds the measured hit-position error (against the reference's first hit) of every ray
    that hits the reference's object at both tolerances (and so does 2 tolerance / cos of
    incidence). The hit is refined on the curve onto the triangle the curve meets (a neighbour of
    the chord's where the curve meets the chord's triangle's plane outside it), so most coarse hits
    are as accurate as the fine ones (Nil: to the reference's own 1e-9), and the worst falls by
    orders of magnitude with the tolerance (Sol's curve is integrated to 1/20 of it)."""
    world = sphere_world(space_of(sid))
    hits, _ = world.compared()
    runs = {t: world.trace(t) for t in (1e-2, 1e-6)}
    same = hits.copy()
    for out in runs.values():
        same &= (out["stop"] == 0) & (out["object"] == world.object)
    rows = np.flatnonzero(same)
    assert len(rows) >= 0.9 * hits.sum()
    table, measured = [], {}
    for t, out in runs.items():
        err = image_distance(world.space, out["position"][rows], world.point[rows])
        estimate = out["error"][rows]
        assert np.all(np.isfinite(estimate)) and np.all(estimate > 0)
        measured[t] = err
        table.append(
            [
                t,
                int(out["ray_chords"].sum()),
                float(np.median(err)),
                float(np.quantile(err, 0.9)),
                err.max(),
                float(np.median(estimate)),
                (err / estimate).max(),
            ]
        )
        assert_within(world, rows, err, estimate, t, f"tolerance {t:g}: measured error vs the estimate")
        assert_within(world, rows, err, (2 * t + 1e-8) / world.cosine[rows], t, f"tolerance {t:g}: 2 tol / cos")
    report(
        f"{sid}: tolerance vs error ({len(rows)} rays hitting the same object)",
        ["tolerance", "chords", "median err", "p90 err", "max err", "median est", "max err/est"],
        table,
    )
    coarse, fine = runs[1e-2], runs[1e-6]
    assert fine["ray_chords"].sum() > 3 * coarse["ray_chords"].sum()
    assert np.all(fine["ray_chords"][rows] >= coarse["ray_chords"][rows] - 2)
    assert np.median(measured[1e-6]) <= np.median(measured[1e-2]) + 1e-12
    assert measured[1e-6].max() < 1e-2 * measured[1e-2].max()


@pytest.mark.parametrize("geometry", ["Nil", "Sol"])
def test_hit_refinement_finds_the_plane_on_straight_rays(geometry):
    """Vertical rays (x, y) = 0, z = z0 + t are geodesics of both metrics (Nil's fibre; Sol's z
    axis), traced without a domain to a horizontal triangle at z = 0.2: the depth is 0.2 - z0
    exactly. Both windings of the triangle (f0 > 0 and f0 < 0), three triangle sizes (the side
    function is on the unnormalised plane). Before 9ede661, find_root left its loop on
    |f| < 1e-15 and returned the bracket's far end, not the root: up to 136 of 200 rays here were
    off by up to a chord (0.95)."""
    worst = []
    for size in (1e-2, 1e-3, 1e-4):
        for winding in (1, -1):
            tri = np.array([[-size, -size, 0.2], [size, -size, 0.2], [0.0, size, 0.2]])[::winding]
            tracer = thurston_core.Tracer(
                thurston_core.Scene(
                    geometry,
                    thurston_core.Domain(np.zeros((0, 4)), np.zeros((0, 4, 4))),
                    thurston_core.Meshes(
                        np.ascontiguousarray(tri), np.array([[0, 1, 2]], np.int32), np.zeros(1, np.int32)
                    ),
                    thurston_core.Surfaces(np.ones((1, 3), np.float32), np.zeros((1, 3), np.float32)),
                    thurston_core.Lights(np.zeros((0, 4)), np.zeros(0, np.int32), np.zeros((0, 3), np.float32)),
                )
            )
            z0 = np.linspace(0.0, 0.15, 200)
            O = np.c_[np.zeros((200, 2)), z0, np.ones(200)]
            D = np.tile([0.0, 0.0, 1.0, 0.0], (200, 1))
            out = tracer.trace(O, D, 1.0, 0, shade=False, tolerance=TOLERANCE)
            assert np.all(out["stop"] == 0)
            err = np.abs(out["depth"] - (0.2 - z0))
            worst.append((size, winding, int((err > TOLERANCE).sum()), err.max()))
    report(
        f"{geometry}: vertical rays to a triangle at z = 0.2 (200 rays each)",
        ["size", "winding", "off > tol", "max err"],
        worst,
    )
    assert all(w[3] <= 1e-12 for w in worst), worst


# --- 5. extremes: Nil's vertical components, Sol's axes, planes and far starts -----------------


def traced_against_reference(space, X, V, L, tolerance=TOLERANCE, rng=None):
    """(out, err, kappa, ratio to the conditioned bound) for rays (X, V) traced for L through the
    empty scene, against the reduced reference end."""
    out = trace(empty_tracer(space), X, V, L, tolerance=tolerance)
    assert np.all(np.isfinite(out["end"])) and np.all(out["stop"] == 1), np.bincount(out["stop"])
    assert np.all(space.domain.contains(space.geometry.to_model(out["end"]), tol=1e-9))
    end = reference_end(space, X, V, L)
    err = image_distance(space, out["end"], end)
    kappa = conditioning(space, X, V, L, out["end"], rng or np.random.default_rng(0))
    return out, err, kappa, err / conditioned_bound(space.id, kappa, out["crossings"], tolerance)


_nil_w_runs = {}


def nil_w_run(space, w, L):
    """40 Nil rays with vertical component +-w from random points, traced for L: (out, err, kappa,
    ratio to the conditioned bound)."""
    if (w, L) not in _nil_w_runs:
        rng = np.random.default_rng(51)
        n = 40
        x = interior_points(space, rng, n)
        a = rng.uniform(0, 2 * np.pi, n)
        c = math.sqrt(1 - w * w)
        e = np.stack([c * np.cos(a), c * np.sin(a), np.where(np.arange(n) % 2 == 0, w, -w)], -1)
        X, V = space.geometry.to_model(x), np.c_[chart_velocity("Nil", x, e), np.zeros(n)]
        _nil_w_runs[w, L] = traced_against_reference(space, X, V, L, rng=rng)
    return _nil_w_runs[w, L]


@pytest.mark.parametrize("w", NIL_W)
def test_nil_vertical_components_through_the_space(space_of, w):
    """Nil rays whose vertical component (in the orthonormal frame) is w = 0, 1e-300, 1e-12, 1e-6
    (horizontal) or 1 (the fibre), from random points, for ~100 and ~1000 crossings: no NaN,
    the reference's end within the tolerance after ~100 crossings and within the conditioned
    bound after ~1000 (horizontal rays are the worst conditioned: kappa ~ 5e7 at L = 650)."""
    space = space_of("nil")
    rows = []
    for L in (100.0, 1000.0) if w == 1 else (70.0, 650.0):
        out, err, kappa, ratio = nil_w_run(space, w, L)
        rows.append(
            [
                w,
                L,
                int(out["crossings"].min()),
                int(out["crossings"].max()),
                err.max(),
                float(np.median(err)),
                kappa.max(),
                ratio.max(),
            ]
        )
        assert np.all(ratio <= 1), ratio.max()
        if L < 200:
            assert err.max() <= TOLERANCE
    report(
        "nil: rays with vertical component w",
        ["w", "length", "min cross", "max cross", "max err", "median err", "max kappa", "max err/bnd"],
        rows,
    )


def test_nil_horizontal_rays_within_the_tolerance_after_1000_crossings(space_of):
    out, err, _, _ = nil_w_run(space_of("nil"), 0.0, 650.0)
    assert out["crossings"].min() >= 650
    assert err.max() <= TOLERANCE, err.max()


def sol_cases(rng):
    """(label, chart starts, frame directions, length, tolerance) of the Sol extremes."""
    space_rng = np.random.default_rng(rng.integers(1 << 30))
    axes = np.repeat(np.concatenate([np.eye(3), -np.eye(3)]), 6, axis=0)
    near = []
    for tiny in (1e-300, 1e-12, 1e-9, 1e-6):
        for k in (0, 1):  # p_x (k = 0) or p_y (k = 1) tiny: near the planes x = const, y = const
            for _ in range(4):
                d = unit_rows(space_rng, 1)[0]
                d[k] = tiny * np.sign(d[k])
                near.append(d / np.linalg.norm(d))
    return [
        ("axes", axes, 3.0, 1e-9),
        ("axes", axes, 10.0, TOLERANCE),
        ("near planes", np.array(near), 10.0, TOLERANCE),
        ("starts near x=0, y=0", None, 60.0, TOLERANCE),
    ]


def test_sol_axes_and_planes_through_the_space(space_of):
    """Sol rays along the frame's axes (p_x = 0 or p_y = 0: geodesics of the hyperbolic planes
    x = const, y = const, which separate like e^t), near those planes (p_x or p_y = 1e-300 ...
    1e-6), and from points on and near the planes x = 0, y = 0: no NaN, within the conditioned
    bound; the axes within 1e-9 after 3 units at tolerance 1e-9."""
    space = space_of("sol")
    g = space.geometry
    rng = np.random.default_rng(52)
    rows = []
    for label, e, L, tolerance in sol_cases(rng):
        if e is None:
            n = 32
            x = interior_points(space, rng, n)
            x[:16, 0] = rng.choice([0.0, 1e-300, 1e-12, -1e-9], 16)
            x[16:, 1] = rng.choice([0.0, 1e-300, 1e-12, -1e-9], 16)
            e = unit_rows(rng, n)
        else:
            x = interior_points(space, rng, len(e))
        X = g.to_model(x)
        V = g.normalize_tangent(X, np.c_[chart_velocity("Sol", x, e), np.zeros(len(x))])
        out, err, kappa, ratio = traced_against_reference(space, X, V, L, tolerance, rng)
        rows.append(
            [
                label,
                L,
                tolerance,
                int(out["crossings"].max()),
                err.max(),
                float(np.median(err)),
                kappa.max(),
                ratio.max(),
            ]
        )
        assert np.all(ratio <= 1), (label, ratio.max())
        if L <= 3:
            assert err.max() <= tolerance, (label, err.max())
    report(
        "sol: axes, planes",
        ["rays", "length", "tolerance", "max cross", "max err", "median err", "max kappa", "max err/bnd"],
        rows,
    )


def test_sol_vertical_ray_on_the_axis_makes_1000_crossings_exactly(space_of):
    """x = y = 0, z = z0 + t is a geodesic, and the monodromy keeps the axis: after 1000 lid
    crossings (length 962) the ray is still exactly on it, at z0 + L reduced by the period."""
    space = space_of("sol")
    z0 = np.array([0.0, 0.1, -0.3, 0.45])
    X = np.c_[np.zeros((4, 2)), z0, np.ones(4)]
    V = np.tile([0.0, 0.0, 1.0, 0.0], (4, 1))
    V[2:] *= -1
    L = 962.0
    out = trace(empty_tracer(space), X, V, L)
    z = np.asarray(z0, ld) + np.where(V[:, 2] > 0, 1, -1) * ld(L)
    periods = np.floor(z / SOL_PERIOD + ld(0.5))  # lid crossings (999 or 1000)
    z -= SOL_PERIOD * periods
    assert np.all(out["stop"] == 1) and np.all(out["crossings"] == np.abs(periods).astype(int))
    assert np.all(out["end"][:, :2] == 0.0)
    err = np.abs(np.asarray(out["end"][:, 2] - z, float))
    report("sol: vertical rays on the axis", ["max err", "crossings"], [[err.max(), int(out["crossings"].max())]])
    assert err.max() <= 1e-9


def test_sol_far_starts_moved_inside(space_of):
    """Starts at z = +-20 moved into the domain by Space.move_inside first (as `thurston trace`
    does, float64), and in extended precision: the traced end agrees with the reference from
    the original point in the cover (extended precision) within the conditioned bound plus what
    the start's reduction lost (float64: up to ~7e-7 at |z| = 20, a unit of the last place of x
    times phi^42)."""
    space = space_of("sol")
    g = space.geometry
    rng = np.random.default_rng(53)
    n = 40
    x = np.c_[rng.uniform(-1, 1, (n, 2)), np.where(np.arange(n) % 2 == 0, 20.0, -20.0)]
    X = g.to_model(x)
    V = np.c_[chart_velocity("Sol", x, unit_rows(rng, n)), np.zeros(n)]
    Xe, Ve, _ = space.move_inside(X.astype(ld), V.astype(ld))
    X64, V64, _ = space.move_inside(X, V)
    lost = image_distance(space, np.asarray(X64[:, :3], float), Xe[:, :3])
    assert np.all(np.isfinite(X64)) and np.all(np.isfinite(V64)) and lost.max() <= 1e-6
    rows = []
    for L in (1.0, 10.0):
        Y, _ = g.geodesic(X.astype(ld), V.astype(ld), np.full(n, L, ld))
        end = np.asarray(into_domain(space, Y)[0][:, :3], ld)
        Xs, Vs = np.asarray(Xe, float), np.asarray(Ve, float)
        kappa = conditioning(space, Xs, Vs, L, reference_end(space, Xs, Vs, L), rng)
        for label, (P, D), start in (("extended", (Xs, Vs), 1e-15), ("float64", (X64, V64), lost)):
            out = trace(empty_tracer(space), P, D, L)
            assert np.all(np.isfinite(out["end"])) and np.all(out["stop"] == 1)
            err = image_distance(space, out["end"], end)
            bound = conditioned_bound("sol", kappa, out["crossings"]) + 4 * kappa * start
            rows.append(
                [
                    label,
                    L,
                    int(out["crossings"].max()),
                    err.max(),
                    float(np.median(err)),
                    lost.max(),
                    (err / bound).max(),
                ]
            )
            assert np.all(err <= bound), (label, L, err.max())
    report(
        "sol: starts at |z| = 20 moved inside",
        ["reduction", "length", "max cross", "max err", "median err", "start lost", "max err/bnd"],
        rows,
    )


@pytest.mark.parametrize("flow", ["python", "cpp"])
def test_sol_flows_along_the_z_axis_stay_finite(flow):
    """The vertical geodesic (0, 0, t) over lengths 100 and 300: both flows give it exactly. (Past
    |z| ~ 354 e^{2z} leaves float64's range: there the flows give NaN; the tracer's points stay in
    the domain, |z| < 0.49.)"""
    L = np.array([100.0, 300.0])
    with np.errstate(over="ignore", invalid="ignore"):
        if flow == "python":
            X, _ = get("Sol").geodesic(np.array([0.0, 0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0, 0.0]), L)
            x = X[:, :3]
        else:
            x, _ = thurston_core.geodesic_flow("Sol", np.zeros((2, 3)), np.tile([0.0, 0.0, 1.0], (2, 1)), L)
    assert np.all(np.isfinite(x)), x
    assert np.allclose(x, np.c_[np.zeros((2, 2)), L], rtol=1e-14)


# --- 6. shading: a Lambert plane lit by a point light, with an occluder ---------------------------

PLANE_COLOR = np.array([0.8, 0.6, 0.4])
LIGHT_COLOR = np.array([1.0, 0.9, 0.8])
LIGHT_POWER = 0.7


def slab_frame(sid):
    """Chart axes (3, 3) in which the domain is |s|, |t| <= 1/2 (Sol: |z| <= ln phi): Nil the chart
    axes, Sol (u1, 0), (u2, 0), (0, 0, 1)."""
    if sid == "nil":
        return np.eye(3)
    u1, u2 = np.asarray(SOL_U1, float), np.asarray(SOL_U2, float)
    return np.array([[u1[0], u1[1], 0.0], [u2[0], u2[1], 0.0], [0.0, 0.0, 1.0]])


def rectangle(frame, s, t_range, z_range, name, color):
    """The rectangle {s} x t_range x z_range of the frame as a two-triangle object."""
    (t0, t1), (z0, z1) = t_range, z_range
    corners = np.array([[s, t0, z0], [s, t1, z0], [s, t1, z1], [s, t0, z1]]) @ frame
    return SceneObject(name, corners, [[0, 1, 2], [0, 2, 3]], color)


class LitPlane:
    """A plane s = 0.3 (|t|, |z| <= 0.45), a point light at s = -0.05 and, in between at s = 0.12,
    a rectangular occluder; rays from the light's side. The light reaches 0.6: the hits compared
    are lit by its nearest copy alone (all others of theirs lie beyond)."""

    OCCLUDER = (0.12, (0.05, 0.2), (-0.1, 0.1))
    LIGHT_REACH = 0.6

    def __init__(self, space, light_at=(-0.05, 0.05, 0.05), occluder=True, n=2500, seed=61, targets=None):
        g = self.g = space.geometry
        self.space = space
        F = self.frame = slab_frame(space.id)
        plane = rectangle(F, 0.3, (-0.45, 0.45), (-0.45, 0.45), "plane", PLANE_COLOR)
        objects = [plane]
        if occluder:
            s, tr, zr = self.OCCLUDER
            objects.append(rectangle(F, s, tr, zr, "occluder", (0.3, 0.3, 0.3)))
        self.objects = objects
        self.light = np.asarray(light_at, float) @ F
        scene = Scene(objects=objects, lights=[PointLight(self.light, LIGHT_COLOR, LIGHT_POWER)])
        self.tracer = render.make_tracer(space, scene, light_reach=self.LIGHT_REACH)
        rng = np.random.default_rng(seed)
        stz = np.c_[rng.uniform(-0.45, 0.0, n), rng.uniform(-0.45, 0.45, (n, 2))]
        x = stz @ F
        if targets is None:
            e = unit_rows(rng, n)
            v = chart_velocity(g.name, x, e)
            toward = (v @ F[0]) / np.linalg.norm(v, axis=1) > 0.2  # towards the plane
            self.P = g.to_model(x[toward])
            self.V = g.normalize_tangent(self.P, np.c_[v[toward], np.zeros(toward.sum())])
        else:  # aimed by the reference at points of the plane (s = 0.3, (t, z) within `targets`)
            aim = np.c_[np.full(n, 0.3), rng.uniform(-targets, targets, (n, 2))] @ F
            self.P = g.to_model(x)
            self.V, _, ok = g.connect(self.P, g.to_model(aim))
            self.P, self.V = self.P[ok], self.V[ok]

    def trace(self, length=3.0):
        return trace(self.tracer, self.P, self.V, length, shade=True)

    def hits_on_plane(self, out):
        """The hits on the plane; their points lie on it to rounding (the refinement's root)."""
        rows = np.flatnonzero((out["stop"] == 0) & (out["object"] == 0))
        off = np.abs(out["position"][rows] @ self.frame[0] - 0.3)
        assert off.max() <= 1e-12, f"a hit {off.max():.3g} off the plane"
        return rows, float(off.max())

    def expected(self, out, rows):
        """The independent colour of the hits `rows` on the plane: (colour, keep, occluded, r) with
        keep where the nearest light copy (by connect's length, among the four nearest in the
        chart) is the light itself by a clear margin and no connecting geodesic passes within
        2e-3 of the occluder's edges."""
        g, space = self.g, self.space
        H = g.to_model(out["position"][rows])
        # the ray's velocity at the hit: the reference geodesic at the traced depth, reduced
        Y, W = g.geodesic(self.P[rows], self.V[rows], out["depth"][rows])
        Xr, Wr, _ = into_domain(space, Y, W)
        assert image_distance(space, out["position"][rows], np.asarray(Xr[:, :3], float)).max() < 1e-5
        Wr = np.asarray(Wr, float)
        # metric unit normal of the plane s = 0.3, facing the ray
        n = self.frame[0]
        N = np.array([np.linalg.solve(METRIC[g.name](h), n) for h in H[:, :3]])
        N /= np.sqrt(N @ n)[:, None]
        facing = np.einsum("ni,nij,nj->n", N, np.array([METRIC[g.name](h) for h in H[:, :3]]), Wr[:, :3])
        N *= np.where(facing > 0, -1.0, 1.0)[:, None]
        # light copies: the four nearest in the chart, joined by connect
        L = np.array([M @ g.to_model(self.light) for M in space.neighbourhood(1)])
        chart = np.linalg.norm(L[None, :, :3] - H[:, None, :3], axis=2)
        nearest4 = np.argsort(chart, axis=1)[:, :4]
        Vc, rc, okc = g.connect(np.repeat(H, 4, axis=0), L[nearest4.ravel()])
        rc = np.where(okc, rc, np.inf).reshape(-1, 4)
        order = np.argsort(rc, axis=1)
        best = order[:, 0]
        r = rc[np.arange(len(rows)), best]
        r2 = rc[np.arange(len(rows)), order[:, 1]]
        Vl = Vc.reshape(-1, 4, 4)[np.arange(len(rows)), best]
        keep = (
            np.isfinite(r)
            & (r2 > 1.5 * r)
            & (r < self.LIGHT_REACH)
            & (r2 > 1.05 * self.LIGHT_REACH)
            & (nearest4[np.arange(len(rows)), best] == 0)
        )
        Vl = np.where(keep[:, None], Vl, np.array([1.0, 0, 0, 0]))
        r = np.where(keep, r, 0.5)
        cos = np.einsum("ni,nij,nj->n", N, np.array([METRIC[g.name](h) for h in H[:, :3]]), Vl[:, :3])
        falloff = g.falloff_along(H, Vl, r)
        occluded = np.zeros(len(rows), bool)
        if len(self.objects) > 1:
            # the connecting geodesic in 200 pieces against the occluder (and its copies)
            t = np.linspace(0, 1, 201)[None, :] * r[:, None]
            Yp, _ = g.geodesic(np.repeat(H, 201, axis=0), np.repeat(Vl, 201, axis=0), t.ravel())
            Yp = (Yp[:, :3] / Yp[:, 3:]).reshape(len(rows), 201, 3)
            s0, (t0, t1), (z0, z1) = self.OCCLUDER
            for M in space.neighbourhood(1):
                # the path in the copy's own frame: (s, t, z) of M^-1 applied to it
                Q = g.transform_points(np.linalg.inv(M), Yp.reshape(-1, 3)).reshape(Yp.shape) @ self.frame.T
                side = Q[..., 0] - s0
                cross = np.flatnonzero(np.any(np.sign(side[:, :-1]) != np.sign(side[:, 1:]), axis=1))
                for i in cross:
                    k = int(np.flatnonzero(np.sign(side[i, :-1]) != np.sign(side[i, 1:]))[0])
                    u = side[i, k] / (side[i, k] - side[i, k + 1])
                    _, tt, zz = Q[i, k] + u * (Q[i, k + 1] - Q[i, k])
                    margin = min(tt - t0, t1 - tt, zz - z0, z1 - zz)
                    if abs(margin) < 2e-3:
                        keep[i] = False
                    occluded[i] |= margin > 0
        colour = (PLANE_COLOR * LIGHT_COLOR * LIGHT_POWER)[None, :] * (np.maximum(cos, 0.0) * falloff * ~occluded)[
            :, None
        ]
        return colour, keep, occluded, cos, r, falloff


_lit = {}


def lit_plane(space, **kw):
    key = (space.id, tuple(sorted(kw.items())))
    if key not in _lit:
        _lit[key] = LitPlane(space, **kw)
    return _lit[key]


@pytest.mark.parametrize("sid", ["nil", "sol"])
def test_lambert_colour_is_base_power_cos_falloff(space_of, sid):
    """Hits on the plane (after crossings too): colour = base * power * cos * falloff, with the
    direction and length of the geodesic to the nearest light copy from connect, the metric
    normal facing the ray and falloff_along (the Python reference), to the float32 colour's
    precision in Nil (2e-5: its falloff is the closed form's; 1e-7 measured) and 3e-4 in Sol (its
    falloff from forward differences of the flow, as test_light_curved holds it; 3e-6 measured);
    hits whose connecting geodesic passes through the occluder are black; faces turned away from
    the light are black."""
    world = lit_plane(space_of(sid))
    out = world.trace()
    rows, off = world.hits_on_plane(out)
    colour, keep, occluded, cos, r, falloff = world.expected(out, rows)
    got = out["color"][rows].astype(float)
    lit = keep & ~occluded & (cos > 0)
    dark = keep & (occluded | (cos <= 0))
    assert lit.sum() >= 100 and (keep & occluded).sum() >= 20 and (keep & (cos <= 0)).sum() >= 20, (
        lit.sum(),
        (keep & occluded).sum(),
        (keep & (cos <= 0)).sum(),
    )
    rel = np.abs(got[lit] - colour[lit]).max(axis=1) / colour[lit].max(axis=1)
    crossed = out["crossings"][rows][lit] > 0
    report(
        f"{sid}: Lambert colour vs base * power * cos * falloff ({len(rows)} hits on the plane, at most "
        f"{off:.1g} off it)",
        ["lit", "of which crossed", "shadowed", "back-facing", "max rel err", "median", "r range"],
        [
            [
                int(lit.sum()),
                int(crossed.sum()),
                int((keep & occluded).sum()),
                int((keep & (cos <= 0)).sum()),
                rel.max(),
                float(np.median(rel)),
                f"{r[lit].min():.2f}-{r[lit].max():.2f}",
            ]
        ],
    )
    assert crossed.sum() >= 10
    assert np.all(rel <= (2e-5 if sid == "nil" else 3e-4)), rel.max()
    assert np.all(got[dark] == 0.0), got[dark].max()
    assert int(out["light_failures"]) == 0


@pytest.mark.parametrize("sid", ["nil", "sol"])
def test_falloff_tends_to_inverse_square_near_the_light(space_of, sid):
    """falloff_along(r) r^2 -> 1 as r -> 0 (the deviation falls like r^2), and a light 0.02 from
    the plane lights its foot point with base * power * cos / r^2 to 1e-3, as traced."""
    space = space_of(sid)
    g = space.geometry
    rng = np.random.default_rng(62)
    P = g.to_model(interior_points(space, rng, 20))
    D = g.normalize_tangent(P, np.c_[chart_velocity(g.name, P[:, :3], unit_rows(rng, 20)), np.zeros(20)])
    rows = []
    deviations = []
    for r in (1e-1, 1e-2, 1e-3):
        dev = np.abs(g.falloff_along(P, D, np.full(20, r)) * r * r - 1).max()
        deviations.append(dev)
        rows.append(["python", r, dev])
    assert deviations[1] < 2e-3 and deviations[2] < 1e-4 and deviations[2] < deviations[1] < deviations[0]
    world = lit_plane(space, light_at=(0.28, 0.0, 0.0), occluder=False, n=100, seed=63, targets=0.01)
    out = world.trace()
    hit, _ = world.hits_on_plane(out)
    colour, keep, _, cos, r, falloff = world.expected(out, hit)
    close = keep & (r < 0.03) & (cos > 0)
    assert close.sum() >= 50, close.sum()
    base = PLANE_COLOR * LIGHT_COLOR * LIGHT_POWER
    inverse_square = base[None, :] * (cos / r**2)[:, None]
    got = out["color"][hit].astype(float)
    dev = np.abs(got[close] / inverse_square[close] - 1).max()
    rows.append(["traced", float(r[close].max()), dev])
    report(f"{sid}: falloff r^2 - 1 near the light", ["", "r", "max |dev|"], rows)
    assert dev < 1e-3
    assert np.all(np.abs(got[close] - colour[close]).max(axis=1) <= 1e-3 * colour[close].max(axis=1))


# --- 7. `thurston trace --tolerance T` writes chords and error estimates ------------------------


@pytest.mark.parametrize("sid", ["nil", "sol"])
def test_cli_trace_writes_chords_and_error_estimates(space_of, sid, tmp_path, monkeypatch, capsys):
    """HITS.npz holds chords (N,) (Embree queries per ray) and error_estimate (N,) (finite and
    positive for hits, NaN for misses); as --tolerance falls from 1e-2 to 1e-6 the chords rise and
    the estimates of the rays that hit the same object at both fall."""
    import warnings

    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)  # cli.main replaces it
    space = space_of(sid)
    rng = np.random.default_rng(71)
    n = 300
    x = np.asarray(space.camera.position, float) + 0.05 * unit_rows(rng, n)
    rays = np.c_[x, chart_velocity(space.geometry.name, x, unit_rows(rng, n))]
    np.save(tmp_path / "rays.npy", rays)
    runs = {}
    for T in (1e-2, 1e-4, 1e-6):
        out = tmp_path / f"hits_{T:g}.npz"
        code = cli.main(
            [
                "trace",
                "--space",
                sid,
                "--rays",
                str(tmp_path / "rays.npy"),
                "--out",
                str(out),
                "--tolerance",
                f"{T:g}",
                "--max-distance",
                "6",
                "--threads",
                "2",
            ]
        )
        assert code == 0, capsys.readouterr().err
        with np.load(out) as data:
            runs[T] = {k: data[k] for k in data.files}
    capsys.readouterr()
    rows = []
    for T, r in runs.items():
        assert r["chords"].shape == (n,) and r["error_estimate"].shape == (n,)
        assert np.issubdtype(r["chords"].dtype, np.integer) and r["error_estimate"].dtype == np.float64
        hit = r["stop"] == 0
        assert hit.sum() >= 50
        assert np.all(np.isfinite(r["error_estimate"][hit])) and np.all(r["error_estimate"][hit] > 0)
        assert np.all(np.isnan(r["error_estimate"][~hit]))
        assert np.all(r["chords"] >= 0) and np.all(r["chords"][hit] >= 1)
        rows.append(
            [
                T,
                int(hit.sum()),
                int(r["chords"].sum()),
                float(np.median(r["error_estimate"][hit])),
                float(np.nanmax(r["error_estimate"])),
            ]
        )
    report(f"{sid}: thurston trace --tolerance T ({n} rays)", ["T", "hits", "chords", "median est", "max est"], rows)
    coarse, fine = runs[1e-2], runs[1e-6]
    assert coarse["chords"].sum() < runs[1e-4]["chords"].sum() < fine["chords"].sum()
    assert fine["chords"].sum() > 3 * coarse["chords"].sum()
    both = (coarse["stop"] == 0) & (fine["stop"] == 0) & (coarse["object"] == fine["object"])
    assert np.all(fine["error_estimate"][both] < coarse["error_estimate"][both])
    assert np.median(fine["error_estimate"][both]) < 1e-2 * np.median(coarse["error_estimate"][both])


# --- threads, progress and cancel, as for the projective kernel --------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("sid", ["nil", "sol"])
def test_marching_threads_progress_and_cancel(space_of, sid):
    """One and two threads give the same bits; progress is reported and a False answer stops the
    trace, leaving the untraced rays marked cancelled; cancel() from another thread stops it too."""
    import threading

    space = space_of(sid)
    scene = default_scene(space)
    settings = render.Settings(width=160, height=90, quality="preview")
    camera = scenes.Camera(space.camera.position, space.camera.forward, space.camera.up, space.camera.fov)
    o, d = render.camera_rays(space, camera, settings)
    args = (space.max_distance, space.max_crossings)
    one, two = (render.make_tracer(space, scene, threads=n).trace(o, d, *args, tolerance=1e-4) for n in (1, 2))
    for key in one:
        np.testing.assert_array_equal(one[key], two[key], err_msg=key)
    assert (one["stop"] == 0).mean() > 0.5

    tracer = render.make_tracer(space, scene, threads=2)
    long = dict(tolerance=1e-7)  # slow enough to outlive the first report
    O, D = np.repeat(o, 8, axis=0), np.repeat(d, 8, axis=0)
    calls = []
    r = tracer.trace(O, D, *args, progress=lambda done, total: calls.append(done) or len(calls) < 2, **long)
    assert calls[0] == 0 and (r["stop"] == 3).any() and np.all(np.isinf(r["depth"][r["stop"] == 3]))
    started = threading.Event()
    threading.Timer(0.3, tracer.cancel).start()
    r = tracer.trace(O, D, *args, progress=lambda done, total: started.set(), **long)
    assert started.is_set() and (r["stop"] == 3).any()
