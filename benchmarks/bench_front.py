"""The error/time front of every geometry: the tracer's hits against a reference that shares no code
with it, at every quality and over a sweep of chord tolerances, side by side in one run (not a
test: the machines are shared and noisy; every time is the best of --repeat runs).

For one preset of each of the eight geometries: a scene of balls (icosphere meshes) inside its
domain, and rays from points of the domain, half of them aimed at a ball. The reference for each ray
is computed here in Python: the geodesic in the universal cover from the geometry's own closed form
(or its Python integrator: Sol), sampled every --step of arclength, each sample carried into the
domain by the face pairings (spaces.move_inside: the cover's copies of the scene, met where the
carried path meets the scene), the carried path's pieces tested against the scene's triangles
exactly (embreex, on the chords between samples), the first crossing refined on the curve itself
(a root of the triangle's plane along the closed form) and kept when it lies clearly inside its
triangle (rays grazing an edge, or meeting a triangle's plane at under 3 degrees, are left out).

Per space and setting: rays compared, chords (Embree queries) per ray, time per ray, the hit
position error (the metric distance between the traced and the reference hit) and the depth error
(median, 99th percentile, max), rays on which tracer and reference disagree about what is hit, and
for the qualities the stated bound (the quality's fraction of the pixel footprint at the hit's
distance, render.Settings.tolerances) against the largest measured error in footprints: it must
bound it. Written as a Markdown table (docs/front.md) and a plot of the 99th-percentile error against
the time per ray (docs/front.png).
Run: .venv/bin/python benchmarks/bench_front.py [--rays 300] [--timing-rays 20000] [--repeat 3]
     [--spaces torus,...] [--tolerances 1e-2,1e-3,1e-4,1e-5,1e-6,1e-7] [--out docs]
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
from scipy.optimize import brentq

from thurston_addon import render, spaces
from thurston_addon.scene import Scene, SceneObject

SPACES = ["torus", "poincare", "seifert_weber", "nil", "sol", "genus2xs1", "s2xs1", "sl2"]
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
    objects = [SceneObject(f"ball{i}", c + r * sphere.vertices, sphere.faces, (0.7, 0.7, 0.7))
               for i, (c, r) in enumerate(zip(centres, radii))]
    return Scene(objects=objects), np.array(centres), np.array(radii)


def rays(space, rng, n, centres, radii):
    g = space.geometry
    x = space._interior_points(rng, 6 * n)
    x = x[np.all(np.linalg.norm(x[:, None] - centres[None], axis=-1) > 1.3 * radii, axis=1)][:n]
    u = rng.normal(size=(len(x), 3))
    aimed = np.arange(len(x)) < len(x) // 2
    towards = centres[rng.integers(len(centres), size=len(x))] - x
    u[aimed] = towards[aimed] + 0.15 * np.linalg.norm(towards[aimed], axis=1)[:, None] * u[aimed]
    P = g.to_model(x)
    return P, g.normalize_tangent(P, g.tangent_to_model(x, u))


class Reference:
    """The reference's first hits (see the module docstring)."""

    def __init__(self, space, scene, step):
        self.space, self.step = space, step
        self.triangles = np.concatenate([o.vertices[o.triangles] for o in scene.objects])
        self.owner = np.concatenate([np.full(len(o.triangles), i) for i, o in enumerate(scene.objects)])
        self.embree = rtcore_scene.EmbreeScene()
        TriangleMesh(self.embree, self.triangles.astype(np.float32))

    def first_hit(self, P, V, length, path=None):
        """(depth, chart point, object) of the first hit, (inf, None, -1) for none, None where the
        ray grazes (left out). `path(s)`: the geodesic's model points at arclengths s (default: the
        geometry's closed form)."""
        g, space = self.space.geometry, self.space
        path = path or (lambda s: g.geodesic(P[None], V[None], s)[0])
        t = np.arange(0.0, length + self.step, self.step)
        X = path(t)
        Y, _, M = space.move_inside(X)
        x = np.asarray(g.to_chart(Y), float)
        x_next = np.asarray(g.to_chart(np.einsum("kij,kj->ki", M[:-1], X[1:])), float)
        d = x_next - x[:-1]
        size = np.linalg.norm(d, axis=1)
        ok = size > 0
        direction = np.where(ok[:, None], d / np.where(ok, size, 1.0)[:, None], [1.0, 0.0, 0.0])
        found = self.embree.run(x[:-1].astype(np.float32), direction.astype(np.float32),
                                dists=(size * 1.0001 + 1e-7).astype(np.float32), output=1)
        for k in np.flatnonzero(found["primID"] >= 0):
            tri = self.triangles[found["primID"][k]]
            n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
            n /= np.linalg.norm(n)
            chart = lambda s: np.asarray(g.to_chart(M[k] @ path(np.array([s]))[0]), float)
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
        found = reference.embree.run(x0.astype(np.float32), (d / size[:, None]).astype(np.float32),
                                     dists=size.astype(np.float32), output=1)
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


def solve_ivp_path(space, P, V, length):
    """Peer (c), the naive accurate way: the geodesic equation with the geometry's Christoffel
    symbols, integrated per ray by scipy's DOP853 at rtol 1e-10 (dense output), as model points."""
    from scipy.integrate import solve_ivp

    g = space.geometry
    x0, v0 = np.asarray(g.to_chart(P), float), np.asarray(g.tangent_to_chart(P, V), float)

    def rhs(_t, y):
        return np.concatenate([y[3:], -np.einsum("kij,i,j->k", g.christoffel(y[:3]), y[3:], y[3:])])

    sol = solve_ivp(rhs, (0.0, length), np.concatenate([x0, v0]), method="DOP853", rtol=1e-10, atol=1e-12,
                    dense_output=True)
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


def timed(tracer, P, V, length, max_crossings, tolerances, repeat, count):
    """(out of the rays, seconds per ray): the rays traced, then tiled to `count` rays and traced
    repeat times for the least time."""
    out = render.trace(tracer, P, V, length, max_crossings, *tolerances, shade=False)
    k = max(1, count // len(P))
    P, V = np.ascontiguousarray(np.tile(P, (k, 1))), np.ascontiguousarray(np.tile(V, (k, 1)))
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        render.trace(tracer, P, V, length, max_crossings, *tolerances, shade=False)
        best = min(best, time.perf_counter() - t0)
    return out, best / len(P)


def p99(a):
    return float(np.percentile(a, 99)) if len(a) else math.nan


def row(sid, name, compared, chords, seconds, pos, depth, disagree, bound, verdict):
    return "| " + " | ".join([sid, name, str(compared), chords, f"{seconds * 1e6:.2f}", fmt(pos), fmt(depth),
                              str(disagree), bound, verdict]) + " |"


def errors(space, out, refs):
    """The row's measured numbers over the rays with a reference."""
    g = space.geometry
    pos, depth, footprints, disagree, compared = [], [], [], 0, 0
    for i, ref in enumerate(refs):
        if ref is None:
            continue
        compared += 1
        s, h, obj = ref
        hit = out["stop"][i] == 0
        if math.isinf(s):
            disagree += bool(hit)
            continue
        if not hit or out["object"][i] != obj:
            disagree += 1
            continue
        e = float(g.chord_distance(g.to_model(h), g.to_model(out["position"][i].astype(float))))
        pos.append(e)
        depth.append(abs(float(out["depth"][i]) - s))
        footprints.append(e / (render.REFERENCE_PIXEL_ANGLE * (s + render.NEAR_FRACTION * space.metric_extent)))
    return compared, disagree, np.array(pos), np.array(depth), np.array(footprints)


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
    ap.add_argument("--timing-rays", type=int, default=20000, help="the rays tiled to this many for the times")
    ap.add_argument("--step", type=float, default=2e-3, help="arclength between the reference's samples")
    ap.add_argument("--out", default=str(ROOT / "docs"))
    args = ap.parse_args()
    print(f"{args.rays} rays per space, best of {args.repeat}, {os.cpu_count()} CPUs; load average at the start "
          f"{os.getloadavg()[0]:.1f}\n")
    header = ["space", "setting", "rays", "chords/ray", "µs/ray", "position error (median / p99 / max)",
              "depth error (median / p99 / max)", "disagree", "error in footprints (max) / bound",
              "within / peer's time against ours at its accuracy"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    front = {}
    for sid in args.spaces.split(","):
        space = spaces.load(sid)
        rng = np.random.default_rng(20261201)
        scene, centres, radii = ball_scene(space, rng)
        P, V = rays(space, rng, args.rays, centres, radii)
        length = min(8.0, 4 * space.metric_extent)
        reference = Reference(space, scene, args.step)
        t0 = time.perf_counter()
        refs = [reference.first_hit(P[i], V[i], length) for i in range(len(P))]
        reference_seconds = (time.perf_counter() - t0) / len(P)
        tracer = render.make_tracer(space, scene)
        settings = [(q, render.Settings(quality=q)) for q in render.QUALITY]
        settings += [(f"tol {t}", render.Settings(tolerance=float(t))) for t in args.tolerances.split(",")]
        ours = []  # (setting, µs per ray, p99 position error)
        for name, s in settings:
            tolerances = s.tolerances(space, render.REFERENCE_PIXEL_ANGLE)
            out, seconds = timed(tracer, np.ascontiguousarray(P), np.ascontiguousarray(V), length, 100000,
                                 tolerances, args.repeat, args.timing_rays)
            compared, disagree, pos, depth, fp = errors(space, out, refs)
            bound = render.QUALITY[name].footprint_fraction if name in render.QUALITY else None
            worst = float(fp.max()) if len(fp) else 0.0
            chords = float(out["chords"]) / len(P)
            if name == "standard":
                standard_chords = chords
            lines.append(row(sid, name, compared, f"{chords:.2f}", seconds, pos, depth, disagree,
                             f"{worst:.1e} / {bound}" if bound else f"{worst:.1e}",
                             ("yes" if worst <= bound else "NO") if bound else ""))
            ours.append((name, seconds * 1e6, p99(pos)))
        front[sid] = list(ours)
        # the peers, each against our cheapest setting at least as accurate (by the 99th percentile)
        peers = [("peer: bare Embree, the chords (floor)", floor_seconds(reference, standard_chords, 0.5 * space.extent, rng),
                  None)]
        k = max(1, min(args.timing_rays, 3000) // len(P))  # a wavefront of thousands of rays, as a user would run
        for h in (0.1, 0.01):
            t0 = time.perf_counter()
            depth_w, at_w, obj_w = (a[:len(P)] for a in wavefront(space, reference, np.tile(P, (k, 1)),
                                                                  np.tile(V, (k, 1)), length, h))
            seconds = (time.perf_counter() - t0) / (k * len(P))
            peers.append((f"peer: numpy + embreex, chords of {h}", seconds,
                          {"stop": np.where(obj_w >= 0, 0, 1), "object": obj_w, "position": at_w, "depth": depth_w}))
        if not space.geometry.projective:
            count = min(60, len(P))
            t0 = time.perf_counter()
            found = [reference.first_hit(P[i], V[i], length, path=solve_ivp_path(space, P[i], V[i], length))
                     for i in range(count)]
            seconds = (time.perf_counter() - t0) / count
            found += [None] * (len(P) - count)
            hit = [f is not None and math.isfinite(f[0]) for f in found]
            peers.append(("peer: scipy solve_ivp per ray", seconds, {
                "stop": np.array([0 if h else 1 for h in hit]), "object": np.array([f[2] if h else -1 for f, h in zip(found, hit)]),
                "position": np.array([f[1] if h else [np.nan] * 3 for f, h in zip(found, hit)]),
                "depth": np.array([f[0] if h else math.inf for f, h in zip(found, hit)])}))
        for name, seconds, out in peers:
            if out is None:
                lines.append(row(sid, name, "", "", seconds, [], [], "", "", ""))
                continue
            compared, disagree, pos, depth, _ = errors(space, out, refs)
            match = min((r for r in ours if r[2] <= p99(pos)), key=lambda r: r[1], default=None)
            versus = f"{seconds * 1e6 / match[1]:.0f}x our {match[0]}" if match else "more accurate than ours"
            lines.append(row(sid, name, compared, "", seconds, pos, depth, disagree, "", versus))
        print(f"{sid}: reference {reference_seconds * 1e3:.0f} ms/ray, {sum(r is None for r in refs)} of {len(refs)} "
              "rays left out (grazing)")
    table = "\n".join(lines)
    print("\n" + table)
    out = Path(args.out)
    out.mkdir(exist_ok=True)
    (out / "front.md").write_text(
        "# The error/time front (benchmarks/bench_front.py)\n\n" + __doc__.split("\n\n")[1] + "\n\n" + table + "\n")
    plot(front, out / "front.png")
    print(f"\nload average at the end {os.getloadavg()[0]:.1f}; wrote {out / 'front.md'} and {out / 'front.png'}")


def plot(front, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for sid, rows in front.items():
        sweep = [(us, e) for name, us, e in rows if name.startswith("tol") and np.isfinite(e) and e > 0]
        line, = ax.plot(*zip(*sweep), "-", label=sid) if sweep else ax.plot([], [], label=sid)
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
