"""Tracer cost, measured side by side in one run (not a test: the machines are shared and noisy).

For a 640x360 frame of each space's default scene:
  - cost per chord of the full tracer (domain exits, pairings, renormalisation, the Embree query,
    double-precision hit refinement; no shading) against a bare Embree query of the very same chord
    segments on the same BVH with the same threads (target <= 1.5x);
  - 2 threads against 1 (target >= 1.8x);
  - memory: resident set growth against the size of the image's passes.
Run: .venv/bin/python benchmarks/bench_tracer.py [--size 640x360] [--repeat 3] [--spaces poincare,seifert_weber]
"""
import argparse
import resource
import time

import numpy as np

from thurston_addon import render, scene as scenes, spaces


def best_of(repeat, fn):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def rss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--spaces", default="poincare,seifert_weber")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    print(f"{'space':<15} {'rays':>7} {'chords':>9} {'tracer ns/chord':>16} {'bare ns/chord':>14} {'ratio':>6} "
          f"{'1 thread s':>10} {'2 threads s':>11} {'speed-up':>8} {'shaded 2T s':>11} {'RSS growth MB':>13} {'passes MB':>9}")
    for sid in args.spaces.split(","):
        space = spaces.load(sid)
        scene = scenes.default_scene(space)
        settings = render.Settings(width=w, height=h, quality="draft")
        camera = scenes.Camera(space.camera.position, space.camera.forward, space.camera.up, space.camera.fov)
        origins, directions = render.camera_rays(space, camera, settings)
        rss0 = rss_mb()
        one = render.make_tracer(space, scene, threads=1)
        two = render.make_tracer(space, scene, threads=2)
        limits = (space.max_distance, space.max_crossings)
        rec = one.trace(origins, directions, *limits, shade=False, record_segments=True)
        starts, ends = rec["segment_starts"], rec["segment_ends"]
        chords = len(starts)
        t1, _ = best_of(args.repeat, lambda: one.trace(origins, directions, *limits, shade=False))
        tb, _ = best_of(args.repeat, lambda: one.query_segments(starts, ends))
        t2, _ = best_of(args.repeat, lambda: two.trace(origins, directions, *limits, shade=False))
        ts, out = best_of(args.repeat, lambda: two.trace(origins, directions, *limits, shade=True))
        del rec, starts, ends
        growth = rss_mb() - rss0
        passes_mb = sum(v.nbytes for v in out.values()) / 2**20
        print(f"{sid:<15} {len(origins):>7} {chords:>9} {t1 / chords * 1e9:>16.1f} {tb / chords * 1e9:>14.1f} "
              f"{t1 / tb:>6.2f} {t1:>10.3f} {t2:>11.3f} {t1 / t2:>8.2f} {ts:>11.3f} {growth:>13.1f} {passes_mb:>9.1f}")
    print("ratio = tracer / bare Embree on the same chords (target <= 1.5); speed-up = 1 thread / 2 threads "
          "(target >= 1.8); RSS growth includes the recorded chords (2 x 24 bytes each) used for the bare query.")


if __name__ == "__main__":
    main()
