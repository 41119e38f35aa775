"""The error/time front of every geometry: the tracer's hits against a reference that shares no code
with it, at every quality and over a sweep of chord tolerances, side by side in one run (not a
test: the machines are shared and noisy; every time of the tracer is the best of --repeat runs, its
settings interleaved); and the chord rule of the qualities (each geometry's chord_scale) derived
from it.

For one preset of each of the eight geometries (and RP3 # RP3, S2xR's folded quotient, traced
through its double cover; and graph_local, a graph of Gaussians, whose reference is DOP853 at 1e-12
of the geodesic equation from its metric): a scene of balls (icosphere meshes) inside its
domain, and rays from points of the domain, a third aimed at a ball's centre, a third at its rim
(where the chords decide what is hit) and a third anywhere. The reference for each ray is computed
here in Python: the geodesic in the universal cover from the geometry's own closed form (or its
Python integrator: Sol), sampled every --step of arclength, each sample carried into the domain by
the face pairings (spaces.move_inside: the cover's copies of the scene, met where the carried path
meets the scene), the carried path's pieces tested against the scene's triangles exactly (embreex,
on the chords between samples), the first crossing refined on the curve itself (a root of the
triangle's plane along the closed form) and kept when it lies clearly inside its triangle (rays
grazing an edge, or meeting a triangle's plane at under 3 degrees, are left out of the position
errors); and every passage of the carried path through a ball with its depth (the balls are convex:
the least distance to a face plane, in the metric).

Per space and setting: rays compared, chords (Embree queries) per ray, time per ray, the hit
position error (the metric distance between the traced and the reference hit) and the depth error
(median, 99th percentile, max), rays on which tracer and reference disagree about what is hit, the
silhouette error of every ray whose hit is not the reference's (grazing ones included): how deep
the true curve went into a ball the tracer passed, and how far a traced hit lies from the true
curve plus how far it lies off its ball, and for the qualities the stated bound (the quality's
fraction of the pixel footprint at the hit's distance, render.footprint) against the largest
measured error (positions and silhouettes) in footprints: it must bound it.

The chord rule: the chord tolerance of a quality is its bound times the geometry's chord_scale
(render.Settings.tolerances). Hits are refined on the true curve, so the tolerance moves
silhouettes by what the chords really stray, and Sol's surfaces by its integrator's accuracy (1/20
of the tolerance). At scale 1 the chords' bound K h^2 / 8 keeps silhouettes within the bound; a
larger scale is worth taking where K overstates what the curve does. For every curved geometry and
quality the sweep traces scales --scales of the bound; the scales that keep the bounds are 1 and
those above it at which, and at every scale between, each quality's error stays within its bound
and within --margin of the bound above its error at scale 1 (what the larger chords add); their
CPU times are measured side by side (interleaved), and the derived scale is the cheapest of them
up to --cap over the four qualities and the geometry's presets (E3, S3 and H3 have exact chords: the tolerance
does not apply). The cap, 4: at 8 and more the silhouettes of two exports of one scene whose
vertices lie 1e-7 apart differ by whole pixels (tests/blender/test_blender.py, RP3 # RP3), where at 4 and
less they agree to 2e-3. Scale 1 is the rule before.

Written as Markdown tables (docs/front.md) and a plot of the 99th-percentile error against the time
per ray (docs/front.png).
Run: .venv/bin/python benchmarks/bench_front.py [--rays 300] [--timing-rays 20000] [--repeat 3]
     [--spaces torus,...] [--tolerances 1e-2,...,1e-7] [--scales 1,2,4,8,16] [--margin 0.5] [--cap 4] [--out docs]
"""

import argparse
import math
import os
import time
from pathlib import Path

import numpy as np
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh
from scipy.optimize import brentq, minimize_scalar
from timing import least_interleaved

from thurston_addon import render, spaces
from thurston_addon.scenes import Scene, SceneObject

SPACES = ["torus", "poincare", "seifert_weber", "nil", "sol", "genus2xs1", "s2xs1", "rp3_rp3", "sl2", "graph_local"]
ROOT = Path(__file__).resolve().parents[1]


def ball_scene(space, rng, count=4):
    """Balls well inside the domain (their vertices, pushed out by a third, inside it), apart."""
    g = space.geometry
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    centres, radii = [], []
    for x in space._interior_points(rng, 2000):
        r = 0.1 * np.linalg.norm(x) if g.name == "S2xR" else 0.16 * space.chart_inradius
        if any(np.linalg.norm(x - c) < 1.5 * (r + q) for c, q in zip(centres, radii)):
            continue
        pushed = x + 1.35 * r * sphere.vertices
        if g.in_chart(pushed).all() and space.domain.contains(g.to_model(pushed), tol=-1e-9).all():
            centres.append(x)
            radii.append(r)
            if len(centres) == count:
                break
    objects = [
        SceneObject(f"ball{i}", c + r * sphere.vertices, sphere.faces, (0.7, 0.7, 0.7))
        for i, (c, r) in enumerate(zip(centres, radii))
    ]
    return Scene(objects=objects), np.array(centres), np.array(radii)


def rays(space, rng, n, centres, radii):
    """A third of the rays aimed at a ball's centre (give or take 15% of the distance), a third at
    its rim (0.93 to 1.03 of its radius off the centre, across the line of sight: the silhouettes),
    a third anywhere."""
    g = space.geometry
    x = space._interior_points(rng, 6 * n)
    x = x[np.all(np.linalg.norm(x[:, None] - centres[None], axis=-1) > 1.3 * radii, axis=1)][:n]
    u = rng.normal(size=(len(x), 3))
    ball = rng.integers(len(centres), size=len(x))
    towards = centres[ball] - x
    aimed, rim = np.arange(len(x)) % 3 == 0, np.arange(len(x)) % 3 == 1
    u[aimed] = towards[aimed] + 0.15 * np.linalg.norm(towards[aimed], axis=1)[:, None] * u[aimed]
    across = np.cross(towards[rim], u[rim])
    across /= np.linalg.norm(across, axis=1)[:, None]
    u[rim] = towards[rim] + rng.uniform(0.93, 1.03, (rim.sum(), 1)) * radii[ball[rim], None] * across
    P = g.to_model(x)
    return P, g.normalize_tangent(P, g.tangent_to_model(x, u))


class Ray:
    """The reference for one ray: its first hit (depth, chart point, object), (inf, None, -1) for
    none, None where it grazes (left out of the position errors); its passages through the balls
    (object, entry and exit arclength, deepest metric depth); and its path (model points at
    arclengths s)."""

    def __init__(self, first, passages, path):
        self.first, self.passages, self.path = first, passages, path


class Reference:
    """The reference's rays (see the module docstring)."""

    def __init__(self, space, scene, step):
        self.space, self.step = space, step
        self.triangles = np.concatenate([o.vertices[o.triangles] for o in scene.objects])
        self.owner = np.concatenate([np.full(len(o.triangles), i) for i, o in enumerate(scene.objects)])
        self.embree = rtcore_scene.EmbreeScene()
        TriangleMesh(self.embree, self.triangles.astype(np.float32))
        # each ball's face planes n . x <= d (n unit, outward: the balls are convex)
        self.planes = []
        for o in scene.objects:
            tri = o.vertices[o.triangles]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            n /= np.linalg.norm(n, axis=1)[:, None]
            d = np.sum(n * tri[:, 0], axis=1)
            flip = n @ o.vertices.mean(axis=0) > d
            self.planes.append((np.where(flip[:, None], -n, n), np.where(flip, -d, d)))

    def trace(self, P, V, length, path=None) -> Ray:
        """The reference of the ray (P, V) over `length`; `path(s)`: the geodesic's model points at
        arclengths s (default: the geometry's geodesic_path, its closed form, or for graph one dense
        DOP853 solution at 1e-12 of the equation from the metric)."""
        g, space = self.space.geometry, self.space
        path = path or g.geodesic_path(P, V, length + 1.0)  # (refinements look a little beyond)
        t = np.arange(0.0, length + self.step, self.step)
        X = path(t)
        Y, _, M = space.move_inside(X)
        x = np.asarray(g.to_chart(Y), float)
        x_next = np.asarray(g.to_chart(np.einsum("kij,kj->ki", M[:-1], X[1:])), float)
        if space.fold is not None:  # a folded space's walk is in its double cover: pieces in f(D) back by f
            mirrored = space.fold.mirrored(x)
            x[mirrored] = space.fold.points(x[mirrored])
            x_next[mirrored[:-1]] = space.fold.points(x_next[mirrored[:-1]])
        return Ray(self._first_hit(path, t, x, x_next), self._passages(path, t, x), path)

    def _first_hit(self, path, t, x, x_next):
        d = x_next - x[:-1]
        size = np.linalg.norm(d, axis=1)
        ok = size > 0
        direction = np.where(ok[:, None], d / np.where(ok, size, 1.0)[:, None], [1.0, 0.0, 0.0])
        found = self.embree.run(
            x[:-1].astype(np.float32),
            direction.astype(np.float32),
            dists=(size * 1.0001 + 1e-7).astype(np.float32),
            output=1,
        )
        for k in np.flatnonzero(found["primID"] >= 0):
            tri = self.triangles[found["primID"][k]]
            n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
            n /= np.linalg.norm(n)
            chart = lambda s: self._carried(path, t[k], s)[0]
            f = lambda s: n @ (chart(s) - tri[0])
            f0, f1 = f(t[k]), f(t[k + 1])
            if not (f0 * f1 < 0):
                return None  # the chord crosses, the curve does not change sides: a graze
            s = brentq(f, t[k], t[k + 1], xtol=1e-15, rtol=4 * np.finfo(float).eps)
            h = chart(s)
            if trimesh.triangles.points_to_barycentric(tri[None], h[None])[0].min() < 1e-3:
                return None  # at a triangle's edge: which one is hit is ill-posed
            velocity = chart(s + 1e-7) - chart(s - 1e-7)
            if abs(n @ velocity) < math.sin(math.radians(3)) * np.linalg.norm(velocity):
                return None
            return s, h, int(self.owner[found["primID"][k]])
        return math.inf, None, -1

    def _passages(self, path, t, x):
        """(object, entry, exit, depth) of each run of samples inside a ball, its depth the largest
        on a fine sampling about the deepest sample (a passage shorter than a step, at most
        K step^2 / 8 deep, is not seen)."""
        found = []
        for obj, (n, d) in enumerate(self.planes):
            inside = np.min(d[None] - x @ n.T, axis=1) > 0
            edges = np.flatnonzero(np.diff(np.r_[0, inside.astype(int), 0]))
            for a, b in zip(edges[::2], edges[1::2]):
                k = a + int(np.argmax(np.min(d[None] - x[a:b] @ n.T, axis=1)))
                s = np.linspace(t[max(k - 1, 0)], t[min(k + 1, len(t) - 1)], 41)
                fine = self._carried(path, t[k], s)
                depth = max(self._depth(obj, y) for y in fine)
                found.append((obj, t[max(a - 1, 0)], t[min(b, len(t) - 1)], depth))
        return sorted(found, key=lambda p: p[1])

    def _carried(self, path, s0, s):
        """Chart points of the path at arclengths s, carried by the isometry that brings s0's in
        (and by the fold where that lies in f(D))."""
        space = self.space
        Y, _, M = space.move_inside(path(np.array([s0])))
        x = np.asarray(space.geometry.to_chart(path(np.atleast_1d(s)) @ M[0].T), float)
        if space.fold is not None and space.fold.mirrored(np.asarray(space.geometry.to_chart(Y), float))[0]:
            x = space.fold.points(x)
        return x

    def _depth(self, obj, y):
        """The metric distance of the chart point y from ball obj's surface (positive inside):
        from each face plane, the chart distance over the metric length of the plane's covector."""
        g = self.space.geometry
        n, d = self.planes[obj]
        k = int(np.argmin(d - n @ y))
        return (d[k] - n[k] @ y) / math.sqrt(n[k] @ np.linalg.solve(g.metric(y), n[k]))

    def clearance(self, ray, obj, s, radius):
        """How near the ray's true curve passes ball obj about arclength s (within `radius` of
        arclength either way), in the metric: the least distance of its points from the ball's
        triangles (0 where it enters the ball)."""
        g = self.space.geometry
        tri = self.triangles[self.owner == obj]
        n, d = self.planes[obj]

        def gap(u):
            y = self._carried(ray.path, s, u)
            if np.all(y @ n.T < d[None]):
                return np.zeros(len(y)), y
            near = trimesh.triangles.closest_point(np.tile(tri, (len(y), 1, 1)), np.repeat(y, len(tri), axis=0))
            near = near.reshape(len(y), len(tri), 3)
            q = near[np.arange(len(y)), np.argmin(np.linalg.norm(near - y[:, None], axis=2), axis=1)]
            return np.asarray(g.chord_distance(g.to_model(y), g.to_model(q)), float), y

        u = np.linspace(s - radius, s + radius, 101)
        k = int(np.argmin(gap(u)[0]))
        best = minimize_scalar(
            lambda v: gap(np.array([v]))[0][0],
            bounds=(u[max(k - 1, 0)], u[min(k + 1, 100)]),
            method="bounded",
            options={"xatol": 1e-12},
        )
        return float(min(best.fun, gap(u[k : k + 1])[0][0]))

    def off_curve(self, ray, s, h):
        """The metric distance of the chart point h from the ray's true curve about arclength s."""
        g = self.space.geometry
        gap = lambda u: float(np.sum((self._carried(ray.path, s, u)[0] - h) ** 2))
        best = minimize_scalar(gap, bounds=(s - 0.02, s + 0.02), method="bounded", options={"xatol": 1e-12})
        q = self._carried(ray.path, s, best.x)[0]
        return float(g.chord_distance(g.to_model(h), g.to_model(q)))

    def silhouette_error(self, ray, hit, obj, s, h, diameter):
        """How far the traced outcome (hit or not; object obj at depth s, chart point h) is from
        one the true curve allows, in footprints: the deepest passage through a ball the tracer went
        past (at its entry), and for a hit that is not the reference's, how near the true curve
        passes the ball hit (its silhouette moved by that much would give the traced hit) plus the
        hit point's distance from the true curve (at the hit's depth)."""
        footprint = lambda depth: render.footprint(self.space, render.REFERENCE_PIXEL_ANGLE, depth)
        worst = 0.0
        for o, entry, exit_, depth in ray.passages:
            if not hit or exit_ < s - self.step or (entry < s - self.step and o != obj):
                worst = max(worst, depth / footprint(entry))
        if hit and not same_passage(ray.first, obj, s, diameter):
            worst = max(worst, (self.clearance(ray, obj, s, diameter) + self.off_curve(ray, s, h)) / footprint(s))
        return worst


def same_passage(first, obj, s, diameter):
    """Whether a traced hit (object obj at depth s) is the reference's first hit, on the same
    passage through that ball (one ball's diameter of arclength apart at most), so that its position
    error is measured; other hits are silhouettes that moved."""
    return first is not None and first[2] == obj and abs(first[0] - s) < diameter


def wavefront(space, reference, P, V, length, h):
    """Peer (b): what a Python user would write with numpy and embreex: every live ray stepped by
    chords of arclength h along the geometry's closed form (vectorised), each chord tested against
    the scene by embreex, the rays that meet nothing moved on and brought into the domain by the
    face pairings. The hit is where the chord meets the triangle (not refined on the curve).
    Returns (depth, chart hit point, object) per ray (inf, NaN, -1 for none)."""
    g = space.geometry
    n = len(P)
    depth, hit_at, obj = np.full(n, math.inf), np.full((n, 3), np.nan), np.full(n, -1)
    s = np.zeros(n)
    P, V = P.copy(), V.copy()
    live = np.arange(n)
    while live.size:
        step = np.minimum(h, length - s[live])
        X1, V1 = g.geodesic(P[live], V[live], step)
        x0, x1 = np.asarray(g.to_chart(P[live]), float), np.asarray(g.to_chart(X1), float)
        d = x1 - x0
        size = np.maximum(np.linalg.norm(d, axis=1), 1e-300)
        found = reference.embree.run(
            x0.astype(np.float32), (d / size[:, None]).astype(np.float32), dists=size.astype(np.float32), output=1
        )
        met = found["primID"] >= 0
        fraction = found["tfar"][met] / size[met]
        depth[live[met]] = s[live[met]] + fraction * step[met]
        hit_at[live[met]] = x0[met] + fraction[:, None] * d[met]
        obj[live[met]] = reference.owner[found["primID"][met]]
        rest = live[~met]
        s[rest] += step[~met]
        P[rest], V[rest], _ = space.move_inside(X1[~met], V1[~met])
        live = rest[s[rest] < length - 1e-12]
    return depth, hit_at, obj


def geodesic_equation(g):
    """x'' = -Gamma(x)(x', x') with the geometry's Christoffel symbols, the state (x, v), for solve_ivp."""

    def rhs(_t, y):
        return np.concatenate([y[3:], -np.einsum("kij,i,j->k", g.christoffel(y[:3]), y[3:], y[3:])])

    return rhs


def solve_ivp_path(space, P, V, length):
    """Peer (c), the naive accurate way: the geodesic equation with the geometry's Christoffel
    symbols, integrated per ray by scipy's DOP853 at rtol 1e-10 (dense output), as model points."""
    from scipy.integrate import solve_ivp

    g = space.geometry
    x0, v0 = np.asarray(g.to_chart(P), float), np.asarray(g.tangent_to_chart(P, V), float)
    sol = solve_ivp(
        geodesic_equation(g),
        (0.0, length),
        np.concatenate([x0, v0]),
        method="DOP853",
        rtol=1e-10,
        atol=1e-12,
        dense_output=True,
    )
    return lambda s: g.to_model(np.atleast_2d(sol.sol(np.atleast_1d(s))[:3].T))


def floor_seconds(reference, chords_per_ray, chord_length, rng, count=200000):
    """Peer (a), the floor: bare Embree (embreex, one batch) on as many chord segments per ray as
    the tracer queries, of the tracer's mean chord length, through the scene's box."""
    lo, hi = reference.triangles.reshape(-1, 3).min(axis=0), reference.triangles.reshape(-1, 3).max(axis=0)
    origins = rng.uniform(lo, hi, (count, 3)).astype(np.float32)
    d = rng.normal(size=(count, 3))
    d = (d / np.linalg.norm(d, axis=1)[:, None]).astype(np.float32)
    t0 = time.perf_counter()
    reference.embree.run(origins, d, dists=np.full(count, chord_length, np.float32), output=1)
    return (time.perf_counter() - t0) / count * chords_per_ray


def least_seconds(tracer, P, V, length, max_crossings, settings, repeat, count, clock=time.process_time):
    """Seconds per ray of each of the tolerance settings (process CPU time, all threads: time the
    machine's other loads take is not counted), the rays tiled to `count` rays, traced repeat
    times in turn (interleaved: a drift of the load falls on each alike) for the least time."""
    k = max(1, count // len(P))
    P, V = np.ascontiguousarray(np.tile(P, (k, 1))), np.ascontiguousarray(np.tile(V, (k, 1)))
    runs = [
        lambda t=tolerances: render.trace(tracer, P, V, length, max_crossings, *t, shade=False)
        for tolerances in settings
    ]
    best, _ = least_interleaved(runs, repeat, clock)
    return [b / len(P) for b in best]


def p99(a):
    return float(np.percentile(a, 99)) if len(a) else math.nan


def row(sid, name, compared, chords, seconds, pos, depth, disagree, bound, verdict):
    return (
        "| "
        + " | ".join(
            [
                sid,
                name,
                str(compared),
                chords,
                f"{seconds * 1e6:.2f}",
                fmt(pos),
                fmt(depth),
                str(disagree),
                bound,
                verdict,
            ]
        )
        + " |"
    )


def errors(space, out, firsts, radii):
    """The measured numbers over the rays with a reference first hit (firsts[i]: see Ray)."""
    g = space.geometry
    position = render.own_hits(space, out)[0] if "normal" in out else out["position"]  # a folded space's own points
    pos, depth, footprints, disagree, compared = [], [], [], 0, 0
    for i, first in enumerate(firsts):
        if first is None:
            continue
        compared += 1
        s, h, obj = first
        hit = out["stop"][i] == 0
        if math.isinf(s):
            disagree += bool(hit)
            continue
        if not (hit and same_passage(first, int(out["object"][i]), float(out["depth"][i]), 2 * radii[obj])):
            disagree += 1
            continue
        e = float(g.chord_distance(g.to_model(h), g.to_model(position[i].astype(float))))
        pos.append(e)
        depth.append(abs(float(out["depth"][i]) - s))
        footprints.append(e / render.footprint(space, render.REFERENCE_PIXEL_ANGLE, s))
    return compared, disagree, np.array(pos), np.array(depth), np.array(footprints)


def silhouettes(reference, out, refs, radii):
    """The largest silhouette error (Reference.silhouette_error) over the rays, in footprints."""
    position = render.own_hits(reference.space, out)[0]
    worst = 0.0
    for i, ray in enumerate(refs):
        hit, obj = out["stop"][i] == 0, int(out["object"][i])
        worst = max(
            worst,
            reference.silhouette_error(
                ray, hit, obj, float(out["depth"][i]), position[i].astype(float), 2 * radii[obj]
            ),
        )
    return worst


def fmt(a):
    if len(a) == 0:
        return "-"
    return " / ".join(f"{v:.1e}" for v in (np.median(a), np.percentile(a, 99), a.max()))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rays", type=int, default=300)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--spaces", default=",".join(SPACES))
    ap.add_argument("--tolerances", default="1e-2,1e-3,1e-4,1e-5,1e-6,1e-7")
    ap.add_argument("--scales", default="1,2,4,8,16", help="chord tolerances in units of a quality's bound")
    ap.add_argument(
        "--margin",
        type=float,
        default=0.5,
        help="a derived scale above 1 adds at most this fraction of the bound to the error at scale 1",
    )
    ap.add_argument(
        "--cap",
        type=float,
        default=4.0,
        help="the largest scale taken: above it, silhouettes of nearly equal scenes (1e-7 apart) differ by pixels",
    )
    ap.add_argument("--balls", type=int, default=8)
    ap.add_argument("--timing-rays", type=int, default=20000, help="the rays tiled to this many for the times")
    ap.add_argument("--step", type=float, default=2e-3, help="arclength between the reference's samples")
    ap.add_argument("--out", default=str(ROOT / "docs"))
    args = ap.parse_args()
    scales = [float(v) for v in args.scales.split(",")]
    print(
        f"{args.rays} rays per space, best of {args.repeat}, {os.cpu_count()} CPUs; load average at the start "
        f"{os.getloadavg()[0]:.1f}\n"
    )
    header = [
        "space",
        "setting",
        "rays",
        "chords/ray",
        "µs/ray (wall)",
        "position error (median / p99 / max)",
        "depth error (median / p99 / max)",
        "disagree",
        "error in footprints (positions; silhouettes) / bound",
        "within / peer's time against ours at its accuracy",
    ]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    front, sweep, cases = {}, {}, {}
    for sid in args.spaces.split(","):
        space = spaces.load(sid)
        rng = np.random.default_rng(20261201)
        scene, centres, radii = ball_scene(space, rng, args.balls)
        P, V = rays(space, rng, args.rays, centres, radii)
        P, V = np.ascontiguousarray(P), np.ascontiguousarray(V)
        length = min(8.0, 4 * space.metric_extent)
        reference = Reference(space, scene, args.step)
        t0 = time.perf_counter()
        refs = [reference.trace(P[i], V[i], length) for i in range(len(P))]
        reference_seconds = (time.perf_counter() - t0) / len(P)
        firsts = [r.first for r in refs]
        tracer = render.make_tracer(space, scene)
        cases[sid] = (space, tracer, P, V, length)
        settings = [(q, render.Settings(quality=q)) for q in render.QUALITY]
        settings += [(f"tol {t}", render.Settings(tolerance=float(t))) for t in args.tolerances.split(",")]
        ours = []  # (setting, µs per ray, p99 position error)
        tolerances_of = [s.tolerances(space, render.REFERENCE_PIXEL_ANGLE) for _, s in settings]
        # the settings' wall times side by side (interleaved), as the peers' are wall times
        seconds_of = least_seconds(
            tracer, P, V, length, 100000, tolerances_of, args.repeat, args.timing_rays, time.perf_counter
        )
        for (name, _), tolerances, seconds in zip(settings, tolerances_of, seconds_of):
            out = render.trace(tracer, P, V, length, 100000, *tolerances, shade=False)
            compared, disagree, pos, depth, fp = errors(space, out, firsts, radii)
            sil = silhouettes(reference, out, refs, radii)
            bound = render.QUALITY[name].footprint_fraction if name in render.QUALITY else None
            worst = max(float(fp.max()) if len(fp) else 0.0, sil)
            chords = float(out["chords"]) / len(P)
            if name == "standard":
                standard_chords = chords
            measured = f"{float(fp.max()) if len(fp) else 0.0:.1e}; {sil:.1e}"
            lines.append(
                row(
                    sid,
                    name,
                    compared,
                    f"{chords:.2f}",
                    seconds,
                    pos,
                    depth,
                    disagree,
                    f"{measured} / {bound}" if bound else measured,
                    ("yes" if worst <= bound else "NO") if bound else "",
                )
            )
            ours.append((name, seconds * 1e6, p99(pos)))
        front[sid] = list(ours)
        if not space.geometry.projective:
            sweep[sid] = scale_sweep(space, tracer, P, V, length, reference, refs, radii, scales)
        # the peers, each against our cheapest setting at least as accurate (by the 99th percentile)
        peers = [
            (
                "peer: bare Embree, the chords (floor)",
                floor_seconds(reference, standard_chords, 0.5 * space.extent, rng),
                None,
            )
        ]
        k = max(1, min(args.timing_rays, 3000) // len(P))  # a wavefront of thousands of rays, as a user would run
        for h in (0.1, 0.01):
            t0 = time.perf_counter()
            depth_w, at_w, obj_w = (
                a[: len(P)] for a in wavefront(space, reference, np.tile(P, (k, 1)), np.tile(V, (k, 1)), length, h)
            )
            seconds = (time.perf_counter() - t0) / (k * len(P))
            peers.append(
                (
                    f"peer: numpy + embreex, chords of {h}",
                    seconds,
                    {"stop": np.where(obj_w >= 0, 0, 1), "object": obj_w, "position": at_w, "depth": depth_w},
                )
            )
        if not space.geometry.projective:
            count = min(60, len(P))
            t0 = time.perf_counter()
            found = [
                reference.trace(P[i], V[i], length, path=solve_ivp_path(space, P[i], V[i], length)).first
                for i in range(count)
            ]
            seconds = (time.perf_counter() - t0) / count
            found += [None] * (len(P) - count)
            hit = [f is not None and math.isfinite(f[0]) for f in found]
            peers.append(
                (
                    "peer: scipy solve_ivp per ray",
                    seconds,
                    {
                        "stop": np.array([0 if h else 1 for h in hit]),
                        "object": np.array([f[2] if h else -1 for f, h in zip(found, hit)]),
                        "position": np.array([f[1] if h else [np.nan] * 3 for f, h in zip(found, hit)]),
                        "depth": np.array([f[0] if h else math.inf for f, h in zip(found, hit)]),
                    },
                )
            )
        for name, seconds, out in peers:
            if out is None:
                lines.append(row(sid, name, "", "", seconds, [], [], "", "", ""))
                continue
            compared, disagree, pos, depth, _ = errors(space, out, firsts, radii)
            match = min((r for r in ours if r[2] <= p99(pos)), key=lambda r: r[1], default=None)
            versus = f"{seconds * 1e6 / match[1]:.0f}x our {match[0]}" if match else "more accurate than ours"
            lines.append(row(sid, name, compared, "", seconds, pos, depth, disagree, "", versus))
        print(
            f"{sid}: reference {reference_seconds * 1e3:.0f} ms/ray, {sum(f is None for f in firsts)} of {len(refs)} "
            "rays left out of the position errors (grazing)"
        )
    table = "\n".join(lines)
    print("\n" + table)
    rule = chord_rule(sweep, scales, args.margin, args.cap, cases, args.repeat, args.timing_rays)
    print("\n" + rule)
    out = Path(args.out)
    out.mkdir(exist_ok=True)
    (out / "front.md").write_text(
        "# The error/time front (benchmarks/bench_front.py)\n\n"
        + "\n\n".join(__doc__.split("\n\n")[1:3])
        + f"\n\nMeasured {time.strftime('%Y-%m-%d')}: {len(P)} rays per space, {args.balls} balls, best of {args.repeat}; load average "
        f"{os.getloadavg()[0]:.1f} at the end.\n\n"
        + table
        + "\n\n## The chord rule\n\n"
        + __doc__.split("\n\n")[3]
        + "\n\n"
        + rule
        + "\n"
    )
    plot(front, out / "front.png")
    print(f"\nload average at the end {os.getloadavg()[0]:.1f}; wrote {out / 'front.md'} and {out / 'front.png'}")


def scale_sweep(space, tracer, P, V, length, reference, refs, radii, scales):
    """{quality: [(largest error in footprints / bound, chords per ray) per scale]}: each quality's
    chord tolerance at each scale of its bound."""
    firsts = [r.first for r in refs]
    found = {}
    for q, level in render.QUALITY.items():
        base = np.array(rule_tolerances(space, q))
        found[q] = []
        for scale in scales:
            out = render.trace(tracer, P, V, length, 100000, *(scale * base), shade=False)
            _, _, _, _, fp = errors(space, out, firsts, radii)
            worst = max(float(fp.max()) if len(fp) else 0.0, silhouettes(reference, out, refs, radii))
            found[q].append((worst / level.footprint_fraction, float(out["chords"]) / len(P)))
    return found


def chord_rule(sweep, scales, margin, cap, cases, repeat, count):
    """The sweep's table; for each geometry the scales that keep every quality of each of its
    presets within its bound (1, where the chords' bound K h^2 / 8 does it; those above it at
    which, and at every scale between, each quality's error stays within its bound and within
    `margin` of the bound above its error at scale 1), their CPU time measured side by side
    (interleaved), and the derived scale: the cheapest of them up to `cap` over the four qualities
    (and the geometry's presets)."""
    lines = [
        "| space | quality | " + " | ".join(f"scale {s:g}: error / bound, chords/ray" for s in scales) + " |",
        "|---|---|" + "---|" * len(scales),
    ]
    timing = [
        f"CPU µs per ray (both threads) of each scale that keeps the bounds, interleaved, least of {repeat}:\n",
        "| space | quality | " + " | ".join(f"scale {s:g}" for s in scales) + " |",
        "|---|---|" + "---|" * len(scales),
    ]
    above = [k for k, s in enumerate(scales) if s > 1]
    one = scales.index(1.0)
    keep = {}  # geometry: the scales (indices) that keep the bounds in every preset of it
    for sid, found in sweep.items():
        ok = [True] * len(scales)
        for q, cells in found.items():
            lines.append(f"| {sid} | {q} | " + " | ".join(f"{e:.2g}, {c:.2f}" for e, c in cells) + " |")
            ok = [a and e <= min(1.0, cells[one][0] + margin) for a, (e, _) in zip(ok, cells)]
        name = cases[sid][0].geometry.name
        kept = {one} | {k for k in above if all(ok[j] for j in above if j <= k)}
        keep[name] = keep.get(name, kept) & kept
    micro = {}  # (sid, quality): {scale index: CPU seconds per ray}
    for sid, found in sweep.items():
        space, tracer, P, V, length = cases[sid]
        kept = sorted(keep[space.geometry.name])
        for q in found:
            base = np.array(rule_tolerances(space, q))
            micro[sid, q] = dict(
                zip(kept, least_seconds(tracer, P, V, length, 100000, [scales[k] * base for k in kept], repeat, count))
            )
            timing.append(
                f"| {sid} | {q} | "
                + " | ".join(f"{micro[sid, q][k] * 1e6:.2f}" if k in micro[sid, q] else "-" for k in range(len(scales)))
                + " |"
            )
    saving = []
    for name, kept in keep.items():
        sids = [sid for sid in sweep if cases[sid][0].geometry.name == name]
        total = lambda k: sum(micro[sid, q][k] for sid in sids for q in sweep[sid])
        best = min((k for k in kept if scales[k] <= cap), key=total)
        final = ", ".join(
            f"{sid} {sweep[sid]['final'][one][1]:.2f} → {sweep[sid]['final'][best][1]:.2f}" for sid in sids
        )
        saving.append(
            f"{name} **{scales[best]:g}** ({1 - total(best) / total(one):.0%} of the CPU time of its presets' four "
            f"qualities; chords/ray at final: {final}; its chord_scale is "
            f"{cases[sids[0]][0].geometry.chord_scale:g})"
        )
    return "\n".join(
        lines
        + [
            "",
            *timing,
            "",
            f"Derived scales (the cheapest up to {cap:g} that keeps the bounds; saved "
            "against scale 1): " + ", ".join(saving) + ".",
        ]
    )


def rule_tolerances(space, quality):
    """The chord tolerances of a quality at scale 1: its bound's (render.Settings.tolerances over
    the geometry's chord_scale)."""
    t0, t1 = render.Settings(quality=quality).tolerances(space, render.REFERENCE_PIXEL_ANGLE)
    return t0 / space.geometry.chord_scale, t1 / space.geometry.chord_scale


def plot(front, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for sid, rows in front.items():
        sweep = [(us, e) for name, us, e in rows if name.startswith("tol") and np.isfinite(e) and e > 0]
        (line,) = ax.plot(*zip(*sweep), "-", label=sid) if sweep else ax.plot([], [], label=sid)
        qualities = [(us, e) for name, us, e in rows if not name.startswith("tol") and np.isfinite(e) and e > 0]
        if qualities:
            ax.plot(*zip(*qualities), "o", color=line.get_color())
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("µs per ray (2 threads)")
    ax.set_ylabel("99th percentile hit position error (metric)")
    ax.set_title("Error against time: tolerance sweeps (lines) and qualities (dots)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
