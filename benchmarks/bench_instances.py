"""Instanced against flattened, side by side in one run (not a test): N balls on a grid of the torus,
one mesh placed N times (Embree instances) or the same triangles copied into one object. Prints
the build time (compile_scene and the tracer's BVH), the bytes of the compiled arrays, the core's
triangles, the render time of one view and the ratios flattened / instanced.
Run: .venv/bin/python benchmarks/bench_instances.py [--counts 100,1000,10000] [--size 320x180]
"""

import argparse
import time

import numpy as np
import thurston_core
import trimesh

from thurston_addon import render, spaces
from thurston_addon.scenes import Camera, PointLight, Scene, SceneObject


def balls(n: int, subdivisions: int) -> SceneObject:
    """n balls on (the first n points of) a cubic grid filling the torus' domain, by translations."""
    side = int(np.ceil(n ** (1 / 3) - 1e-9))
    c = -0.5 + (np.arange(side) + 0.5) / side
    A = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    A[:, :3, 3] = np.stack(np.meshgrid(c, c, c, indexing="ij"), -1).reshape(-1, 3)[:n]
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.3 / side)
    return SceneObject("ball", mesh.vertices, mesh.faces, instances=A)


def measure(space, scene, settings):
    t0 = time.perf_counter()
    data = render.compile_scene(space, scene)
    tracer = thurston_core.Tracer(render.core_scene(data))
    built = time.perf_counter() - t0
    nbytes = sum(v.nbytes for v in data.values() if isinstance(v, np.ndarray))
    t0 = time.perf_counter()
    render.render(space, scene, settings, tracer=tracer)
    return built, nbytes, tracer.num_triangles, time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--counts", default="100,1000,10000")
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--subdivisions", type=int, default=3, help="of the icosphere: 3 is 1280 triangles")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    space = spaces.load(spaces.preset_path("torus"))
    settings = render.Settings(width=w, height=h, quality="draft")
    camera = Camera(np.array([0.01, 0.02, 0.03]), np.array([0.3, 1.0, 0.2]), np.array([0, 0, 1.0]), 90)
    light = [PointLight(np.array([0.02, 0.01, 0.0]))]
    print(f"{'N':>6} {'kind':<10} {'build s':>8} {'arrays MiB':>10} {'core triangles':>14} {'render s':>8}")
    for n in (int(v) for v in args.counts.split(",")):
        obj = balls(n, args.subdivisions)
        rows = {}
        for kind, o in (("instanced", obj), ("flattened", obj.placed())):
            rows[kind] = measure(space, Scene([o], light, camera), settings)
            b, m, t, r = rows[kind]
            print(f"{n:>6} {kind:<10} {b:>8.3f} {m / 2**20:>10.2f} {t:>14} {r:>8.3f}")
        ratio = [f / i for f, i in zip(rows["flattened"], rows["instanced"])]
        print(f"{n:>6} {'flat/inst':<10} {ratio[0]:>8.1f} {ratio[1]:>10.1f} {ratio[2]:>14.0f} {ratio[3]:>8.2f}")


if __name__ == "__main__":
    main()
