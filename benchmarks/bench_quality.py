"""The speed/accuracy trade of the quality setting, measured side by side in one run (not a test).

For each space, renders the default scene at every quality level and at a 64-sample reference, and
prints time and the colour error against the reference (RMS and 99th percentile over pixels, in
linear units, after clipping to [0, 1] as a display would). This is where the quality levels'
promise ("more samples, less aliasing") is measured rather than assumed.
Run: .venv/bin/python benchmarks/bench_quality.py [--size 320x180] [--spaces torus,poincare,seifert_weber]
"""

import argparse
import time

import numpy as np

from thurston_addon import render, scenes, spaces


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--spaces", default="torus,poincare,seifert_weber")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    print(f"{'space':<15} {'quality':<9} {'samples':>7} {'seconds':>8} {'RMS error':>10} {'p99 error':>10}")
    for sid in args.spaces.split(","):
        space = spaces.load(sid)
        scene = scenes.default_scene(space)
        tracer = render.make_tracer(space, scene)
        ref = render.render(space, scene, render.Settings(width=w, height=h, samples=64), tracer=tracer)
        ref_color = np.clip(ref.passes["color"], 0, 1)
        for quality, level in render.QUALITY.items():
            samples = level.samples
            t = time.perf_counter()
            res = render.render(space, scene, render.Settings(width=w, height=h, quality=quality), tracer=tracer)
            seconds = time.perf_counter() - t
            err = np.abs(np.clip(res.passes["color"], 0, 1) - ref_color).max(axis=2)
            print(
                f"{sid:<15} {quality:<9} {samples:>7} {seconds:>8.3f} {np.sqrt(np.mean(err**2)):>10.4f} "
                f"{np.percentile(err, 99):>10.4f}"
            )
    print("error: per-pixel max over RGB of |colour - 64-sample reference|; time excludes building the BVH")


if __name__ == "__main__":
    main()
