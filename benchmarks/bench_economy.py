"""What each economy of "model only what the scene requires" saves, each on and off side by side in
one run, on a sparse and a dense scene (not a test: the machines are shared and noisy; times are
the least over --repeat interleaved runs, process CPU time of the trace where said).

Scenes, for each preset: sparse, four small balls inside the domain (bench_front.ball_scene); dense,
the default scene (the domain's edges or face frames as tubes, which cross the faces, a ring and a
sphere). Rays: the default view's frame at --size, one ray per pixel (render.camera_rays).

1. Closed forms instead of integration (per geometry, no scene): the core has no integrator for
   the geometries with closed forms (Sol's Taylor integrator is Sol's own), so each closed form
   (the C++ one the tracer uses, and the Python one, vectorised over 2000 geodesics) is measured
   against scipy's DOP853 on the geodesic equation built from the geometry's Christoffel symbols,
   one call per geodesic (what a Python user would write; its per-call overhead is part of the
   cost), per geodesic of length 5, with the largest position error of each against the Python
   closed form in extended precision (Sol: its Taylor integrators against DOP853, for scale: the
   tracer's own integrator costs what a closed form would save).
2. Empty-space steps without Embree queries: the marching kernels' walk with skip_empty on
   (through empty space to the next face without a query, by a 32^3 occupancy grid) and off
   (chords within the tolerance everywhere): Embree queries per ray, CPU µs per ray.
3. Chords sized by the pixel footprint instead of a fixed tolerance, at equal measured image
   error: the standard quality (its bound times the footprint, growing with distance) against the
   largest fixed tolerance (a power of 2 times the rule's tolerance at the camera) whose image is
   at least as accurate; image error = RMS over pixels of the largest channel difference from the
   same view at a hundredth of the rule's tolerance (normal shading: silhouettes and surfaces,
   no lights; one sample per pixel).
4. Object copies only where objects cross the domain (render.compile_scene: the copies g(object)
   of the domain's neighbours that reach it, their triangles wholly beyond a face dropped) against
   every neighbour's whole copy: triangles given to the core, the arrays' MiB, the build seconds
   and CPU µs per ray. (SL2~'s chart holds phi modulo 4 pi: whole copies of the dense scene's
   tubes along the fibre wrap across it, some of their triangles spanning 4 pi through the domain,
   so there "every" is not the same scene; its costs still compare.)

Run: .venv/bin/python benchmarks/bench_economy.py [--size 160x90] [--repeat 3] [--spaces torus,...]
     [--out docs/economy.md]
"""

import argparse
import math
import os
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import thurston_core
from bench_front import ball_scene, geodesic_equation
from scipy.integrate import solve_ivp
from timing import least_interleaved

from thurston_addon import checks, render, spaces
from thurston_addon.render import compilation
from thurston_addon.scenes import Camera, default_scene

SPACES = ["torus", "poincare", "seifert_weber", "nil", "sol", "genus2xs1", "s2xs1", "sl2"]
ROOT = Path(__file__).resolve().parents[1]


def table(title, header, rows):
    return (
        "\n".join(
            [f"### {title}\n", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            + ["| " + " | ".join(r) + " |" for r in rows]
        )
        + "\n"
    )


def frame_rays(space, settings):
    """The default view's rays (one per pixel centre) and the frame's pixel angle."""
    camera = Camera(space.camera.position, space.camera.forward, space.camera.up, space.camera.fov)
    origins, directions = render.camera_rays(space, camera, settings)
    return np.ascontiguousarray(origins), np.ascontiguousarray(directions), math.radians(camera.fov) / settings.width


def cpu_per_ray(runs, repeat, n):
    """Least process CPU µs per ray of each zero-argument run over n rays, interleaved repeat times
    (timing.least_interleaved), and the last results."""
    best, results = least_interleaved(runs, repeat)
    return [b / n * 1e6 for b in best], results


# --- 1. closed forms -------------------------------------------------------------------------------


def closed_form_rows(sid, rng, n=2000, count=20, length=5.0):
    space = spaces.load(sid)
    g = space.geometry
    x = space._interior_points(rng, n)
    P = g.to_model(x)
    V = g.normalize_tangent(P, g.tangent_to_model(x, rng.normal(size=(n, 3))))
    u = np.ascontiguousarray(g.tangent_to_chart(P, V), float)
    t = np.full(n, length)
    exact = np.asarray(g.geodesic(P.astype(np.longdouble), V.astype(np.longdouble), t)[0], float)
    t0 = time.perf_counter()
    xc, _ = thurston_core.geodesic_flow(g.name, np.ascontiguousarray(x), u, t)
    cpp = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    xp = np.asarray(g.to_chart(g.geodesic(P, V, t)[0]), float)
    python = (time.perf_counter() - t0) / n
    rhs = geodesic_equation(g)
    t0 = time.perf_counter()
    xd = np.array(
        [
            solve_ivp(rhs, (0.0, length), np.r_[x[i], u[i]], method="DOP853", rtol=1e-10, atol=1e-12).y[:3, -1]
            for i in range(count)
        ]
    )
    dop = (time.perf_counter() - t0) / count
    err = lambda a, k: f"{np.max(g.chord_distance(g.to_model(a), exact[:k])):.1e}"  # metric (SL2: phi mod 4 pi)
    name = g.name if sid != "sol" else f"{g.name} (no closed form: the C++ and Python Taylor integrators)"
    return [
        sid,
        name,
        f"{cpp * 1e6:.2f}",
        f"{python * 1e6:.2f}",
        f"{dop * 1e6:.0f}",
        f"{dop / cpp:.0f}",
        err(xc, n),
        err(xp, n),
        err(xd, count),
    ]


# --- 2. empty space --------------------------------------------------------------------------------


def empty_space_row(sid, scene_name, space, tracer, rays, tolerances, repeat):
    origins, directions, _ = rays
    limits = dict(
        max_distance=space.max_distance,
        max_crossings=space.max_crossings,
        shade=False,
        tolerance=tolerances[0],
        tolerance_per_distance=tolerances[1],
    )
    runs = [lambda skip=skip: tracer.trace(origins, directions, skip_empty=skip, **limits) for skip in (True, False)]
    (on, off), (out_on, out_off) = cpu_per_ray(runs, repeat, len(origins))
    q_on, q_off = int(out_on["chords"]) / len(origins), int(out_off["chords"]) / len(origins)
    same = np.array_equal(out_on["object"], out_off["object"])
    return [
        sid,
        scene_name,
        f"{q_on:.2f}",
        f"{q_off:.2f}",
        f"{q_off / q_on:.2f}",
        f"{on:.2f}",
        f"{off:.2f}",
        f"{off / on:.2f}",
        "yes" if same else f"{np.mean(out_on['object'] != out_off['object']):.2%} differ",
    ]


# --- 3. chords sized by the footprint ---------------------------------------------------------------


def image(space, scene, tracer, settings):
    result = render.render(space, scene, settings, tracer=tracer)
    return result.passes["color"], result.stats


def footprint_row(sid, scene_name, space, scene, tracer, size, repeat):
    base = dict(width=size[0], height=size[1], samples=1, shading="normal")
    rule = render.Settings(quality="standard", **base)
    pixel = math.radians(space.camera.fov) / size[0]
    near, per_distance = rule.tolerances(space, pixel)
    truth, _ = image(space, scene, tracer, render.Settings(tolerance=near / 100, **base))
    rms = lambda c: float(np.sqrt(np.mean(np.max(np.abs(c - truth), axis=2) ** 2)))
    colour, stats = image(space, scene, tracer, rule)
    rule_error = rms(colour)
    fixed, fixed_error = near, None
    for k in range(12):  # the largest power of 2 times `near` at least as accurate as the rule
        c, s = image(space, scene, tracer, render.Settings(tolerance=near * 2**k, **base))
        if rms(c) > rule_error:
            break
        fixed, fixed_error = near * 2**k, rms(c)
    runs = [
        lambda s=s: render.render(space, scene, s, tracer=tracer).stats
        for s in (rule, render.Settings(tolerance=fixed, **base))
    ]
    (t_rule, t_fixed), (s_rule, s_fixed) = cpu_per_ray(runs, repeat, size[0] * size[1])
    return [
        sid,
        scene_name,
        f"{near:.1e} + {per_distance:.1e} d",
        f"{fixed:.1e}",
        f"{rule_error:.4f}",
        f"{fixed_error:.4f}",
        f"{s_rule['chords_per_ray']:.2f}",
        f"{s_fixed['chords_per_ray']:.2f}",
        f"{t_rule:.2f}",
        f"{t_fixed:.2f}",
        f"{t_fixed / t_rule:.2f}",
    ]


# --- 4. copies only where objects cross the domain ---------------------------------------------------


@contextmanager
def every_neighbour_copy():
    """compile_scene with every object's whole copy under every neighbour of the domain (the
    charted ones: S3's gnomonic chart holds one hemisphere) instead of the copies that reach it."""
    kept = compilation._object_copies

    def every(space, obj, C):
        g = space.geometry
        home = checks.home_element(space, obj.vertices)
        X = g.to_model(obj.vertices) @ home.T
        whole = np.arange(len(obj.triangles))
        copies = [(X @ M.T, whole, M @ home) for M in space.neighbourhood(1) if g.charted(X @ M.T).all()]
        return copies, np.ones(len(X), bool)

    compilation._object_copies = every
    try:
        yield
    finally:
        compilation._object_copies = kept


def copies_row(sid, scene_name, space, scene, rays, tolerances, repeat):
    origins, directions, _ = rays
    built = []
    for every in (False, True):
        t0 = time.perf_counter()
        if every:
            with every_neighbour_copy():
                data = render.compile_scene(space, scene)
                tracer = render.make_tracer(space, scene)
        else:
            data = render.compile_scene(space, scene)
            tracer = render.make_tracer(space, scene)
        seconds = time.perf_counter() - t0
        mib = (data["vertices"].nbytes + data["triangles"].nbytes) / 2**20
        built.append((tracer, seconds, mib))
    limits = dict(
        max_distance=space.max_distance,
        max_crossings=space.max_crossings,
        shade=False,
        tolerance=tolerances[0],
        tolerance_per_distance=tolerances[1],
    )
    runs = [lambda t=t: t.trace(origins, directions, **limits) for t, _, _ in built]
    (on, off), (out_on, out_off) = cpu_per_ray(runs, repeat, len(origins))
    (t_on, b_on, m_on), (t_off, b_off, m_off) = built
    same = np.array_equal(out_on["object"], out_off["object"])
    return [
        sid,
        scene_name,
        str(t_on.num_triangles),
        str(t_off.num_triangles),
        f"{t_off.num_triangles / max(t_on.num_triangles, 1):.1f}",
        f"{m_on:.2f}",
        f"{m_off:.2f}",
        f"{b_on:.2f}",
        f"{b_off:.2f}",
        f"{on:.2f}",
        f"{off:.2f}",
        f"{off / on:.2f}",
        "yes" if same else f"{np.mean(out_on['object'] != out_off['object']):.2%} differ",
    ]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="160x90")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--spaces", default=",".join(SPACES))
    ap.add_argument("--out", default=str(ROOT / "docs" / "economy.md"))
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    load = os.getloadavg()[0]
    print(f"{args.size}, least of {args.repeat}, {os.cpu_count()} CPUs; load average at the start {load:.1f}\n")
    rows = {k: [] for k in ("closed", "empty", "footprint", "copies")}
    rng = np.random.default_rng(20261202)
    for sid in args.spaces.split(","):
        space = spaces.load(sid)
        curved = not space.geometry.projective
        if curved:
            rows["closed"].append(closed_form_rows(sid, rng))
        settings = render.Settings(width=size[0], height=size[1], quality="standard")
        rays = frame_rays(space, settings)
        tolerances = settings.tolerances(space, rays[2])
        for scene_name, scene in (
            ("sparse", ball_scene(space, np.random.default_rng(7), 4)[0]),
            ("dense", default_scene(space)),
        ):
            tracer = render.make_tracer(space, scene)
            if curved:
                rows["empty"].append(empty_space_row(sid, scene_name, space, tracer, rays, tolerances, args.repeat))
                rows["footprint"].append(footprint_row(sid, scene_name, space, scene, tracer, size, args.repeat))
            rows["copies"].append(copies_row(sid, scene_name, space, scene, rays, tolerances, args.repeat))
        print(f"{sid} done (load {os.getloadavg()[0]:.1f})")
    text = "\n".join(
        [
            table(
                "1. Closed forms instead of integration (µs per geodesic of length 5; error: metric distance "
                "from the closed form in extended precision)",
                [
                    "space",
                    "geometry",
                    "C++ closed form",
                    "Python closed form (vectorised)",
                    "scipy DOP853 (rtol 1e-10)",
                    "DOP853 / C++",
                    "C++ error",
                    "Python error",
                    "DOP853 error",
                ],
                rows["closed"],
            ),
            table(
                "2. Empty-space steps without Embree queries (the standard quality's chords)",
                [
                    "space",
                    "scene",
                    "queries/ray on",
                    "off",
                    "off / on",
                    "CPU µs/ray on",
                    "off",
                    "off / on",
                    "same objects hit",
                ],
                rows["empty"],
            ),
            table(
                "3. Chords sized by the pixel footprint against the cheapest fixed tolerance as accurate",
                [
                    "space",
                    "scene",
                    "footprint rule (standard)",
                    "fixed tolerance",
                    "image error: rule",
                    "fixed",
                    "chords/ray: rule",
                    "fixed",
                    "CPU µs/ray: rule",
                    "fixed",
                    "fixed / rule",
                ],
                rows["footprint"],
            ),
            table(
                "4. Copies only where objects cross the domain, against every neighbour's whole copy",
                [
                    "space",
                    "scene",
                    "triangles: crossing",
                    "every",
                    "every / crossing",
                    "MiB: crossing",
                    "every",
                    "build s: crossing",
                    "every",
                    "CPU µs/ray: crossing",
                    "every",
                    "every / crossing",
                    "same objects hit",
                ],
                rows["copies"],
            ),
        ]
    )
    header = (
        "# What each economy saves (benchmarks/bench_economy.py)\n\n"
        + __doc__.split("\n\n", 1)[1].rsplit("\n\nRun:", 1)[0]
        + f"\n\nMeasured {time.strftime('%Y-%m-%d')}, {args.size}, least of {args.repeat}, {os.cpu_count()} CPUs, "
        f"load average {load:.1f} at the start and {os.getloadavg()[0]:.1f} at the end.\n\n"
    )
    print(text)
    Path(args.out).write_text(header + text)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
