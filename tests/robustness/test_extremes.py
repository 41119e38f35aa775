"""Stability at the extremes (issue 10, point 4), each against truth that does not come from the
tracer:

- ends and hits after 1 to 1000 face crossings against the geodesic of the universal cover (the
  geometry's closed form, or Sol's integrator, in extended precision where it has one), carried
  into the domain by the face pairings (Nil and Sol: the lattice in closed form first, as
  test_marching does), held to the final quality's stated bound (its fraction of the pixel
  footprint at the distance travelled);
- accumulated isometries against the invariants that define them (the ambient quadratic forms of
  S3, H3, H2xR and SL2's first rows; the textbook metrics of truth.py pulled back by the affine
  maps of E3, Nil, Sol and S2xR);
- flows at the extremes against DOP853 on the geodesic equation of truth.py's metrics;
- 10^6 rays per preset aimed exactly at the domain's edges and vertices (each ray's start found by
  flowing backwards from its target), against the domain's own faces;
- hits far from the chart's origin against the double-precision planes of the triangles hit and
  the reference geodesic;
- grazing hits at a coarse tolerance against the balls' meshes and the reference geodesic.

Tables of the measured numbers are printed (pytest -s).
"""

import functools
import math

import numpy as np
import pytest
import thurston_core
import trimesh
from support.cover import first_hits
from support.lattice import into_domain
from support.presets import presets, simplest_per_geometry
from support.report import report
from support.truth import (
    AMBIENT,
    assert_sl2_flow,
    chart_metric,
    check_flows_against_dop853,
    h2xr_metric,
    nil_metric,
    nil_sol_christoffel,
    s2xr_metric,
    sl2_body_direction,
    sl2_metric,
    sol_metric,
    unit_in,
)

from thurston_addon import render, spaces
from thurston_addon.render.statistics import _image_distance
from thurston_addon.scenes import Scene, SceneObject

ld = np.longdouble
FINAL = render.QUALITY["final"].footprint_fraction
LEVELS = (1, 10, 100, 1000)
SOL = spaces.load("sol").geometry


def stated_bound(space, depth):
    """The final quality's bound at geodesic distance `depth` (the tightest quality's)."""
    return FINAL * render.footprint(space, render.REFERENCE_PIXEL_ANGLE, depth)


def final_tolerances(space):
    return render.Settings(quality="final").tolerances(space, render.REFERENCE_PIXEL_ANGLE)


def random_rays(space, rng, n):
    g = space.geometry
    x = space._interior_points(rng, n)
    P = g.to_model(x)
    return P, g.normalize_tangent(P, g.tangent_to_model(x, rng.normal(size=(n, 3))))


def trace(space, scene, P, V, length, tolerances, max_crossings=10**6):
    out = render.make_tracer(space, scene).trace(
        np.ascontiguousarray(P, float),
        np.ascontiguousarray(V, float),
        float(length),
        max_crossings,
        shade=False,
        tolerance=tolerances[0],
        tolerance_per_distance=tolerances[1],
    )
    return out


def reduce(space, Y):
    """Cover model points (extended precision is kept) carried into the domain: (X, M); the
    lattices of the torus, Nil and Sol in closed form first (fast for far points)."""
    if space.id in ("nil", "sol"):
        X, _, M = into_domain(space, Y)
    elif space.id == "torus":
        shift = np.floor(Y[:, :3] / Y[:, 3:] + 0.5)
        M = np.broadcast_to(np.eye(4, dtype=Y.dtype), (len(Y), 4, 4)).copy()
        M[:, :3, 3] = -shift
        X = np.einsum("nij,nj->ni", M, Y)
        X, _, R = space.move_inside(X)
        M = np.einsum("nij,njk->nik", R, M)
    else:
        X, _, M = space.move_inside(Y)
    return X, M


def cover_ends(space, P, V, lengths):
    """Model points where the cover geodesics from (P, V) end after `lengths` (one, or one per
    ray), carried into the domain."""
    lengths = np.full(len(P), ld(1)) * np.asarray(lengths, ld)
    Y, _ = space.geometry.geodesic(np.asarray(P, ld), np.asarray(V, ld), lengths)
    return np.asarray(reduce(space, Y)[0], float)


def end_errors(space, out, X):
    """Metric distance of the traced ends from the model points X (the nearest copy: a point on a
    face has two)."""
    return _image_distance(space, space.geometry.to_model(out["end"]), X)


CHART_METRICS = {
    "E3": lambda x: chart_metric("E3", x),
    "S3": lambda x: chart_metric("S3", x),
    "H3": lambda x: chart_metric("H3", x),
    "Nil": nil_metric,
    "Sol": sol_metric,
    "H2xR": h2xr_metric,
    "S2xR": s2xr_metric,
    "SL2": sl2_metric,
}


@pytest.mark.parametrize("sid", simplest_per_geometry())
def test_the_error_measure_is_the_metric_distance(space_of, sid):
    """end_errors (render.statistics._image_distance: Geometry.chord_distance over the neighbouring copies),
    which every bound below is checked with, against truth.py's metrics: a point 1e-6 from a
    point of the domain, and that point moved to a neighbouring copy, are at the length of their
    chart difference in the metric (at the midpoint), to 1e-5 relative (the copy rounds)."""
    space = space_of(sid)
    g = space.geometry
    rng = np.random.default_rng(83)
    x = space._interior_points(rng, 40)
    d = 1e-6 * rng.normal(size=x.shape)
    metric = CHART_METRICS[g.name]
    want = np.array([math.sqrt(e @ metric(p + e / 2) @ e) for p, e in zip(x, d)])
    near = g.normalize_point(g.to_model(x + d))
    around = space.neighbourhood(1)[1:]  # (the identity first)
    away = np.array([np.linalg.solve(around[k % len(around)], p) for k, p in enumerate(near)])
    for Z in (near, away):
        got = end_errors(space, {"end": x}, Z)
        np.testing.assert_allclose(got, want, rtol=1e-5)


def crossing_rate(space, P, V):
    """Face crossings per unit of length along the rays (an empty scene, length 20)."""
    out = trace(space, Scene(), P, V, 20.0, final_tolerances(space))
    return float(out["crossings"].mean()) / 20.0


# --- 1. ends and hits from 1 to 1000 crossings --------------------------------------------------

# The flows of H3, Sol and SL2~ separate nearby geodesics like e^(rate t) (rate 1, 1 and 1.32:
# test_sl2), so what float64 leaves of a ray after length t is ~1e-16 e^(rate t) at best (Sol's
# integrator, asked for 1/20 of the tolerance, adds tolerance / 20 e^t), while the final bound
# grows like t: past ~10 crossings (length ~7-15) no tracer can hold a random ray to it, nor can
# a float64 reference tell where the ray ends. There random rays are held to the bound up to 10
# crossings; beyond, to ending finite and inside the domain, and the rays whose flows do not
# separate are held to the bound at every level: Sol's vertical axis (the monodromy keeps it)
# and SL2's fibres.
CHAOTIC = {"seifert_weber", "sol", "sl2"}
CHAOS_LEVEL = 10


def stable_rays(space, rng, n):
    """Rays whose nearby geodesics do not separate exponentially: Sol's axis x = y = 0 both ways,
    SL2's fibres (body velocity (0, 0, +-1)) from random points; None elsewhere."""
    g = space.geometry
    if space.id == "sol":
        x = np.c_[np.zeros((n, 2)), rng.uniform(-0.4, 0.4, n)]
        u = np.c_[np.zeros((n, 2)), np.where(np.arange(n) % 2, 1.0, -1.0)]
    elif space.id == "sl2":
        x = space._interior_points(rng, n)
        u = np.array([sl2_body_direction(p, [0.0, 0.0, 1.0 if i % 2 else -1.0]) for i, p in enumerate(x)])
    else:
        return None
    P = g.to_model(x)
    return P, g.normalize_tangent(P, g.tangent_to_model(x, u))


# (H2xR's and S2xR's long rays: test_h2xr.py, test_s2xr.py)
@pytest.mark.parametrize("sid", simplest_per_geometry(lambda space: space.geometry.name not in ("H2xR", "S2xR")))
def test_ends_within_the_bound_from_1_to_1000_crossings(space_of, sid):
    """Rays through an empty scene at the final quality's tolerances, stopped by their length after
    about 1, 10, 100 and 1000 crossings: each ends (stop 1, finite, inside the domain) where the
    cover geodesic ends, within the final bound at that distance (see CHAOTIC for the flows that
    separate geodesics exponentially)."""
    space = space_of(sid)
    rng = np.random.default_rng(71)
    n = 16
    P, V = random_rays(space, rng, n)
    rate = crossing_rate(space, P, V)
    stable = stable_rays(space, rng, 8)
    rows = []
    for level in LEVELS:
        families = [("random", P, V, level / rate)]
        if stable is not None:
            families.append(("stable", *stable, level / crossing_rate(space, *stable)))
        for name, Pf, Vf, L in families:
            out = trace(space, Scene(), Pf, Vf, L, final_tolerances(space))
            assert np.all(out["stop"] == 1) and np.all(np.isfinite(out["end"])), (level, name)
            assert space.domain.contains(space.geometry.to_model(out["end"]), tol=1e-9).all(), (level, name)
            held = name == "stable" or sid not in CHAOTIC or level <= CHAOS_LEVEL
            err = end_errors(space, out, cover_ends(space, Pf, Vf, L)) if held else np.full(len(Pf), np.nan)
            bound = stated_bound(space, L)
            rows.append(
                [name, level, L, float(out["crossings"].mean()), float(np.max(err)), bound, float(np.max(err) / bound)]
            )
            if held:
                assert np.all(err <= bound), (name, level, err.max(), bound)
    report(
        f"{sid}: traced ends against the cover geodesic's (final tolerances)",
        ["rays", "crossings~", "length", "mean cross", "max error", "bound", "error/bound"],
        rows,
    )
    assert max(r[3] for r in rows) >= 900


BALL = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
BALL_INNER = float(np.min(np.abs(np.einsum("kj,kj->k", BALL.face_normals, BALL.triangles[:, 0]))))


def cover_entry(space, P, V, L, centre, radius, step):
    """cover.first_hits for the ball about the chart point `centre` (circumscribed radius
    `radius`) along the cover geodesic from (P, V) over L: the pieces are sampled every `step`,
    carried into the domain, and searched from the first that comes within reach of the ball."""
    g = space.geometry
    t = np.arange(0.0, L + step, step)
    Y, _ = g.geodesic(np.asarray(P, float)[None], np.asarray(V, float)[None], t)  # float64: the bound is >= 1e-4
    X, M = reduce(space, Y)
    x = np.asarray(g.to_chart(X), float)
    x_next = np.asarray(g.to_chart(np.einsum("kij,kj->ki", M[:-1], Y[1:])), float)
    near = np.minimum(np.linalg.norm(x[:-1] - centre, axis=1), np.linalg.norm(x_next - centre, axis=1))
    close = np.flatnonzero(near < radius + step)
    if not len(close):
        return math.inf, math.inf, float(near.min() - radius)
    k0 = close[0]

    def chart(k, s):
        Z, _ = g.geodesic(np.asarray(P, float), np.asarray(V, float), s)
        return np.asarray(g.to_chart(M[k0 + k] @ Z), float)

    return first_hits(t[k0:], x[k0:], x_next[k0:], chart, [centre], [radius], [radius * BALL_INNER])


# (space, levels with hits): a ball on the cover geodesic after many crossings is met earlier
# where geodesics close up (S3's great circles, SL2's fibres, Sol's axis) or separate
HIT_LEVELS = {
    "torus": LEVELS,
    "nil": LEVELS,
    "poincare": (1,),
    "seifert_weber": (1, 10),
    "sol": (1, 10),
    "sl2": (1, 10),
}
# Chords this close to the curve: what is measured is the walk's accumulated error, not where
# coarse chords put silhouettes (an earlier pass of the ray within the chord tolerance of the ball
# may hit it; benchmarks/bench_front.py measures that).
FINE = (1e-6, 0.0)


@pytest.mark.parametrize("sid", list(HIT_LEVELS))
def test_hit_depths_within_the_bound_after_many_crossings(space_of, sid):
    """A ball (radius 0.02) placed where the cover geodesic of a ray stands after about 1 to 1000
    crossings: the ray hits it (or whatever copy of it the cover geodesic meets first) at the
    depth of the geodesic's first entry, between its circumscribed and inscribed spheres, within
    the final bound there (rays grazing a ball are left out)."""
    space = space_of(sid)
    g = space.geometry
    rng = np.random.default_rng(72)
    radius = 0.02
    rows = []
    for level in HIT_LEVELS[sid]:
        P, V = random_rays(space, rng, 12 if level < 1000 else 8)
        L = level / crossing_rate(space, P, V)
        ends = cover_ends(space, P, V, L)
        compared = 0
        worst = 0.0
        for i in range(len(P)):
            centre = np.asarray(g.to_chart(ends[i]), float)
            mesh = centre + radius * BALL.vertices
            if not space.domain.contains(g.to_model(centre + 1.5 * radius * BALL.vertices), tol=-1e-9).all():
                continue  # a ball across a face: its copies are not where the carried path looks
            t_outer, t_inner, margin = cover_entry(space, P[i], V[i], L + 2 * radius, centre, radius, 0.005)
            if not (math.isfinite(t_inner) and t_inner - t_outer < 0.01):
                continue  # grazing, or (first through a copy's rim) ill-posed
            out = trace(
                space,
                Scene(objects=[SceneObject("ball", mesh, BALL.faces)]),
                P[i : i + 1],
                V[i : i + 1],
                L + 2 * radius,
                FINE,
            )
            bound = stated_bound(space, t_outer)
            assert out["stop"][0] == 0, (level, i)
            depth = float(out["depth"][0])
            assert t_outer - bound <= depth <= t_inner + bound, (level, i, t_outer, depth, t_inner, bound)
            compared += 1
            worst = max(worst, max(t_outer - depth, depth - t_inner, 0.0) / bound)
        rows.append([level, L, compared, worst])
        assert compared >= (3 if level >= 1000 else 6), (level, compared)
    report(
        f"{sid}: hit depth against the cover geodesic's first entry",
        ["crossings~", "length", "compared", "outside/bound"],
        rows,
    )


# --- 2. accumulated isometries ------------------------------------------------------------------

# The quadratic forms the model vectors' isometries keep: S3's and H3's ambient forms, H2xR's
# hyperboloid slots (X1, X2, X0) with the line's slot e^z scaled on its own, SL2's first rows
# (Re a, Im a, Re b, Im b) of SU(1,1) matrices, |a|^2 - |b|^2 = 1, which left multiplications and
# fibre translations keep.
FORMS = {"S3": AMBIENT["S3"], "H3": AMBIENT["H3"], "SL2": np.diag([1.0, 1.0, -1.0, -1.0])}
AFFINE_METRICS = {"E3": lambda x: np.eye(3), "Nil": nil_metric, "Sol": sol_metric, "S2xR": s2xr_metric}


def isometry_defect(space, M, rng):
    """How far the matrices M (n, 4, 4) are from isometries, relative to the size of the terms
    compared: |M^T Q M - Q| / |M|^2 for the forms Q; for the affine charts, the pull-back of the
    metric A^T g(M x) A - g(x) at random domain points over |A|^T |g(M x)| |A| + |g(x)|."""
    g = space.geometry
    M = np.asarray(M, float)
    if g.name in FORMS or g.name == "H2xR":
        if g.name == "H2xR":
            lorentz, line = M[:, [0, 1, 3]][:, :, [0, 1, 3]], M[:, 2, 2]
            coupled = np.abs(np.concatenate([M[:, 2, [0, 1, 3]], M[:, [0, 1, 3], 2]], axis=1)).max(axis=1)
            assert np.all(line > 0)
            M, Q = lorentz, np.diag([1.0, 1.0, -1.0])
        else:
            coupled, Q = 0.0, FORMS[g.name]
        defect = np.abs(np.einsum("nki,kl,nlj->nij", M, Q, M) - Q).max(axis=(1, 2))
        return np.maximum(defect, coupled) / np.maximum(1.0, np.abs(M).max(axis=(1, 2)) ** 2)
    metric = AFFINE_METRICS[g.name]
    x = space._interior_points(rng, 6)
    worst = np.zeros(len(M))
    for i, m in enumerate(M):
        A = m[:3, :3]
        assert np.allclose(m[3], [0, 0, 0, 1], rtol=0, atol=0)
        for p in x:
            gi, g0 = metric(A @ p + m[:3, 3]), metric(p)
            scale = np.abs(A).T @ np.abs(gi) @ np.abs(A) + np.abs(g0)
            worst[i] = max(worst[i], float(np.max(np.abs(A.T @ gi @ A - g0) / np.where(scale > 0, scale, 1.0))))
    return worst


# (space, geodesic length): about 1000 crossings, or as far as the Python reduction reaches: in
# float64 the Klein and Poincare charts hold points out to distance ~18 in H3 and H2xR, ~35 in SL2
# (model vectors ~e^t, their quadric lost beyond), and Nil's face steps (z grows like t^2) and
# Sol's exponentials (e^|z|, |z| <= t) stay within move_inside's steps
FAR = {
    "torus": 660.0,
    "poincare": 420.0,
    "seifert_weber": 15.0,
    "nil": 60.0,
    "sol": 20.0,
    "genus2xs1": 15.0,
    "s2xs1": 100.0,
    "sl2": 30.0,
}


@pytest.mark.parametrize("sid", list(FAR))
def test_accumulated_isometries_stay_isometries(space_of, sid):
    """The isometries the Python side accumulates stay isometries to 1e-12 (relative): those that
    bring cover points far along geodesics (up to ~1000 crossings) into the domain, the copies of a
    light within the default reach (the tile walks' products) and the domain's neighbours;
    the points brought in are finite, on the model and inside the domain."""
    space = space_of(sid)
    g = space.geometry
    rng = np.random.default_rng(73)
    P, V = random_rays(space, rng, 40)
    Y, _ = g.geodesic(P, V, np.full(len(P), FAR[sid]))
    X, _, M = space.move_inside(Y)
    assert np.all(np.isfinite(X)) and space.domain.contains(X, tol=1e-9).all()
    assert np.allclose(g.normalize_point(X), X, rtol=1e-12, atol=1e-12)
    defects = {"move_inside": isometry_defect(space, M, rng)}
    light = g.to_model(space._interior_points(rng, 1))[0]
    defects["light copies"] = isometry_defect(
        space, render.light_copies(space, light, render.default_light_reach(space)), rng
    )
    defects["neighbours"] = isometry_defect(space, np.array(space.neighbourhood(1)), rng)
    report(
        f"{sid}: isometry defects (relative)",
        ["matrices", "count", "max defect"],
        [[k, len(v), float(v.max())] for k, v in defects.items()],
    )
    for name, d in defects.items():
        assert d.max() <= 1e-12, (name, d.max())


# --- 3. grazing hits at a coarse tolerance ------------------------------------------------------


@pytest.mark.parametrize("sid", ["nil", "sol", "sl2"])
def test_grazing_hits_stay_on_their_ball_at_a_coarse_tolerance(space_of, sid):
    """Rays aimed at the rims of balls, traced with chords of tolerance 0.03 (the chord may meet a
    ball the curve passes by): every hit lies within the tolerance of the cover geodesic at its
    depth (reduced into the domain; Sol's integrator is asked for 1/20 of the tolerance, the
    closed forms are exact) and of the ball it reports. (Hits used to be refined onto where
    the curve crosses the plane of the chord's triangle, which at grazing angles lies far from
    the triangle: 0.2 off the ball at tolerance 0.05 in Nil.)"""
    space = space_of(sid)
    g = space.geometry
    rng = np.random.default_rng(74)
    tolerance = 0.03
    radius = 0.3 * space.chart_inradius
    centres = np.array(
        [
            c
            for c in space._interior_points(rng, 200)
            for around in [c + 1.3 * radius * BALL.vertices]
            if g.in_chart(around).all() and space.domain.contains(g.to_model(around), tol=-1e-9).all()
        ][:2]
    )
    scene = Scene(
        objects=[SceneObject(f"ball{k}", c + radius * BALL.vertices, BALL.faces) for k, c in enumerate(centres)]
    )
    x = space._interior_points(rng, 6000)
    x = x[np.min(np.linalg.norm(x[:, None] - centres[None], axis=2), axis=1) > 1.5 * radius][:3000]
    k = rng.integers(len(centres), size=len(x))
    towards = centres[k] - x
    across = np.cross(towards, rng.normal(size=(len(x), 3)))
    across /= np.linalg.norm(across, axis=1)[:, None]
    u = towards + rng.uniform(0.9, 1.1, (len(x), 1)) * radius * across
    P = g.to_model(x)
    V = g.normalize_tangent(P, g.tangent_to_model(x, u))
    out = trace(space, scene, P, V, 3.0, (tolerance, 0.0))
    hit = np.flatnonzero(out["stop"] == 0)
    assert len(hit) > 300
    h = out["position"][hit]
    owner = out["object"][hit]
    tri = np.stack([c + radius * BALL.triangles for c in centres])[owner]  # (n, faces, 3, 3)
    n_faces = tri.shape[1]
    near = trimesh.triangles.closest_point(tri.reshape(-1, 3, 3), np.repeat(h, n_faces, axis=0)).reshape(
        len(h), n_faces, 3
    )
    off_ball = np.min(np.linalg.norm(near - h[:, None], axis=2), axis=1)
    on_curve = end_errors(space, {"end": h}, cover_ends(space, P[hit], V[hit], out["depth"][hit]))
    report(
        f"{sid}: grazing hits at tolerance {tolerance}",
        ["hits", "max off ball", "max off curve"],
        [[len(hit), float(off_ball.max()), float(on_curve.max())]],
    )
    assert off_ball.max() <= tolerance, off_ball.max()
    assert on_curve.max() <= tolerance, on_curve.max()


# --- 4. no NaN or inf at the extremes -----------------------------------------------------------


def test_h3_rays_of_length_50(space_of):
    """Seifert-Weber rays traced for 50 (about 50 crossings; H3 separates nearby geodesics like e^t,
    so past ~10 crossings no float64 path is the cover geodesic's, see CHAOTIC): no NaN or inf,
    every ray ends by its length (or on the ball) inside the domain, hits on the ball's surface."""
    space = space_of("seifert_weber")
    g = space.geometry
    rng = np.random.default_rng(75)
    P, V = random_rays(space, rng, 20000)
    radius = 0.1
    scene = Scene(objects=[SceneObject("ball", radius * BALL.vertices, BALL.faces)])
    for s, name in ((Scene(), "empty"), (scene, "ball")):
        out = trace(space, s, P, V, 50.0, final_tolerances(space))
        assert np.all(np.isin(out["stop"], (0, 1))) and np.all(np.isfinite(out["end"])), name
        assert space.domain.contains(g.to_model(out["end"]), tol=1e-9).all(), name
        assert np.all(out["distance"][out["stop"] == 1] == 50.0), name
        hit = out["stop"] == 0
        if name == "ball":
            r = np.linalg.norm(out["position"][hit], axis=1)
            assert hit.sum() > 1000 and np.all((r >= radius * BALL_INNER - 1e-12) & (r <= radius + 1e-12))
        assert out["crossings"].max() >= 40


def test_sol_starts_at_z_20(space_of):
    """Sol at |z| = 20: the C++ and Python flows from there (in the cover, e^(2z) ~ 2e17 in the
    metric) match DOP853 of the geodesic equation; rays started there are brought into the domain
    by the core itself (~500 face maps: once, the walk's reduction stopped after 64 and reported the distance
    limit at a point outside the domain) and end inside it, where the cover geodesic ends within
    what the start's float64 reduction loses (about a unit of the last place of x times phi^42,
    ~1e-6) grown by e^L."""
    space = space_of("sol")
    g = space.geometry
    rng = np.random.default_rng(76)
    n = 12
    x = np.c_[rng.uniform(-1, 1, (n, 2)), np.where(np.arange(n) % 2 == 0, 20.0, -20.0)]
    u = rng.normal(size=(n, 3))
    # the C++ and the Python flow (and their speed) against DOP853; tol 5e-10 (relative + absolute
    # on 1 + |reference|) is within 1e-9 (1 + |reference|)
    check_flows_against_dop853(
        SOL,
        functools.partial(nil_sol_christoffel, "Sol"),
        sol_metric,
        [(x[i], unit_in(sol_metric, x[i], u[i]), 1.5) for i in range(4)],
        tol=5e-10,
    )
    P = g.to_model(x)
    V = g.normalize_tangent(P, g.tangent_to_model(x, u))
    L = 1.0
    out = trace(space, Scene(), P, V, L, (1e-7, 0.0))
    assert np.all(out["stop"] == 1) and np.all(out["distance"] == L) and np.all(np.isfinite(out["end"]))
    assert space.domain.contains(g.to_model(out["end"]), tol=1e-9).all()
    err = end_errors(space, out, cover_ends(space, P, V, L))
    report(
        "sol: rays started at |z| = 20",
        ["rays", "crossings", "max error"],
        [[n, int(out["crossings"].max()), float(err.max())]],
    )
    assert err.max() <= 1e-6 * math.exp(L), err.max()  # 9.3e-7 measured


@pytest.mark.parametrize("w", [0.0, -0.0, 1e-300, -1e-300, 5e-324])
def test_nil_rays_with_vanishing_vertical_component(space_of, w):
    """Nil rays whose vertical component in the orthonormal frame (dx, dy, dz - x dy) is 0, -0,
    +-1e-300 or the least subnormal (the closed form divides by it), through ~1000 crossings:
    finite, inside the domain, where the cover geodesic ends within the final bound."""
    space = space_of("nil")
    g = space.geometry
    rng = np.random.default_rng(77)
    n = 12
    x = space._interior_points(rng, n)
    a = rng.uniform(0, 2 * math.pi, n)
    e = np.c_[np.cos(a), np.sin(a), np.full(n, w)]
    u = np.c_[e[:, 0], e[:, 1], e[:, 2] + x[:, 0] * e[:, 1]]  # the frame's chart vectors
    P = g.to_model(x)
    V = np.c_[u, np.zeros(n)]
    assert np.allclose(np.einsum("ni,nij,nj->n", u, np.array([nil_metric(p) for p in x]), u), 1.0)
    for L in (60.0, 650.0):
        out = trace(space, Scene(), P, V, L, final_tolerances(space))
        assert np.all(out["stop"] == 1) and np.all(np.isfinite(out["end"]))
        assert space.domain.contains(g.to_model(out["end"]), tol=1e-9).all()
        err = end_errors(space, out, cover_ends(space, P, V, L))
        assert err.max() <= stated_bound(space, L), (L, err.max())
    assert out["crossings"].min() >= 600


def test_sl2_rays_at_a_equal_to_c(space_of):
    """SL2 rays whose body velocity has a = |c| exactly (where the closed form's hyperbolic
    functions turn trigonometric): the C++ and Python flows match DOP853; traced rays end finite
    and inside after ~1000 crossings, and where the cover geodesic ends within the final bound
    after ~10 (past that the flow's chaos leaves float64 nothing to compare, see CHAOTIC)."""
    space = space_of("sl2")
    g = space.geometry
    rng = np.random.default_rng(78)
    n = 12
    x = space._interior_points(rng, n)
    c = np.where(np.arange(n) % 2, 1.0, -1.0) / math.sqrt(2)
    axis = np.arange(n) % 4 // 2  # the horizontal part along one body axis: a = |c| exactly
    b = np.zeros((n, 3))
    b[np.arange(n), axis] = np.abs(c) * np.where(np.arange(n) % 3, 1.0, -1.0)
    b[:, 2] = c
    u = np.array([sl2_body_direction(p, q) for p, q in zip(x, b)])
    for i in range(3):  # the C++ and the Python flow against DOP853, within 1e-9 (1 + |reference|)
        assert_sl2_flow(x[i], unit_in(sl2_metric, x[i], u[i]), 3.0, tol=5e-10)
    P = g.to_model(x)
    V = g.normalize_tangent(P, g.tangent_to_model(x, u))
    rate = crossing_rate(space, P, V)
    for level in (10, 1000):
        L = level / rate
        out = trace(space, Scene(), P, V, L, final_tolerances(space))
        assert np.all(out["stop"] == 1) and np.all(np.isfinite(out["end"]))
        assert space.domain.contains(g.to_model(out["end"]), tol=1e-9).all()
        if level <= CHAOS_LEVEL:
            err = end_errors(space, out, cover_ends(space, P, V, L))
            assert err.max() <= stated_bound(space, L), err.max()
    assert out["crossings"].mean() >= 500


# (space, the chart radius of the disk or ball whose rim is approached, how the chart point of
# radius r is placed): the Klein ball of H3, the Klein disk of H2xR, the Poincare disk of SL2
RIMS = {
    "seifert_weber": lambda d, r: r * d,
    "genus2xs1": lambda d, r: np.c_[r * d[:, :2] / np.linalg.norm(d[:, :2], axis=1)[:, None], d[:, 2]],
    "sl2": lambda d, r: np.c_[r * d[:, :2] / np.linalg.norm(d[:, :2], axis=1)[:, None], d[:, 2]],
}


@pytest.mark.parametrize("sid", list(RIMS))
@pytest.mark.parametrize("gap", [1e-6, 1e-9, 1e-12])
def test_points_near_the_rim_of_the_disks(space_of, sid, gap):
    """Chart points 1 - gap from the centre of H3's Klein ball, H2xR's Klein disk and SL2's
    Poincare disk (distances ~7 to ~28 from it): brought into the domain finite, on the model and
    inside, by isometries (relative defect <= 1e-12); rays from there end finite and inside; the
    C++ flow from there (H2xR, SL2) stays finite, in the chart, at unit speed in the metric and
    comes back to its start when flowed back, to what float64 allows there: 1 - r^2 is known to
    eps / gap, and the metric (1 / (1 - r^2)^2) to twice that, so the tolerance is 1e-14 / gap
    (the measured errors are 1e-15 / gap to 2e-15 / gap)."""
    space = space_of(sid)
    g = space.geometry
    rng = np.random.default_rng(79)
    n = 200
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    x = RIMS[sid](d, 1.0 - gap)
    assert g.in_chart(x).all()
    X, _, M = space.move_inside(g.to_model(x))
    assert np.all(np.isfinite(X)) and space.domain.contains(X, tol=1e-9).all()
    assert np.allclose(g.normalize_point(X), X, rtol=1e-12, atol=1e-12)
    assert isometry_defect(space, M, rng).max() <= 1e-12
    u = rng.normal(size=(n, 3))
    V = g.normalize_tangent(X, g.tangent_to_model(np.asarray(g.to_chart(X), float), u))
    out = trace(space, Scene(), X, V, 10.0, final_tolerances(space))
    assert np.all(out["stop"] == 1) and np.all(np.isfinite(out["end"]))
    assert space.domain.contains(g.to_model(out["end"]), tol=1e-9).all()
    if g.projective:
        return
    metric = {"H2xR": h2xr_metric, "SL2": sl2_metric}[g.name]
    v = np.array([w / math.sqrt(w @ metric(p) @ w) for p, w in zip(x, u)])
    t = np.full(n, 0.5)
    xt, vt = thurston_core.geodesic_flow(g.name, np.ascontiguousarray(x), v, t)
    assert np.all(np.isfinite(xt)) and g.in_chart(xt).all()
    speed = np.array([w @ metric(p) @ w for p, w in zip(xt, vt)])
    floor = 1e-14 / gap
    back, _ = thurston_core.geodesic_flow(g.name, xt, np.ascontiguousarray(-vt), t)
    gone = np.array([math.sqrt(max(q @ metric(p) @ q, 0.0)) for p, q in zip(x, back - x)])
    report(
        f"{sid}: the flow from 1 - {gap:g}",
        ["max |speed - 1|", "max back", "floor"],
        [[float(np.abs(speed - 1).max()), float(gone.max()), floor]],
    )
    assert np.all(np.abs(speed - 1) <= floor), np.abs(speed - 1).max()
    assert gone.max() <= floor, gone.max()


# --- 5. no leak at the domain's edges and vertices ----------------------------------------------

LEAK_RAYS = 10**6
PRESETS = presets()


def boundary_targets(space, rng, n):
    """n points of the domain's boundary: on its edges (a fifth at vertices), interpolated in the
    plane chart where the faces are planes; on the face spheres of a shell."""
    g = space.geometry
    if not space.domain.edges:  # a folded shell's inner sphere is inside the double cover traced
        radii = np.asarray(space.radii)[rng.integers(1 if space.fold else 0, 2, size=n)]
        d = rng.normal(size=(n, 3))
        return radii[:, None] * d / np.linalg.norm(d, axis=1)[:, None]
    V = space.plane_vertices
    E = np.array([e[:2] for e in space.domain.edges])[rng.integers(len(space.domain.edges), size=n)]
    s = rng.random(n)
    s[: n // 5] = rng.integers(0, 2, size=n // 5)
    y = s[:, None] * V[E[:, 0]] + (1 - s[:, None]) * V[E[:, 1]]
    return np.asarray(g.from_plane_chart(y), float)


def rays_through(space, rng, targets, s):
    """Rays from inside the domain that pass exactly through the chart points `targets` after
    arclength s: the geodesic from each target towards a random interior point, flowed s and
    turned back (the closed form of the projective geometries, the C++ flow of the others).
    Returns (P, V) of the rays whose start lies inside the domain."""
    g = space.geometry
    q = space._interior_points(rng, 4096)[rng.integers(4096, size=len(targets))]
    T = g.to_model(targets)
    W = g.normalize_tangent(T, g.tangent_to_model(targets, q - targets))
    if g.projective:
        P, back = g.geodesic(T, W, np.full(len(T), s))
    else:
        w = np.ascontiguousarray(g.tangent_to_chart(T, W), float)
        x, v = thurston_core.geodesic_flow(g.name, np.ascontiguousarray(targets), w, np.full(len(T), s))
        P = g.to_model(x)
        back = g.tangent_to_model(x, v)
    V = g.normalize_tangent(P, -back)
    inside = np.all(np.isfinite(P), axis=1) & space.domain.contains(P, tol=-1e-9)
    return P[inside], V[inside]


@pytest.mark.slow
@pytest.mark.parametrize("sid", PRESETS)
def test_no_leak_at_edges_and_vertices(space_of, sid):
    """10^6 rays per preset (a quarter at each quality's tolerances, each quarter from its own
    distance) that pass exactly through points of the domain's edges and vertices (shells: of its
    spheres; RP3 # RP3 is traced through its double cover, where only the outer one is a face),
    stopped a little past them: each ends by its length, finite, inside the domain, having
    crossed; and 10^5 rays through a vertex where a ball sits hit it inside the domain (to the
    chord tolerance)."""
    space = space_of(sid)
    g = space.geometry
    rng = np.random.default_rng(80)
    tracer = render.make_tracer(space, Scene())
    past = 0.05 * space.inradius
    rows = []
    for k, q in enumerate(render.QUALITY):
        n = LEAK_RAYS // 4
        s = (0.1 + 0.1 * k) * space.inradius
        P, V = rays_through(space, rng, boundary_targets(space, rng, 3 * n // 2), s)
        assert len(P) >= n, (q, len(P))
        tolerances = render.Settings(quality=q).tolerances(space, render.REFERENCE_PIXEL_ANGLE)
        out = tracer.trace(
            np.ascontiguousarray(P[:n]),
            np.ascontiguousarray(V[:n]),
            s + past,
            10**6,
            shade=False,
            tolerance=tolerances[0],
            tolerance_per_distance=tolerances[1],
        )
        assert np.all(out["stop"] == 1) and np.all(np.isfinite(out["end"])), (q, np.bincount(out["stop"]))
        inside = space.domain.contains(g.to_model(out["end"]), tol=1e-9)
        assert inside.all(), (q, np.flatnonzero(~inside)[:5])
        rows.append([q, n, float(out["crossings"].mean()), float(np.mean(out["crossings"] >= 1))])
    report(f"{sid}: rays through edges and vertices", ["quality", "rays", "mean cross", "crossed"], rows)
    assert min(r[3] for r in rows) >= 0.99
    # a ball about a point of the boundary (a vertex; a shell: a point of its outer sphere), its
    # copies added where it sticks out: rays through that point hit it, inside the domain
    corner = boundary_targets(space, rng, 1)[:1] if not space.domain.edges else space.domain.vertices[:1]
    P, V = rays_through(space, rng, np.repeat(corner, LEAK_RAYS // 10, axis=0), 0.3 * space.inradius)
    # half the chart distance of the nearest start: every ray starts outside the ball
    radius = 0.5 * np.min(np.linalg.norm(np.asarray(g.to_chart(P), float) - corner, axis=1))
    ball = Scene(objects=[SceneObject("ball", corner + radius * BALL.vertices, BALL.faces)])
    tolerance = 1e-4
    out = render.make_tracer(space, ball).trace(
        np.ascontiguousarray(P), np.ascontiguousarray(V), 0.3 * space.inradius, 10**6, shade=False, tolerance=tolerance
    )
    hit = out["stop"] == 0
    assert hit.mean() >= 0.99 and np.all(np.isfinite(out["position"][hit])), hit.mean()
    # (a curve may poke out of a face and back within a chord, by less than the tolerance: SL2's
    # sides are curved in its chart; by 2e-7 here)
    inside = space.domain.contains(g.to_model(out["position"][hit]), tol=tolerance)
    assert inside.all(), (out["position"][hit][~inside][:3], out["crossings"][hit][~inside][:3])


# --- 6. float32 BVH, float64 geodesics ----------------------------------------------------------


def first_hits_in_double(origins, directions, triangles):
    """(t, point) of the first crossing of each ray (unit chart directions) with the triangles,
    Moeller-Trumbore in float64 (t = inf: none)."""
    a, b, c = (triangles[:, k][None] for k in range(3))
    e1, e2 = b - a, c - a
    d = directions[:, None]
    p = np.cross(d, e2)
    det = np.sum(e1 * p, axis=2)
    s = origins[:, None] - a
    u = np.sum(s * p, axis=2) / det
    q = np.cross(s, e1)
    v = np.sum(d * q, axis=2) / det
    t = np.sum(e2 * q, axis=2) / det
    t = np.where((u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0), t, np.inf)
    first = t.min(axis=1)
    return first, origins + first[:, None] * directions


def test_far_from_the_origin_hits_are_refined_in_double(tmp_path):
    """A flat 3-torus of side 2000 with a ball at x ~ 900 (triangles) and an instance of it at
    x ~ -900 (Embree traverses both in float32: a unit of the last place is 6e-5 there): every
    hit is the float64 ray-triangle intersection to 1e-9 (the hits are refined on the triangles'
    planes in double precision), far below what float32 could give."""
    side = 2000.0
    text = spaces.preset_path("torus").read_text()
    big = (
        text.replace("[1, 0, 0, 1]", f"[1, 0, 0, {side}]")
        .replace("[0, 1, 0, 1]", f"[0, 1, 0, {side}]")
        .replace("[0, 0, 1, 1]", f"[0, 0, 1, {side}]")
        .replace("position = [0.1, -0.2, 0.05]", "position = [0, 0, 0]")
    )
    path = tmp_path / "big_torus.toml"
    path.write_text(big)
    space = spaces.load(path)
    assert abs(space.extent - side) < 1e-9
    g = space.geometry
    radius = 5.0
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=radius)
    centre = np.array([900.0, 300.0, -600.0])
    shift = np.eye(4)
    shift[:3, 3] = [-1800.0, 0.0, 0.0]  # the instance's centre: (-900, 300, -600)
    scene = Scene(
        objects=[
            SceneObject("ball", mesh.vertices + centre, mesh.faces),
            SceneObject("placed", mesh.vertices + centre, mesh.faces, instances=shift[None]),
        ]
    )
    rng = np.random.default_rng(81)
    n = 4000
    target = np.where(np.arange(n)[:, None] % 2 == 0, centre, centre + shift[:3, 3])
    x = target + rng.uniform(-60, 60, (n, 3))
    d = target + rng.uniform(-radius, radius, (n, 3)) - x
    d /= np.linalg.norm(d, axis=1)[:, None]
    P = g.to_model(x)
    V = g.normalize_tangent(P, g.tangent_to_model(x, d))
    out = trace(space, scene, P, V, 200.0, (1e-3, 0.0))
    triangles = np.concatenate([mesh.triangles + centre, mesh.triangles + centre + shift[:3, 3]])
    t, h = first_hits_in_double(x, d, triangles)
    hit = np.isfinite(t)
    assert hit.sum() > 2000 and np.array_equal(out["stop"] == 0, hit)
    err = np.linalg.norm(out["position"][hit] - h[hit], axis=1)
    depth_err = np.abs(out["depth"][hit] - t[hit])
    report(
        "flat torus of side 2000, hits at |x| ~ 900",
        ["hits", "max position error", "max depth error", "float32 ulp"],
        [[int(hit.sum()), float(err.max()), float(depth_err.max()), float(np.spacing(np.float32(900.0)))]],
    )
    assert err.max() <= 1e-9 and depth_err.max() <= 1e-9


def test_s2xr_hits_far_out_in_the_chart_are_refined_in_double(space_of):
    """S2xS1's chart reaches |x| = e^(2 pi) ~ 535, where float32 holds 3e-5: a ball (metric radius
    0.1) at |x| ~ 400 hit by rays from near it lies on a triangle of the mesh (and a face's plane)
    to 1e-12 relative (refined in double) and on the cover geodesic at the hit's depth within the
    tolerance asked for (metric; the flow is S2xR's closed form)."""
    space = space_of("s2xs1")
    g = space.geometry
    rng = np.random.default_rng(82)
    centre = 400.0 * np.array([0.6, -0.48, 0.64])
    radius = 0.1 * np.linalg.norm(centre)
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=radius)
    scene = Scene(objects=[SceneObject("ball", mesh.vertices + centre, mesh.faces)])
    n = 3000
    x = centre * (1 + rng.uniform(0.25, 0.3, n))[:, None] + rng.normal(size=(n, 3)) * 0.05 * np.linalg.norm(centre)
    P = g.to_model(x)
    V = g.normalize_tangent(P, g.tangent_to_model(x, centre + rng.uniform(-radius, radius, (n, 3)) - x))
    tolerance = 1e-7
    out = trace(space, scene, P, V, 2.0, (tolerance, 0.0))
    hit = out["stop"] == 0
    assert hit.sum() > 1000
    h = out["position"][hit]
    tri = mesh.triangles + centre
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    off_plane = np.min(np.abs(np.einsum("fj,nj->nf", normal, h) - np.sum(normal * tri[:, 0], axis=1)), axis=1)
    # on a triangle, not merely on some face's plane (6e-16 relative measured)
    near = trimesh.triangles.closest_point(np.tile(tri, (len(h), 1, 1)), np.repeat(h, len(tri), axis=0))
    off_mesh = np.min(np.linalg.norm(near.reshape(len(h), len(tri), 3) - h[:, None], axis=2), axis=1)
    on_curve = end_errors(space, {"end": h}, cover_ends(space, P[hit], V[hit], out["depth"][hit]))
    report(
        "s2xs1: hits at |x| ~ 400",
        ["hits", "max off plane / |x|", "max off curve (metric)", "float32 ulp / |x|"],
        [
            [
                int(hit.sum()),
                float((off_plane / np.linalg.norm(h, axis=1)).max()),
                float(on_curve.max()),
                float(np.spacing(np.float32(400.0)) / 400.0),
            ]
        ],
    )
    assert np.all(off_plane <= 1e-12 * np.linalg.norm(h, axis=1))
    assert np.all(off_mesh <= 1e-12 * np.linalg.norm(h, axis=1)), (off_mesh / np.linalg.norm(h, axis=1)).max()
    assert on_curve.max() <= tolerance
