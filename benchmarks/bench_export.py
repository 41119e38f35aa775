"""The Blender export against Cycles, side by side (not a test): one smooth UV sphere with UVs and one
material, of 250k, 1M and 4M triangles, in the torus, rendered with F12 at 8x8 pixels and one sample
by Thurston and by Cycles, each render in its own child process (real bpy), the engines taking
turns. Each child builds the scene, renders it once with a 12-triangle cube in the sphere's place
(so that what a first render loads, Cycles' kernels and Thurston's space, is not counted), then
renders the sphere: the time of that F12 and its peak memory, the peak resident set above the one
before it (the high-water mark reset by /proc/self/clear_refs). Thurston's F12 is the export from
the depsgraph, the compilation, the core's scene and its BVH, and the 64-pixel trace; Cycles' is its
synchronisation, BVH and render. Prints a table with Thurston / Cycles ratios (the least time and
memory of --repeat runs each).
Run: .venv/bin/python benchmarks/bench_export.py [--quick] [--triangles 250000,1000000,4000000]
     [--repeat 1] [--profile N] (--profile: cProfile's top functions of Thurston's F12 at N triangles)
"""

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path


def peak_reset():
    """The resident set now (bytes), the high-water mark reset to it (Linux)."""
    Path("/proc/self/clear_refs").write_text("5")
    return _status("VmRSS")


def _status(key):
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024
    raise KeyError(key)


def build_scene(engine: str, triangles: int):
    """The benchmark's scene in a fresh bpy: a smooth UV sphere of about `triangles` triangles
    (2 segments (rings - 1)), with UVs and one material, a small cube (hidden), a light, a camera."""
    import bpy

    import thurston_addon

    if not hasattr(bpy.types.Scene, "thurston"):
        thurston_addon.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = engine
    sc.render.resolution_x = sc.render.resolution_y = 8
    sc.render.resolution_percentage = 100
    sc.cycles.samples = 1
    sc.cycles.use_denoising = False
    sc.cycles.device = "CPU"
    sc.thurston.space = "torus"
    sc.thurston.scale = 1.0
    sc.thurston.quality = "draft"
    sc.thurston.samples = 1
    sc.thurston.threads = 2
    sc.render.threads_mode = "FIXED"
    sc.render.threads = 2
    sphere = bpy.data.objects.new("Sphere", sphere_mesh(triangles))
    sc.collection.objects.link(sphere)
    material = bpy.data.materials.new("Material")
    sphere.data.materials.append(material)
    bpy.ops.mesh.primitive_cube_add(size=0.2)
    cube = bpy.context.object
    cube.data.materials.append(material)
    light = bpy.data.objects.new("Light", bpy.data.lights.new("Light", "POINT"))
    light.location = (0.35, -0.35, 0.3)
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    camera.location = (0, -0.45, 0)
    camera.rotation_euler = (math.pi / 2, 0, 0)
    for obj in (light, camera):
        sc.collection.objects.link(obj)
    sc.camera = camera
    return sc, sphere, cube


def sphere_mesh(triangles: int):
    """A smooth UV sphere of radius 0.3 as quads between `rings` parallels and triangles at the
    poles, with a UV map (longitude, latitude): 2 segments (rings - 1) triangles, filled through
    foreach_set (bpy.ops' UV sphere takes minutes at 4M triangles)."""
    import bpy
    import numpy as np

    segments = max(8, round(math.sqrt(triangles)))
    rings = max(3, round(triangles / (2 * segments)) + 1)
    theta = np.pi * np.arange(1, rings) / rings  # the parallels, from the north pole
    phi = 2 * np.pi * np.arange(segments) / segments
    ring = np.stack(
        [
            np.outer(np.sin(theta), np.cos(phi)),
            np.outer(np.sin(theta), np.sin(phi)),
            np.repeat(np.cos(theta), segments).reshape(-1, segments),
        ],
        axis=-1,
    ).reshape(-1, 3)
    co = 0.3 * np.vstack([[0, 0, 1], ring, [0, 0, -1]])
    north, south = 0, len(co) - 1
    at = lambda r, s: 1 + r * segments + s % segments  # noqa: E731
    s = np.arange(segments)
    caps_n = np.stack([np.full(segments, north), at(0, s), at(0, s + 1)], -1)
    r = np.arange(rings - 2)[:, None]
    quads = np.stack([at(r, s), at(r + 1, s), at(r + 1, s + 1), at(r, s + 1)], -1).reshape(-1, 4)
    caps_s = np.stack([np.full(segments, south), at(rings - 2, s + 1), at(rings - 2, s)], -1)
    corners = np.concatenate([caps_n.ravel(), quads.ravel(), caps_s.ravel()])
    sizes = np.concatenate([np.full(segments, 3), np.full(len(quads), 4), np.full(segments, 3)])
    mesh = bpy.data.meshes.new("Sphere")
    mesh.vertices.add(len(co))
    mesh.vertices.foreach_set("co", co.astype(np.float32).ravel())
    mesh.loops.add(len(corners))
    mesh.loops.foreach_set("vertex_index", corners.astype(np.int32))
    mesh.polygons.add(len(sizes))
    mesh.polygons.foreach_set("loop_start", (np.cumsum(sizes) - sizes).astype(np.int32))
    mesh.polygons.foreach_set("loop_total", sizes.astype(np.int32))
    mesh.polygons.foreach_set("use_smooth", np.ones(len(sizes), bool))
    p = co[corners]  # the UV map: longitude and latitude of each corner
    u = (np.arctan2(p[:, 1], p[:, 0]) / (2 * np.pi)) % 1.0
    v = 0.5 + np.arcsin(np.clip(p[:, 2] / 0.3, -1, 1)) / np.pi
    mesh.uv_layers.new(name="UVMap").data.foreach_set("uv", np.stack([u, v], -1).astype(np.float32).ravel())
    mesh.update()
    return mesh


def child(engine: str, triangles: int, profile: bool) -> dict:
    """One engine's F12 of the sphere (after one of the cube), in this process."""
    import bpy

    sc, sphere, cube = build_scene(engine, triangles)
    sphere.hide_render = True
    bpy.ops.render.render()  # the first render's loading, on the cube
    sphere.hide_render, cube.hide_render = False, True
    shown = len(sphere.data.polygons)
    before = peak_reset()
    t = time.perf_counter()
    if profile:
        import cProfile
        import pstats

        with cProfile.Profile() as p:
            bpy.ops.render.render()
        stats = pstats.Stats(p, stream=sys.stderr).sort_stats("cumulative")
        stats.print_stats(40)
        stats.sort_stats("tottime").print_stats(25)
        stats.print_callers("make_tracer")
    else:
        bpy.ops.render.render()
    seconds = time.perf_counter() - t
    mesh = sphere.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    mesh.calc_loop_triangles()
    return dict(
        seconds=seconds,
        peak=_status("VmHWM") - before,
        triangles=len(mesh.loop_triangles),
        faces=shown,
        error=getattr(sc.thurston.stats, "summary", "") if engine == "THURSTON" else "",
    )


def run_child(engine: str, triangles: int) -> dict:
    out = subprocess.run(
        [sys.executable, __file__, "--child", engine, "--triangles", str(triangles)],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--triangles", default="250000,1000000,4000000")
    ap.add_argument("--quick", action="store_true", help="250k triangles only")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--child", choices=("THURSTON", "CYCLES"), help=argparse.SUPPRESS)
    ap.add_argument("--profile", type=int, metavar="N", help="profile Thurston's F12 at N triangles")
    args = ap.parse_args()
    if args.child or args.profile:
        result = child(
            args.child or "THURSTON", int(args.triangles) if args.child else args.profile, bool(args.profile)
        )
        print(json.dumps(result))
        return
    counts = [250_000] if args.quick else [int(v) for v in args.triangles.split(",")]
    print("| triangles | Thurston s | Cycles s | time ratio | Thurston MiB | Cycles MiB | memory ratio |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for n in counts:
        best = {e: dict(seconds=math.inf, peak=math.inf) for e in ("THURSTON", "CYCLES")}
        for _ in range(args.repeat):
            for engine in best:  # taking turns: a drift of the machine's load falls on both
                r = run_child(engine, n)
                best[engine] = dict(
                    seconds=min(best[engine]["seconds"], r["seconds"]),
                    peak=min(best[engine]["peak"], r["peak"]),
                    triangles=r["triangles"],
                )
        t, c = best["THURSTON"], best["CYCLES"]
        print(
            f"| {t['triangles']:,} | {t['seconds']:.2f} | {c['seconds']:.2f} | {t['seconds'] / c['seconds']:.2f} "
            f"| {t['peak'] / 2**20:.0f} | {c['peak'] / 2**20:.0f} | {t['peak'] / c['peak']:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
