"""Global illumination: noise against time, measured side by side in one run (not a test).

Table 1, the default scene (a point light): direct-only and path traced (--bounces) at 1, 4, 16 and
64 samples per pixel, against a long path-traced reference (--reference-samples, other random
numbers: its own seeds start after the renders'). Per row the seconds, the time against the
direct-only render, the RMS over pixels of the brightness (mean of RGB) against the reference, and
the render's own noise estimate (the standard error of its pixel means from their samples). The
direct-only row's difference is mostly bias: the light the bounces bring. The reference's own noise
(its estimate, printed) sets the floor of the RMS column.

Table 2, the emitters' light: the default scene with its point light replaced by an emissive ball
("lamp": radius 0.04 of the inradius, the ring a metal of roughness 0.2 and the sphere varnished, a
dielectric specular layer of roughness 0.3; "metal": radius 0.15, every object a metal of roughness
0.15; --emitter-scenes), path traced at --emitter-samples samples per pixel with the emitters' light
gathered by multiple importance sampling, by the emitters' samples alone and by the bounces alone
(the tracer's emitter_sampling), with the distance limit at the light reach, so that the three
reach the same copies of the emitter. Each twice with other random numbers (the three modes
rendered in turn, interleaved, as are table 3's four renders): the noise is the RMS over
the pixels of their difference over sqrt 2 (the standard error of one render's pixels), leaving out
the pixels that see the emitter or its copies (their brightness is the emitter's) and their
neighbours; per row the seconds, that noise, the noise at equal time (noise * sqrt(seconds / the
MIS row's seconds), noise falling as 1 / sqrt(samples)) and the mean brightness of those pixels
(the three estimate one image).

Table 3, the glossy BSDF's cost: the same scene direct-only and path traced with its materials
Lambert (metallic and specular 0) and glossy, --emitter-samples samples per pixel (noise as in
table 2).
With --baseline CORE.so (another build of the core, e.g. from before a change), table 2 is measured
first with that build, in a child process, then with this one.
Run: .venv/bin/python benchmarks/bench_gi.py [--size 160x90] [--spaces poincare,torus] [--bounces 4]
     [--tables 1,2,3] [--emitter-scenes lamp,metal] [--baseline OLD/thurston_core.cpython-311-x86_64-linux-gnu.so]
"""

import argparse
import math
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
import trimesh
from timing import load_core

GI_SAMPLES = (1, 4, 16, 64)


class Sampling:
    """A tracer whose traces gather the emitters' light as `mode` says (the core's emitter_sampling),
    for render(), which does not ask for it."""

    def __init__(self, tracer, mode):
        self._tracer, self._mode = tracer, mode

    def trace(self, *args, **kwargs):
        return self._tracer.trace(*args, emitter_sampling=self._mode, **kwargs)

    def __getattr__(self, name):
        return getattr(self._tracer, name)


# The emitter scenes: the lamp's radius (of the inradius) and each object's finish (None: Lambert).
EMITTER_SCENES = {
    "lamp": (
        0.04,
        lambda name: dict(ring=dict(roughness=0.2, metallic=1.0), sphere=dict(roughness=0.3, specular=0.5)).get(name),
    ),
    "metal": (0.15, lambda name: dict(roughness=0.15, metallic=1.0)),
}


def lamp_scene(space, kind="lamp", glossy=True):
    """The default scene, its point light replaced by an emissive ball where the light was
    (radiance giving about the light's power), the objects finished as EMITTER_SCENES[kind] says
    (glossy=False: all Lambert)."""
    scene = scenes.default_scene(space)
    light = scene.lights[0]
    radius, finish_of = EMITTER_SCENES[kind]
    ball = trimesh.creation.icosphere(subdivisions=2, radius=radius * space.chart_inradius)
    # a far ball of radiance Le and metric radius r lights as a point light of intensity Le pi r^2
    radiance = light.power / (radius * space.inradius) ** 2
    lamp = scenes.SceneObject("lamp", ball.vertices + light.position, ball.faces, (0, 0, 0), (radiance,) * 3)
    objects = []
    for obj in scene.objects:
        finish = finish_of(obj.name)
        if finish and glossy:
            obj = replace(obj, materials=[scenes.Material(obj.color, name=obj.name, **finish)])
        objects.append(obj)
    return scenes.Scene(objects=objects + [lamp], lights=[])


def timed(space, scene, tracer, w, h, samples, bounces, seed=0, max_distance=None):
    settings = render.Settings(
        width=w, height=h, samples=samples, bounces=bounces, seed=seed, max_distance=max_distance
    )
    t = time.perf_counter()
    result = render.render(space, scene, settings, tracer=tracer)
    return result, time.perf_counter() - t


def brightness_rms(result, reference):
    a, b = result.passes["color"].mean(axis=2), reference.passes["color"].mean(axis=2)
    return float(np.sqrt(np.mean((a - b) ** 2)))


def twice(space, cases, w, h, samples):
    """For each case (scene, tracer, bounces, lamp): (seconds of one render, noise, mean brightness)
    from two renders with other random numbers, over the pixels whose centre ray and its neighbours'
    do not meet object `lamp`; the cases rendered in turn (interleaved: a drift of the machine's load
    falls on each alike); every geodesic (camera rays, bounces) within the light reach, so that the
    emitters' samples and the bounces reach the same copies of the emitter."""
    reach = render.default_light_reach(space)
    renders = [[] for _ in cases]
    for seed in (0, 100000):
        for done, (scene, tracer, bounces, _) in zip(renders, cases):
            done.append(timed(space, scene, tracer, w, h, samples, bounces, seed=seed, max_distance=reach))
    found = []
    for ((a, ta), (b, tb)), (_, _, _, lamp) in zip(renders, cases):
        seen = a.passes["object"] == lamp
        near = seen.copy()
        near[1:] |= seen[:-1]
        near[:-1] |= seen[1:]
        near[:, 1:] |= near[:, :-1].copy()
        near[:, :-1] |= near[:, 1:].copy()
        A, B = a.passes["color"].mean(axis=2)[~near], b.passes["color"].mean(axis=2)[~near]
        found.append((0.5 * (ta + tb), float(np.sqrt(np.mean((A - B) ** 2) / 2)), float(np.mean(A + B) / 2)))
    return found


def point_light_table(sid, args, w, h):
    space = spaces.load(sid)
    scene = scenes.default_scene(space)
    tracer = render.make_tracer(space, scene)
    reference, ref_seconds = timed(
        space, scene, tracer, w, h, args.reference_samples, args.bounces, seed=max(GI_SAMPLES)
    )
    rows = [(f"direct, {args.direct_samples} spp", *timed(space, scene, tracer, w, h, args.direct_samples, 0))]
    rows += [
        (f"{args.bounces} bounces, {n} spp", *timed(space, scene, tracer, w, h, n, args.bounces)) for n in GI_SAMPLES
    ]
    direct_seconds = rows[0][2]
    for label, result, seconds in rows:
        noise = result.stats["noise"]
        print(
            f"{sid:<10} {label:<24} {seconds:>8.2f} {seconds / direct_seconds:>9.2f} "
            f"{brightness_rms(result, reference):>11.4f} {'-' if noise is None else f'{noise:.4f}':>11}"
        )
    print(
        f"{sid:<10} {'reference, ' + str(args.reference_samples) + ' spp':<24} {ref_seconds:>8.2f} "
        f"{ref_seconds / direct_seconds:>9.2f} {'':>11} {reference.stats['noise']:>11.4f}"
    )


def emitter_table(sid, kind, args, w, h):
    space = spaces.load(sid)
    scene = lamp_scene(space, kind)
    tracer = render.make_tracer(space, scene)
    lamp = len(scene.objects) - 1
    modes = ("mis", "light", "bounce")
    found = twice(
        space, [(scene, Sampling(tracer, mode), args.bounces, lamp) for mode in modes], w, h, args.emitter_samples
    )
    rows = [(mode, *f) for mode, f in zip(modes, found)]
    mis_seconds = rows[0][1]
    for mode, seconds, noise, mean in rows:
        label = {"mis": "MIS", "light": "emitter samples only", "bounce": "bounces only"}[mode]
        print(
            f"{sid:<10} {kind:<6} {label:<22} {seconds:>8.2f} {noise:>11.4f} "
            f"{noise * math.sqrt(seconds / mis_seconds):>11.4f} {mean:>11.4f}"
        )


def glossy_table(sid, args, w, h):
    space = spaces.load(sid)
    cases, labels = [], []
    for glossy in (False, True):
        scene = lamp_scene(space, glossy=glossy)
        tracer = render.make_tracer(space, scene)
        for bounces in (0, args.bounces):
            cases.append((scene, tracer, bounces, len(scene.objects) - 1))
            labels.append(("glossy" if glossy else "Lambert", bounces))
    found = twice(space, cases, w, h, args.emitter_samples)
    rows = [(*label, seconds, noise) for label, (seconds, noise, _) in zip(labels, found)]
    for label, bounces, seconds, noise in rows:
        base = next(s for lab, b, s, _ in rows if lab == "Lambert" and b == bounces)
        what = f"{label}, " + (f"{bounces} bounces" if bounces else "direct")
        print(f"{sid:<10} {what:<24} {seconds:>8.2f} {seconds / base:>9.2f} {noise:>11.4f}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="160x90")
    ap.add_argument("--spaces", default="poincare,torus")
    ap.add_argument("--bounces", type=int, default=4)
    ap.add_argument("--direct-samples", type=int, default=16)
    ap.add_argument("--emitter-samples", type=int, default=16)
    ap.add_argument("--reference-samples", type=int, default=256)
    ap.add_argument("--emitter-scenes", default="lamp,metal")
    ap.add_argument("--tables", default="1,2,3")
    ap.add_argument("--baseline", metavar="CORE.so", help="another build of the core to measure table 2 with")
    ap.add_argument("--core", help=argparse.SUPPRESS)  # the child's core
    args = ap.parse_args()
    if args.core:
        load_core(args.core)
    global render, scenes, spaces  # imported once --core has chosen the core
    from thurston_addon import render, scenes, spaces

    if args.baseline:
        print("table 2 with the baseline build:", flush=True)
        child = [a for a in sys.argv[1:] if not a.startswith("--baseline") and a != args.baseline]
        subprocess.run([sys.executable, __file__, *child, "--tables", "2", "--core", args.baseline], check=True)
        print("\nthis build:")
    w, h = (int(v) for v in args.size.split("x"))
    tables = args.tables.split(",")
    if "1" in tables:
        print(f"{'space':<10} {'render':<24} {'seconds':>8} {'x direct':>9} {'RMS vs ref':>11} {'noise est.':>11}")
        for sid in args.spaces.split(","):
            point_light_table(sid, args, w, h)
    if "2" in tables:
        print(
            f"\n{'space':<10} {'scene':<6} {'emitters lit by':<22} {'seconds':>8} {'noise':>11} {'equal time':>11} "
            f"{'mean':>11}"
        )
        for sid in args.spaces.split(","):
            for kind in args.emitter_scenes.split(","):
                emitter_table(sid, kind, args, w, h)
    if "3" in tables:
        print(f"\n{'space':<10} {'materials':<24} {'seconds':>8} {'x Lambert':>9} {'noise':>11}")
        for sid in args.spaces.split(","):
            glossy_table(sid, args, w, h)
    print("brightness: mean of RGB, linear; seconds exclude building the BVH")


if __name__ == "__main__":
    main()
