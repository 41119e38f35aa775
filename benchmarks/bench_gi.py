"""Global illumination: noise against time, measured side by side in one run (not a test).

For each space, renders the default scene direct-only and with path tracing (--bounces) at 1, 4,
16 and 64 samples per pixel, and a long path-traced reference (--reference-samples, other random
numbers: its own seeds start after the renders'). Prints per row the seconds, the time against
the direct-only render, the RMS over pixels of the brightness (mean of RGB) against the reference,
and the render's own noise estimate (the standard error of its pixel means from their samples).
The direct-only row's difference is mostly bias: the light the bounces bring. The reference's own
noise (its estimate, printed) sets the floor of the RMS column.
Run: .venv/bin/python benchmarks/bench_gi.py [--size 160x90] [--spaces poincare,torus] [--bounces 4]
"""
import argparse
import time

import numpy as np

from thurston_addon import render, scene as scenes, spaces

GI_SAMPLES = (1, 4, 16, 64)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="160x90")
    ap.add_argument("--spaces", default="poincare,torus")
    ap.add_argument("--bounces", type=int, default=4)
    ap.add_argument("--direct-samples", type=int, default=16)
    ap.add_argument("--reference-samples", type=int, default=256)
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    print(f"{'space':<10} {'render':<22} {'seconds':>8} {'x direct':>9} {'RMS vs ref':>11} {'noise est.':>11}")
    for sid in args.spaces.split(","):
        space = spaces.load(sid)
        scene = scenes.default_scene(space)
        tracer = render.make_tracer(space, scene)

        def run(samples, bounces, seed=0):
            settings = render.Settings(width=w, height=h, samples=samples, bounces=bounces, seed=seed)
            t = time.perf_counter()
            result = render.render(space, scene, settings, tracer=tracer)
            return result, time.perf_counter() - t

        reference, ref_seconds = run(args.reference_samples, args.bounces, seed=max(GI_SAMPLES))
        ref = reference.passes["color"].mean(axis=2)
        rows = [(f"direct, {args.direct_samples} spp", *run(args.direct_samples, 0))]
        rows += [(f"{args.bounces} bounces, {n} spp", *run(n, args.bounces)) for n in GI_SAMPLES]
        direct_seconds = rows[0][2]
        for label, result, seconds in rows:
            rms = float(np.sqrt(np.mean((result.passes["color"].mean(axis=2) - ref) ** 2)))
            noise = result.stats["noise"]
            print(f"{sid:<10} {label:<22} {seconds:>8.2f} {seconds / direct_seconds:>9.2f} {rms:>11.4f} "
                  f"{'-' if noise is None else f'{noise:.4f}':>11}")
        print(f"{sid:<10} {'reference, ' + str(args.reference_samples) + ' spp':<22} {ref_seconds:>8.2f} "
              f"{ref_seconds / direct_seconds:>9.2f} {'':>11} {reference.stats['noise']:>11.4f}")
    print("brightness: mean of RGB, linear; seconds exclude building the BVH")


if __name__ == "__main__":
    main()
