"""Tracer cost, measured side by side in one run (not a test: the machines are shared and noisy).

For a 640x360 frame of each space's default scene:
  - cost per chord of the full tracer (domain exits, pairings, renormalisation, the Embree query,
    double-precision hit refinement; no shading) against a bare Embree query of the very same chord
    segments on the same BVH with the same threads (target <= 1.5x);
  - 2 threads against 1 (target >= 1.8x);
  - memory: resident set growth against the size of the image's passes.
With --baseline CORE.so (another build of the core, e.g. from before a change), the tracer/bare
ratio of that build is measured too, in a child process, alternating with this build's round by
round, and the change of the ratio printed: what a change to the walk cost the isotropic path.
Run: .venv/bin/python benchmarks/bench_tracer.py [--size 640x360] [--repeat 3] [--spaces poincare,seifert_weber]
     [--baseline OLD/thurston_core.cpython-311-x86_64-linux-gnu.so --rounds 5]
"""

import argparse
import json
import resource
import subprocess
import sys

from timing import best_of, load_core


def rss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def make_tracer(space, scene, threads):
    """The tracer of whichever core is loaded (builds before the compiled-scene record took the
    arrays as keywords; builds before the geometry registry took a curvature)."""
    import thurston_core

    from thurston_addon import render

    data = render.compile_scene(space, scene)
    if hasattr(thurston_core, "Scene"):
        return thurston_core.Tracer(render.core_scene(data), threads=threads)
    if not hasattr(thurston_core, "GEOMETRIES"):
        data["curvature"] = {"E3": 0, "S3": 1, "H3": -1}[data.pop("geometry")]
    return thurston_core.Tracer(**data, threads=threads)


def frame(sid, size):
    from thurston_addon import render, scenes, spaces

    space = spaces.load(sid)
    scene = scenes.default_scene(space)
    settings = render.Settings(width=size[0], height=size[1], quality="draft")
    camera = scenes.Camera(space.camera.position, space.camera.forward, space.camera.up, space.camera.fov)
    origins, directions = render.camera_rays(space, camera, settings)
    return space, scene, origins, directions, (space.max_distance, space.max_crossings)


def ratio(sid, size, repeat):
    """(tracer ns/chord, bare ns/chord, chords) on one thread."""
    space, scene, origins, directions, limits = frame(sid, size)
    one = make_tracer(space, scene, 1)
    rec = one.trace(origins, directions, *limits, shade=False, record_segments=True)
    starts, ends = rec["segment_starts"], rec["segment_ends"]
    t1, _ = best_of(repeat, lambda: one.trace(origins, directions, *limits, shade=False))
    tb, _ = best_of(repeat, lambda: one.query_segments(starts, ends))
    return t1 / len(starts) * 1e9, tb / len(starts) * 1e9, len(starts)


def full_table(space_ids, size, repeat):
    print(
        f"{'space':<15} {'rays':>7} {'chords':>9} {'tracer ns/chord':>16} {'bare ns/chord':>14} {'ratio':>6} "
        f"{'1 thread s':>10} {'2 threads s':>11} {'speed-up':>8} {'shaded 2T s':>11} {'RSS growth MB':>13} {'passes MB':>9}"
    )
    for sid in space_ids:
        space, scene, origins, directions, limits = frame(sid, size)
        rss0 = rss_mb()
        one, two = make_tracer(space, scene, 1), make_tracer(space, scene, 2)
        rec = one.trace(origins, directions, *limits, shade=False, record_segments=True)
        starts, ends = rec["segment_starts"], rec["segment_ends"]
        chords = len(starts)
        t1, _ = best_of(repeat, lambda: one.trace(origins, directions, *limits, shade=False))
        tb, _ = best_of(repeat, lambda: one.query_segments(starts, ends))
        t2, _ = best_of(repeat, lambda: two.trace(origins, directions, *limits, shade=False))
        ts, out = best_of(repeat, lambda: two.trace(origins, directions, *limits, shade=True))
        rec = starts = ends = None  # the recorded chords freed before the memory is measured
        growth = rss_mb() - rss0
        passes_mb = sum(v.nbytes for v in out.values()) / 2**20
        print(
            f"{sid:<15} {len(origins):>7} {chords:>9} {t1 / chords * 1e9:>16.1f} {tb / chords * 1e9:>14.1f} "
            f"{t1 / tb:>6.2f} {t1:>10.3f} {t2:>11.3f} {t1 / t2:>8.2f} {ts:>11.3f} {growth:>13.1f} {passes_mb:>9.1f}"
        )
    print(
        "ratio = tracer / bare Embree on the same chords (target <= 1.5); speed-up = 1 thread / 2 threads "
        "(target >= 1.8); RSS growth includes the recorded chords (2 x 24 bytes each) used for the bare query."
    )


def child_ratio(sid, size, repeat, core=None):
    """ratio() in a fresh process (with the given build of the core, else the installed one)."""
    command = [sys.executable, __file__, "--ratio-of", sid, "--size", f"{size[0]}x{size[1]}", "--repeat", str(repeat)]
    if core:
        command += ["--core", core]
    return json.loads(subprocess.run(command, capture_output=True, text=True, check=True).stdout)


def compare(space_ids, size, repeat, baseline, rounds):
    """This build's tracer/bare ratio against the baseline build's, each in fresh processes, rounds
    alternating; each time the least of all rounds (the runs least disturbed by other work)."""
    best = {sid: {"this": (float("inf"),) * 2, "baseline": (float("inf"),) * 2} for sid in space_ids}
    for _ in range(rounds):
        for sid in space_ids:
            for who, core in (("this", None), ("baseline", baseline)):
                r = child_ratio(sid, size, repeat, core)
                best[sid][who] = (min(best[sid][who][0], r["tracer"]), min(best[sid][who][1], r["bare"]))
    print(f"\n{'space':<15} {'build':<9} {'tracer ns/chord':>16} {'bare ns/chord':>14} {'ratio':>6}")
    for sid in space_ids:
        for who in ("baseline", "this"):
            t, b = best[sid][who]
            print(f"{sid:<15} {who:<9} {t:>16.1f} {b:>14.1f} {t / b:>6.3f}")
        change = (best[sid]["this"][0] / best[sid]["this"][1]) / (
            best[sid]["baseline"][0] / best[sid]["baseline"][1]
        ) - 1
        print(f"{sid:<15} {'change':<9} {'':>16} {'':>14} {change * 100:>+5.1f}%")
    print(f"least times of {rounds} alternating rounds of {repeat} repeats each, each in a fresh process; one thread")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--spaces", default="poincare,seifert_weber")
    ap.add_argument("--baseline", metavar="CORE.so", help="another build of the core to compare the ratio with")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--core", help=argparse.SUPPRESS)  # the child's core
    ap.add_argument("--ratio-of", help=argparse.SUPPRESS)  # the child's one measurement, as JSON
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    if args.core:
        load_core(args.core)
    if args.ratio_of:
        tracer, bare, chords = ratio(args.ratio_of, size, args.repeat)
        print(json.dumps({"tracer": tracer, "bare": bare, "chords": chords}))
        return
    space_ids = args.spaces.split(",")
    full_table(space_ids, size, args.repeat)
    if args.baseline:
        compare(space_ids, size, args.repeat, args.baseline, args.rounds)


if __name__ == "__main__":
    main()
