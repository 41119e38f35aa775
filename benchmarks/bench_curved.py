"""Cost and accuracy of the curved geometries (Nil, Sol), measured side by side in one run (not a
test: the machines are shared and noisy; every time is the best of --repeat runs).

For the default scene of each preset:
  1. every quality of render.QUALITY: chords (Embree queries) per ray, time per ray, the measured
     error (hits against the geodesic re-traced at 1/100 of the tolerance, in chart units and in
     pixel footprints) against the stated bound (the quality's fraction of the footprint), and the
     error against the Python reference geodesic;
  2. the saving of the empty-space steps: the preview frame's primary rays traced with
     skip_empty=True against False;
  3. the preview frame of each curved preset against the same frame of the baseline (torus, E3):
     the promise is Sol <= 10x torus;
  4. a sweep of absolute chord tolerances (Settings(tolerance=...)): error falling, cost rising;
     the errors in pixel footprints are what a quality's footprint_fraction buys;
  5. what the tolerance does to the image: each quality's colour against the same render with a
     hundredth of its footprint fraction (the chords' effect: silhouettes moved), next to its
     colour against a 64-sample render (what the sampling leaves): a fraction is loose enough when
     the first stays well below the second.
Run: .venv/bin/python benchmarks/bench_curved.py [--size 320x180] [--repeat 3] [--spaces nil,sol]
     [--baseline torus] [--tolerances 1e-2,1e-3,1e-4,1e-5,1e-6] [--tables quality,empty,frame,sweep,image]
"""

import argparse
import math
import os
import time

from thurston_addon import render, scenes, spaces


def best_render(space, scene, tracer, settings, repeat):
    """render() repeat times; its stats with the least of the measured seconds (the stats other
    than time are the same every run)."""
    runs = [render.render(space, scene, settings, tracer=tracer) for _ in range(repeat)]
    stats = runs[-1].stats
    stats["seconds"] = min(r.stats["seconds"] for r in runs)
    return stats


def table(header, rows):
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for row in rows:
        print("| " + " | ".join(row) + " |")
    print()


def load(sid):
    space = spaces.load(sid)
    scene = scenes.default_scene(space)
    return space, scene, render.make_tracer(space, scene)


def quality_rows(sid, space, scene, tracer, size, repeat):
    rows = []
    for name, level in render.QUALITY.items():
        s = best_render(space, scene, tracer, render.Settings(width=size[0], height=size[1], quality=name), repeat)
        ok = s["measured_error_pixels"] <= level.footprint_fraction
        rows.append(
            [
                sid,
                name,
                str(level.samples),
                f"{s['chords_per_ray']:.2f}",
                f"{s['seconds'] / s['rays_traced'] * 1e6:.2f}",
                f"{s['measured_error']:.1e}",
                f"{s['measured_error_pixels']:.2g}",
                f"{level.footprint_fraction:g}",
                "yes" if ok else "**NO**",
                f"{s['retrace_changed'] * 100:.1f}",
                f"{s['geodesic_error']:.1e}",
                f"{s['error_estimate_median']:.1e}",
                f"{s['error_estimate_max']:.1e}",
            ]
        )
    return rows


def image_rows(sid, space, scene, tracer, size):
    """Per quality: the colour difference made by the chords (against a hundredth of the fraction)
    and by the sampling (against 64 samples at the same fraction), RMS and 99th percentile of the
    per-pixel largest channel difference, after clipping to [0, 1] as a display would."""
    import numpy as np

    def colour(settings):
        return np.clip(render.render(space, scene, settings, tracer=tracer).passes["color"], 0, 1)

    def spread(a, b):
        d = np.abs(a - b).max(axis=2)
        return f"{np.sqrt(np.mean(d**2)):.4f}", f"{np.percentile(d, 99):.3f}"

    rows = []
    for name, level in render.QUALITY.items():
        settings = render.Settings(width=size[0], height=size[1], quality=name)
        image = colour(settings)
        tolerances = settings.tolerances(space, math.radians(space.camera.fov) / size[0])
        # the same samples with a hundredth of the chord tolerance at every distance
        render.QUALITY[name] = render.Quality(level.samples, level.footprint_fraction / 100)
        try:
            exact = colour(settings)
        finally:
            render.QUALITY[name] = level
        sampled = colour(render.Settings(width=size[0], height=size[1], quality=name, samples=64))
        rows.append(
            [
                sid,
                name,
                str(level.samples),
                f"{level.footprint_fraction:g}",
                *spread(image, exact),
                *spread(image, sampled),
                f"{tolerances[0]:.1e} + {tolerances[1]:.1e} d",
            ]
        )
    return rows


def image_table(loaded, curved, size):
    print("### What the chords do to the image, next to what the sampling does\n")
    table(
        [
            "space",
            "quality",
            "samples",
            "fraction",
            "chords RMS",
            "chords p99",
            "sampling RMS",
            "sampling p99",
            "tolerance",
        ],
        [row for sid in curved for row in image_rows(sid, *loaded[sid], size)],
    )


def preview_rays(space, size):
    """The preview frame's centre rays and its trace() limits (as render() computes them)."""
    settings = render.Settings(width=size[0], height=size[1], quality="preview")
    camera = scenes.Camera(space.camera.position, space.camera.forward, space.camera.up, space.camera.fov)
    origins, directions = render.camera_rays(space, camera, settings)
    tolerance, per_distance = settings.tolerances(space, math.radians(camera.fov) / size[0])
    return (
        origins,
        directions,
        dict(
            max_distance=space.max_distance,
            max_crossings=space.max_crossings,
            tolerance=tolerance,
            tolerance_per_distance=per_distance,
        ),
    )


def empty_space_row(sid, space, tracer, size, repeat):
    origins, directions, limits = preview_rays(space, size)
    n = len(origins)
    best, chords = {}, {}
    for _ in range(repeat):  # interleaved, so that the machine's load drifts into both alike
        for skip in (True, False):
            for shade in (False, True):
                t = time.process_time()  # CPU time: descheduling by other loads does not count
                out = tracer.trace(origins, directions, shade=shade, skip_empty=skip, **limits)
                seconds = time.process_time() - t
                best[skip, shade] = min(best.get((skip, shade), math.inf), seconds / n * 1e6)
                chords[skip] = int(out["chords"]) / n
    row = [sid, f"{chords[True]:.2f}", f"{chords[False]:.2f}", f"{chords[False] / chords[True]:.2f}"]
    for shade in (False, True):
        row += [
            f"{best[True, shade]:.2f}",
            f"{best[False, shade]:.2f}",
            f"{best[False, shade] / best[True, shade]:.2f}",
        ]
    return row


def frame_seconds(loaded, size, repeat):
    """Best seconds of the preview frame of each space, the spaces interleaved: render()'s wall time,
    and the process CPU time of its trace (all threads; less sensitive to other loads on the machine),
    shaded and unshaded (what the light paths cost)."""
    settings = render.Settings(width=size[0], height=size[1], quality="preview")
    rays = {sid: preview_rays(space, size) for sid, (space, _, _) in loaded.items()}
    wall, cpu, bare = (dict.fromkeys(loaded, math.inf) for _ in range(3))
    for _ in range(repeat):
        for sid, (space, scene, tracer) in loaded.items():
            wall[sid] = min(wall[sid], render.render(space, scene, settings, tracer=tracer).stats["seconds"])
            origins, directions, limits = rays[sid]
            for shade, best in ((True, cpu), (False, bare)):
                t = time.process_time()
                tracer.trace(origins, directions, shade=shade, **limits)
                best[sid] = min(best[sid], time.process_time() - t)
    return wall, cpu, bare


def sweep_rows(sid, space, scene, tracer, size, repeat, tolerances):
    rows = []
    for tol in tolerances:
        s = best_render(
            space,
            scene,
            tracer,
            render.Settings(width=size[0], height=size[1], quality="preview", tolerance=tol),
            repeat,
        )
        rows.append(
            [
                sid,
                f"{tol:.0e}",
                f"{s['chords_per_ray']:.2f}",
                f"{s['seconds'] / s['rays_traced'] * 1e6:.2f}",
                f"{s['measured_error']:.1e}",
                f"{s['measured_error'] / tol:.2g}",
                f"{s['measured_error_pixels']:.2g}",
                f"{s['retrace_changed'] * 100:.1f}",
                f"{s['geodesic_error']:.1e}",
            ]
        )
    return rows


def quality_table(loaded, curved, size, repeat):
    print(
        "Per quality (render(); time per traced ray, the centre pass included; measured error in chart units "
        "and in pixel footprints at the hit's distance, bound = the quality's footprint_fraction; changed = "
        "re-traced rays that met another object; estimate = the tracer's own per-hit error estimate):\n"
    )
    rows = [r for sid in curved for r in quality_rows(sid, *loaded[sid], size, repeat)]
    table(
        [
            "space",
            "quality",
            "samples",
            "chords/ray",
            "µs/ray",
            "measured error",
            "error (footprints)",
            "bound (footprints)",
            "within",
            "changed %",
            "geodesic error",
            "estimate median",
            "estimate max",
        ],
        rows,
    )


def empty_table(loaded, curved, size, repeat):
    print(
        "Empty-space steps (the preview frame's primary rays, trace(skip_empty=True) vs False, interleaved; "
        "chords = Embree queries; process CPU µs per ray (all threads); ratio = no skip / skip):\n"
    )
    rows = [empty_space_row(sid, loaded[sid][0], loaded[sid][2], size, repeat) for sid in curved]
    table(
        [
            "space",
            "chords skip",
            "chords no skip",
            "ratio",
            "CPU µs unshaded skip",
            "no skip",
            "ratio",
            "CPU µs shaded skip",
            "no skip",
            "ratio",
        ],
        rows,
    )


def frame_table(loaded, baseline, size, repeat):
    print(
        f"Preview frame against {baseline} (same size and shading, the spaces interleaved; wall = render() "
        f"seconds, CPU = process CPU seconds of the frame's trace, shaded and unshaded; target sol <= 10x):\n"
    )
    wall, cpu, bare = frame_seconds(loaded, size, max(repeat, 3))
    table(
        ["space", "wall s", f"/ {baseline}", "CPU s", f"/ {baseline}", "CPU s unshaded", f"/ {baseline}"],
        [
            [
                sid,
                f"{wall[sid]:.3f}",
                f"{wall[sid] / wall[baseline]:.2f}",
                f"{cpu[sid]:.3f}",
                f"{cpu[sid] / cpu[baseline]:.2f}",
                f"{bare[sid]:.3f}",
                f"{bare[sid] / bare[baseline]:.2f}",
            ]
            for sid in loaded
        ],
    )


def sweep_table(loaded, curved, size, repeat, tolerances):
    print(
        "Tolerance sweep (absolute chord tolerance, preview: 1 sample; measured error / tolerance <= 1 "
        "is the bound; footprints = what a footprint_fraction would have to be):\n"
    )
    rows = [r for sid in curved for r in sweep_rows(sid, *loaded[sid], size, repeat, tolerances)]
    table(
        [
            "space",
            "tolerance",
            "chords/ray",
            "µs/ray",
            "measured error",
            "/ tolerance",
            "footprints",
            "changed %",
            "geodesic error",
        ],
        rows,
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--spaces", default="nil,sol")
    ap.add_argument("--baseline", default="torus")
    ap.add_argument("--tolerances", default="1e-2,1e-3,1e-4,1e-5,1e-6")
    ap.add_argument("--tables", default="quality,empty,frame,sweep,image")
    args = ap.parse_args()
    tables = args.tables.split(",")
    size = tuple(int(v) for v in args.size.split("x"))
    curved = args.spaces.split(",")
    loaded = {sid: load(sid) for sid in [args.baseline] + curved}  # tracers built once
    print(
        f"{args.size}, default scenes, lambert shading, {loaded[curved[0]][2].num_threads} threads, "
        f"best of {args.repeat}; load average at the start {os.getloadavg()[0]:.1f}\n"
    )
    if "quality" in tables:
        quality_table(loaded, curved, size, args.repeat)
    if "empty" in tables:
        empty_table(loaded, curved, size, args.repeat)
    if "frame" in tables:
        frame_table(loaded, args.baseline, size, args.repeat)
    if "sweep" in tables:
        sweep_table(loaded, curved, size, args.repeat, [float(t) for t in args.tolerances.split(",")])
    if "image" in tables:
        image_table(loaded, curved, size)
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
