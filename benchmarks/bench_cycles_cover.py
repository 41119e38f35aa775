"""The flat torus rendered by Thurston against Cycles rendering the same scene tiled in the universal
cover (what an artist would do without Thurston), both at the same error: the time ratio (issue 19,
point 5). Not a test.

One Blender scene (bpy in this process, the add-on registered): --scene lamp, the floor under the
lamp of tests/render/test_light.py (a floor and two walls, a corridor in the cover, a point lamp),
or --scene default, the torus preset's default scene (its tubes, ring, sphere, light and camera)
built as Blender objects (nothing shadows its lamp's copies: the tiling's corner lamps beyond the
reach, which Cycles sums, make its image some 20% brighter; the lamp scene's walls shadow them, and
the two references agree there). Thurston renders it as the add-on exports it (export_scene, export_camera;
Lambert shading, light reach --cells / 2, so that the copies it sums are the ones the tiling holds);
Cycles (CPU, --threads threads, denoiser and adaptive sampling off, view transform Standard)
renders the scene tiled --cells^3 times as tests/support/blender_helpers.py tiles it (linked
duplicates of every mesh and light, every lamp lighting everything). Direct light only (Cycles'
max bounces 0; Thurston's exact sum over the lamps' copies), or with --bounces N path traced by
both (Thurston's sampled light paths then, its default).

Each renderer at a range of sample counts, least of --repeat. Thurston: the wall clock around
render.render, its tracer built beforehand. Cycles: its sampling alone, from its status "Sample 0/N"
to "Finished" (bpy.app.handlers.render_stats), and apart the whole bpy.ops.render.render call,
which also syncs the tiled scene and builds its BVH every render (persistent data would keep them,
but with it a repeated render in background mode returns the old image). Also the process's CPU
time over the same spans (both threads; robust to a busy machine). The error of each: the RMS over
the pixels of the brightness (mean of RGB) against that renderer's OWN reference (Thurston at
--thurston-reference samples, Cycles the mean of two renders of --cycles-reference samples with
other seeds, half their difference its own error, taken off in quadrature; Thurston's direct light
has no random numbers, its samples are fixed antialiasing positions), over the pixels that see the
central cell (Thurston's crossings pass 0, the border pixels left out), where the tiled cover is
the closed space, relative to the reference's mean there. Then, at target errors (Thurston's error
at --targets samples per pixel), the samples Cycles needs, interpolated in log-log between its
measured points or extrapolated along the least-squares line through its last three (marked "*"),
their time at its time per sample over those three (wall, CPU; the call: and the setup), and the
ratio Cycles / Thurston; and, without extrapolation, Cycles' most samples against
Thurston's fewest. Scene building apart: Blender's tiling (bpy copies), Cycles' setup in each
render (sync, scene update, BVH: the call less the sampling), Thurston's export and tracer build.

Run: .venv/bin/python benchmarks/bench_cycles_cover.py [--size 160x90] [--scene lamp|default]
     [--bounces 0] [--cells 7] [--repeat 1] [--quick]
"""

from __future__ import annotations

import argparse
import datetime
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from support import blender_helpers as bh  # noqa: E402

from thurston_addon import render, spaces  # noqa: E402
from thurston_addon.scenes import default_scene  # noqa: E402


# --- the scene, built in Blender -----------------------------------------------------------------
def torus_default(size):
    """The torus preset's default scene as Blender objects (scale 1): its meshes with Lambert
    materials of their colours, its point light (energy = power 4 pi^2, as export_light reads it)
    and its default camera (horizontal field of view)."""
    import bpy

    space = spaces.load("torus")
    scene = default_scene(space)
    sc = bh.fresh_scene("torus", size=size)
    for obj in scene.objects:
        mesh = bpy.data.meshes.new(obj.name)
        mesh.from_pydata(np.asarray(obj.vertices, float).tolist(), [], np.asarray(obj.triangles, int).tolist())
        mesh.update()
        b = bpy.data.objects.new(obj.name, mesh)
        b.data.materials.append(bh.lambert(bh.material(obj.name, tuple(map(float, obj.color)))))
        bh.link(b)
    for light in scene.lights:
        lamp = bh.point_light(tuple(map(float, light.position)), energy=float(light.power) * 4 * math.pi**2)
        lamp.data.color = tuple(map(float, light.color))
        lamp.data.shadow_soft_size = 0.0
    cam = space.camera
    forward = np.asarray(cam.forward, float) / np.linalg.norm(cam.forward)
    side = np.cross(forward, cam.up)
    side /= np.linalg.norm(side)
    up = np.cross(side, forward)
    c = bh.camera(tuple(map(float, cam.position)))
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = side, up, -forward, cam.position
    c.matrix_world = M.T.tolist()  # mathutils takes rows
    c.data.sensor_fit = "HORIZONTAL"
    c.data.angle = math.radians(cam.fov)
    bpy.context.view_layer.update()
    return sc


# --- Thurston --------------------------------------------------------------------------------------
def thurston_side(sc, size, threads, reach, bounces):
    """(render(samples, seed) -> (seconds, seconds, passes), building seconds, central mask,
    triangles): the Blender scene as the add-on exports it, the tracer built once."""
    import bpy

    from thurston_addon.blender import export

    t0 = time.perf_counter()
    space = spaces.load("torus")
    depsgraph = bpy.context.evaluated_depsgraph_get()
    scene = export.export_scene(depsgraph, sc.thurston.scale, [])
    camera = export.export_camera(sc, depsgraph, sc.thurston.scale, *size)
    tracer = render.make_tracer(space, scene, threads, reach)
    build = time.perf_counter() - t0

    def run(samples, seed=0):
        settings = render.Settings(
            width=size[0],
            height=size[1],
            quality="draft",
            samples=samples,
            threads=threads,
            seed=seed,
            bounces=bounces,
            light_reach=reach,
        )
        t, c = time.perf_counter(), time.process_time()
        r = render.render(space, scene, settings, camera=camera, tracer=tracer)
        seconds = time.perf_counter() - t
        return seconds, seconds, time.process_time() - c, r.passes

    passes = run(1)[-1]
    central = bh.interior(passes["crossings"] == 0) & (passes["stop"] == 0)
    return run, build, central, tracer.num_triangles


# --- Cycles ----------------------------------------------------------------------------------------
def cycles_side(sc, cells, threads, bounces, folder):
    """(render(samples, seed) -> (seconds, seconds, colour), tiling seconds, [each render's setup
    seconds: Blender's sync, Cycles' scene update and BVH], mesh objects, lights, triangles): the
    scene tiled cells^3 times, Cycles set up, a first render to load its kernels."""
    import bpy

    t0 = time.perf_counter()
    bh.tile_torus_for_cycles(sc, cells)
    tiling = time.perf_counter() - t0
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.render.threads_mode = "FIXED"
    sc.render.threads = threads
    sc.cycles.use_adaptive_sampling = False
    sc.cycles.use_denoising = False
    sc.cycles.use_animated_seed = False
    sc.cycles.max_bounces = sc.cycles.diffuse_bounces = sc.cycles.glossy_bounces = bounces
    s = sc.render.image_settings
    s.media_type = "MULTI_LAYER_IMAGE"
    s.file_format = "OPEN_EXR_MULTILAYER"
    s.color_depth = "32"
    path = folder / "cycles.exr"
    sc.render.filepath = str(path)

    events = []  # (perf_counter, Cycles' status) of the render under way
    handler = lambda status: events.append((time.perf_counter(), time.process_time(), str(status)))
    bpy.app.handlers.render_stats.append(handler)

    def run(samples, seed=0):
        """(sampling seconds, whole call seconds, sampling CPU seconds, colour); the setup's seconds
        (sync, BVH) in `setup`."""
        sc.cycles.samples = samples
        sc.cycles.seed = seed
        path.unlink(missing_ok=True)
        events.clear()
        t = time.perf_counter()
        bpy.ops.render.render(write_still=True)  # (writing a small EXR: milliseconds)
        whole = time.perf_counter() - t
        start, cpu_start = next((s, c) for s, c, status in events if "Sample 0/" in status)
        end, cpu_end = next((s, c) for s, c, status in events if status.endswith("Finished"))
        ch = bh.read_exr(path)
        colour = bh.rgb(ch, next(k[: -len("R")] for k in ch if k.endswith("Combined.R")))
        setup.append(start - t)
        return end - start, whole, cpu_end - cpu_start, colour

    setup = []
    run(1, 12345)  # Cycles' kernels loaded
    copies = sum(1 for o in sc.objects if o.type == "MESH")
    lights = sum(1 for o in sc.objects if o.type == "LIGHT")
    depsgraph = bpy.context.evaluated_depsgraph_get()
    triangles = 0
    for o in sc.objects:
        if o.type == "MESH":
            ev = o.evaluated_get(depsgraph)
            ev.data.calc_loop_triangles()
            triangles += len(ev.data.loop_triangles)
    return run, tiling, setup, copies, lights, triangles


# --- error against time --------------------------------------------------------------------------
def brightness(colour):
    return np.asarray(colour, float)[..., :3].mean(axis=-1)


def rms(image, reference, mask, floor=0.0):
    """The RMS over the mask of the brightness difference, relative to the reference's mean there,
    less (in quadrature) the reference's own relative RMS error `floor`."""
    d = brightness(image)[mask] - brightness(reference)[mask]
    raw = np.mean(d**2) / brightness(reference)[mask].mean() ** 2
    return float(np.sqrt(max(raw - floor**2, 0.0)))


def reference(run, samples, stochastic):
    """(colour, its own relative RMS error over the mask as a function of the mask, seconds): the
    mean of two renders with other seeds, whose difference over 2 (in RMS) is the mean's own error,
    where the renders are random (else one render, taken as exact)."""
    one = run(samples, 10**6)
    if not stochastic:
        return one[-1], lambda mask: 0.0, one[0]
    two = run(samples, 2 * 10**6)
    one, two, seconds = colour_of(one[-1]), colour_of(two[-1]), one[0] + two[0]
    return (one + two) / 2, lambda mask: rms(one, two, mask) / 2, seconds


def colour_of(out):
    return np.asarray(out["color"] if isinstance(out, dict) else out, float)


def samples_at(error, points, fit=3):
    """(samples, extrapolated): the samples per pixel that reach `error` along (samples, error)
    points, log-log interpolated between the bracketing points, else extrapolated along the
    least-squares line through the `fit` points nearest that end."""
    pts = sorted(points)
    n = np.log([p[0] for p in pts])
    e = np.log([max(p[1], 1e-12) for p in pts])
    target = math.log(error)
    for i in range(len(pts) - 1):
        lo, hi = sorted((e[i], e[i + 1]))
        if lo <= target <= hi and e[i] != e[i + 1]:
            f = (target - e[i]) / (e[i + 1] - e[i])
            return math.exp(n[i] + f * (n[i + 1] - n[i])), False
    end = slice(-fit, None) if target < e[-1] else slice(0, fit)
    slope, intercept = np.polyfit(e[end], n[end], 1)
    return math.exp(intercept + slope * target), True


def slope(points, fit=3):
    """The log-log slope of error against samples over the last `fit` points."""
    pts = sorted(points)[-fit:]
    return float(np.polyfit(np.log([p[0] for p in pts]), np.log([p[1] for p in pts]), 1)[0])


def measure(run, counts, repeat, seed0):
    """[(samples, least render seconds, least call seconds, least CPU seconds, colour)]: each count
    `repeat` times, each time with its own seed."""
    rows = []
    for n in counts:
        best, colour = [math.inf] * 3, None
        for k in range(repeat):
            *times, colour = run(n, seed0 + 1000 * k + n)
            best = [min(b, t) for b, t in zip(best, times)]
        rows.append((n, *best, colour))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="160x90")
    ap.add_argument("--scene", choices=("lamp", "default"), default="lamp")
    ap.add_argument("--bounces", type=int, default=0)
    ap.add_argument("--cells", type=int, default=7, help="odd: the tiling's cells a side; light reach cells / 2")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--thurston-samples", default="1,2,4,8,16")
    ap.add_argument("--cycles-samples", default="1,2,4,8,16,32,64,128,256,512")
    ap.add_argument("--thurston-reference", type=int, default=144)
    ap.add_argument("--cycles-reference", type=int, default=1024, help="samples of each of its two renders")
    ap.add_argument("--targets", default="1,4,16", help="Thurston sample counts whose errors are the targets")
    ap.add_argument("--quick", action="store_true", help="a smoke run: 96x54, fewer samples")
    a = ap.parse_args()
    if a.quick:
        a.size = "96x54"
        a.thurston_samples, a.cycles_samples = "1,4", "1,4,16,64"
        a.thurston_reference, a.cycles_reference = 64, 256
        a.targets = "1,4"
    size = tuple(int(v) for v in a.size.split("x"))
    t_counts = [int(v) for v in a.thurston_samples.split(",")]
    c_counts = [int(v) for v in a.cycles_samples.split(",")]
    targets = [int(v) for v in a.targets.split(",")]
    reach = a.cells / 2
    t_counts = sorted(set(t_counts) | set(targets))

    import bpy

    import thurston_addon

    if not hasattr(bpy.types.Scene, "thurston"):
        thurston_addon.register()
    sc = (bh.floor_under_lamp if a.scene == "lamp" else torus_default)(size)
    sc.view_settings.view_transform = "Standard"
    print(
        f"# {datetime.datetime.now():%Y-%m-%d %H:%M}  bench_cycles_cover: scene {a.scene}, {size[0]}x{size[1]}, "
        f"bounces {a.bounces}, cells {a.cells}^3 (light reach {reach}), {a.threads} threads, Blender {bpy.app.version_string}",
        flush=True,
    )

    run_t, build_t, central, tri_t = thurston_side(sc, size, a.threads, reach, a.bounces)
    print(f"Thurston: {tri_t} triangles, export and tracer build {build_t:.2f} s", flush=True)
    ref_t, floor_t, seconds = reference(run_t, a.thurston_reference, a.bounces > 0)
    ref_t = colour_of(ref_t)
    print(f"  reference {a.thurston_reference} samples: {seconds:.1f} s", flush=True)
    rows_t = [(*row[:-1], colour_of(row[-1])) for row in measure(run_t, t_counts, a.repeat, 0)]
    with tempfile.TemporaryDirectory() as tmp:
        run_c, tiling, setup, copies, lights, tri_c = cycles_side(sc, a.cells, a.threads, a.bounces, Path(tmp))
        print(
            f"Cycles: {a.cells**3} cells, {copies} mesh objects, {lights} lights, {tri_c} triangles; "
            f"Blender tiling {tiling:.2f} s",
            flush=True,
        )
        ref_c, floor_c, seconds = reference(run_c, a.cycles_reference, True)
        print(f"  reference 2 x {a.cycles_reference} samples: {seconds:.1f} s", flush=True)
        rows_c = measure(run_c, c_counts, a.repeat, 0)
    setup = sorted(setup[1:])  # (the first render's holds the kernels' loading)
    print(
        f"Cycles' setup in each render (Blender's sync, scene update, BVH; before its first sample): "
        f"median {setup[len(setup) // 2]:.3f} s, least {setup[0]:.3f} s"
    )
    floor_t, floor_c = floor_t(central), floor_c(central)
    print(
        f"\nmask: {int(central.sum())} of {size[0] * size[1]} pixels (the central cell); reference means "
        f"Thurston {brightness(ref_t)[central].mean():.4f}, Cycles {brightness(ref_c)[central].mean():.4f}; "
        f"relative RMS of their difference {rms(ref_t, ref_c, central):.4f}; the references' own relative RMS "
        f"error: Thurston {floor_t:.4f}{'' if a.bounces else ' (its colour is not random: taken as exact)'}, "
        f"Cycles {floor_c:.4f} (half their two renders' difference, taken off in quadrature below)"
    )
    errors = {}
    print(f"\n{'renderer':<9} {'samples':>7} {'render s':>9} {'call s':>7} {'CPU s':>7} {'rel. RMS':>9}")
    for name, rows, ref, floor in (("Thurston", rows_t, ref_t, floor_t), ("Cycles", rows_c, ref_c, floor_c)):
        for n, seconds, call, cpu, colour in rows:
            errors.setdefault(name, []).append((n, rms(colour, ref, central, floor)))
            print(f"{name:<9} {n:>7} {seconds:>9.3f} {call:>7.3f} {cpu:>7.3f} {errors[name][-1][1]:>9.4f}")
    # Cycles' time per sample (wall, CPU) over its last three rows, the setup of a render apart
    last = rows_c[-3:]
    per_sample = [sum(row[k] for row in last) / sum(row[0] for row in last) for k in (1, 3)]
    overhead = float(np.median([call - seconds for _, seconds, call, *_ in rows_c]))
    print(
        f"log-log slope of error against samples, last 3 points: Thurston {slope(errors['Thurston']):.2f}, "
        f"Cycles {slope(errors['Cycles']):.2f}; Cycles' time per sample {1e3 * per_sample[0]:.1f} ms "
        f"({1e3 * per_sample[1]:.1f} CPU ms), its setup {overhead:.3f} s a render"
    )
    print(
        f"\n{'at the error of':<17} {'rel. RMS':>8} {'Thurston s':>10} {'CPU s':>6} {'Cycles spp':>11} {'Cycles s':>9}"
        f" {'ratio':>6} {'call s':>7} {'ratio':>6} {'CPU s':>7} {'ratio':>6}"
    )
    for n in targets:
        i = next(i for i, row in enumerate(rows_t) if row[0] == n)
        _, seconds, _, cpu, _ = rows_t[i]
        e = errors["Thurston"][i][1]
        spp, extra = samples_at(e, errors["Cycles"])
        tc, tcpu = spp * per_sample[0], spp * per_sample[1]
        tcc = tc + overhead  # the call: the sampling and the setup of every render
        print(
            f"{f'Thurston, {n} spp':<17} {e:>8.4f} {seconds:>10.3f} {cpu:>6.2f} {spp:>10.0f}{'*' if extra else ' '}"
            f" {tc:>9.1f} {tc / seconds:>5.0f}x {tcc:>7.1f} {tcc / seconds:>5.0f}x {tcpu:>7.1f} {tcpu / cpu:>5.0f}x"
        )
    n, seconds, call, cpu, _ = rows_c[-1]
    e = errors["Cycles"][-1][1]
    n1, t1, _, c1, _ = rows_t[0]
    e1 = errors["Thurston"][0][1]
    print(
        f"Without extrapolation: Cycles at {n} samples, {seconds:.1f} s ({call:.1f} s the call, {cpu:.1f} CPU s), has "
        f"{e / e1:.1f} times the error of Thurston at {n1} sample(s), {t1:.3f} s ({c1:.3f} CPU s): "
        f"{seconds / t1:.0f}x ({call / t1:.0f}x, CPU {cpu / c1:.0f}x) the time at {'more' if e > e1 else 'less'} error."
    )
    print(
        "render s: Thurston's render call (its tracer built before); Cycles' sampling, from its first sample to "
        "Finished (wall clock).\ncall s: the whole render call (Cycles: with its setup of the tiled scene, every "
        "render). CPU s: the process's CPU time over the render s span (both threads; a busy machine's other work "
        "does not count).\nrel. RMS: of the brightness over the central cell's pixels, against the renderer's own "
        "reference, relative to its mean.\nCycles spp: the samples per pixel at which Cycles has that error, "
        "log-log interpolated between its measured points (*: extrapolated along the line through its last "
        "three); its times: those samples at its time per sample (call: and its setup).\nratio: Cycles' time over "
        "Thurston's at the same error."
    )


if __name__ == "__main__":
    main()
