"""Time to a clean image: this build against the previous one, side by side in one run (not a test:
the machines are shared and noisy; issue 19 point 5).

For each space's default scene and view, (a) direct light and (b) path traced (--bounces): the
previous build's render at its default settings (the exact light sum) with --direct-target samples
per pixel (direct; the standard quality's 4) or --bounce-target (path traced; 16) sets the target
error. Then for each of this build's ways to a clean image, the render time it needs to reach that
error: the exact light sum (light_paths 0 and light_map 0: the previous build's image), sampled
light (light_paths 2, 4, 8), this build's defaults where they use visibility maps (E3, S3, H3: the
point lights' geodesics looked up, with bounces the emitters' sampled as before), and the best of those (by time to the target) with adaptive sampling (noise_threshold
--adaptive-fraction x the target error), with denoising (OIDN) and with both. Per way the samples
per pixel are searched over 1, 2, 4, 8, ... until two neighbouring counts bracket the target; the
time to it is interpolated between them as error ~ time^-p, p through the two points (1/2 where the
error falls as 1/sqrt(samples)); never extrapolated: a target met at 1 sample per pixel is an upper
bound of the time (ratio >=), a way that would need more than --limit x the previous build's time
stops there (ratio <). Adaptive sampling takes every sample below its min_samples (4), so its
counts up to 4 are the same renders as without it (reused). The ways are rendered in turn, one
render of each at a time (interleaved: a drift of the machine's load falls on each alike); the
previous build renders in a child process (its own virtualenv, --baseline), before and after this
build's renders with --old-twice (its time: their mean), else before them, this build's exact
light (the same work) right after it.

Error: the RMS over the pixels of the brightness (mean of RGB) against a converged reference of this
build with the exact light sum (light_paths 0) and its own random numbers (seeds from 1000000):
two renders of --reference-samples / 2 samples with other seeds, their mean the reference, its own
noise (the RMS of their difference / 2) subtracted in quadrature from every error (the error
against the true image); with direct light from point lights the image has no random numbers (one
render, no noise to subtract; its error is that of the pixel sampling). References are cached in
--cache (keyed by their settings; --fresh renders them again). Times: each render's (its
denoising included) in process CPU time (all threads: the machine's other work, which slows the wall
clock, does not count; --clock wall: Result.stats' seconds), tracers built once per space beforehand
(not counted), 2 threads.

Run: .venv/bin/python benchmarks/bench_clean.py [--size 320x180] [--bounce-size 160x90]
     [--spaces torus,poincare,seifert_weber,nil,sl2] [--parts direct,bounces] [--baseline ../base/.venv]
     [--quick]   (a smoke run: 96x54, torus and Poincare, small references, light_paths 4)
"""

import argparse
import hashlib
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
# The exact light sum: every geodesic's shadow walk (no sampling, no visibility maps; the key of a
# cached reference says light_paths 0 for it, as before the maps)
EXACT = dict(light_paths=0, light_map=0)
REFERENCE_SEEDS = (1_000_000, 2_000_000)  # far beyond the tests' seeds (sample k draws from seed + k)
THREADS = 2


def load_api():
    """(spaces, scenes, render) of whichever build this interpreter imports (the scene module was
    thurston_addon.scene before the render package)."""
    from thurston_addon import render, spaces

    try:
        from thurston_addon import scenes
    except ImportError:
        from thurston_addon import scene as scenes
    return spaces, scenes, render


class Renderer:
    """Renders of one build in this process: each space's scene and tracer made once."""

    def __init__(self):
        self.spaces, self.scenes, self.render = load_api()
        self.made = {}

    def _space(self, sid):
        if sid not in self.made:
            space = self.spaces.load(sid)
            scene = self.scenes.default_scene(space)
            reach = self.render.light_reach_for(space, self.render.Settings())
            self.made[sid] = space, scene, self.render.make_tracer(space, scene, THREADS, reach)
        return self.made[sid]

    def maps(self, sid) -> bool:
        """Whether this build lights the space's default scene with visibility maps by default."""
        space = self._space(sid)[0]
        settings = self.render.Settings()
        return hasattr(settings, "map_texels") and settings.map_texels(space, 1e-3) > 0

    def __call__(self, sid, size, samples, bounces, seed=0, **options):
        """((CPU seconds, wall seconds), colour) of one render; options: this build's settings
        (light_paths, ...)."""
        space, scene, tracer = self._space(sid)
        settings = self.render.Settings(
            width=size[0], height=size[1], samples=samples, bounces=bounces, seed=seed, threads=THREADS, **options
        )
        cpu = time.process_time()
        result = self.render.render(space, scene, settings, tracer=tracer)
        cpu = time.process_time() - cpu
        return (cpu, result.stats["seconds"]), np.nan_to_num(result.passes["color"])


class Baseline:
    """The previous build's renders, in a child process of its own interpreter serving requests."""

    def __init__(self, venv, tmp):
        self.tmp = tmp
        self.child = subprocess.Popen(
            [str(Path(venv) / "bin" / "python"), __file__, "--serve"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=tmp,
        )

    def __call__(self, sid, size, samples, bounces, seed=0):
        out = os.path.join(self.tmp, "baseline.npy")
        request = dict(space=sid, size=size, samples=samples, bounces=bounces, seed=seed, out=out)
        self.child.stdin.write(json.dumps(request) + "\n")
        self.child.stdin.flush()
        line = self.child.stdout.readline()
        if not line:
            sys.exit("bench_clean: the baseline build's process ended (its error above)")
        return tuple(json.loads(line)["seconds"]), np.load(out)

    def close(self):
        self.child.stdin.close()
        self.child.wait()


def serve():
    """The child: one JSON request a line on stdin, the colour saved to request['out'], the seconds
    as a JSON line on stdout (the renders' own output goes to stderr)."""
    answer, sys.stdout = sys.stdout, sys.stderr
    renderer = Renderer()
    for line in sys.stdin:
        r = json.loads(line)
        seconds, color = renderer(r["space"], r["size"], r["samples"], r["bounces"], r["seed"])
        np.save(r["out"], color)
        answer.write(json.dumps({"seconds": seconds}) + "\n")
        answer.flush()


def brightness(color):
    return color.astype(np.float64).mean(axis=2)


class Reference:
    """The converged image's brightness and the variance of its own noise (mean over pixels)."""

    def __init__(self, new, sid, size, bounces, samples, cache, fresh):
        deterministic = bounces == 0 and not any(np.any(o.emission) for o in new._space(sid)[1].objects)
        key = dict(space=sid, size=list(size), bounces=bounces, samples=samples, seeds=REFERENCE_SEEDS, light_paths=0)
        digest = hashlib.sha1(json.dumps(key, sort_keys=True).encode()).hexdigest()[:12]
        path = Path(cache) / f"{sid}_{size[0]}x{size[1]}_b{bounces}_n{samples}_{digest}.npz"
        if path.exists() and not fresh:
            data = np.load(path)
            self.image, self.variance, self.seconds = data["image"], float(data["variance"]), float(data["seconds"])
            self.cached = True
            return
        if deterministic:  # one render: nothing random to average out
            (_, self.seconds), color = new(sid, size, samples, bounces, REFERENCE_SEEDS[0], **EXACT)
            self.image, self.variance = brightness(color), 0.0
        else:
            halves = [new(sid, size, samples // 2, bounces, seed, **EXACT) for seed in REFERENCE_SEEDS]
            a, b = (brightness(c) for _, c in halves)
            self.seconds = sum(s[1] for s, _ in halves)
            self.image, self.variance = (a + b) / 2, float(np.mean((a - b) ** 2) / 4)
        self.cached = False
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, image=self.image, variance=self.variance, seconds=self.seconds)

    def error(self, color):
        """The RMS brightness error against the true image (the reference's own noise taken out)."""
        return math.sqrt(max(float(np.mean((brightness(color) - self.image) ** 2)) - self.variance, 0.0))


def _at(points, n):
    """The (seconds, error) of n samples per pixel: measured already, else asked for (yielded)."""
    if n not in points:
        points[n] = yield n
    return points[n]


def search(target, limit, start=1, known=None):
    """A generator: yields the sample counts to render and is sent their (seconds, error); returns
    (seconds to the target, bound, points): bound "=" (interpolated between two neighbouring
    counts), "<=" (met at the first count) or ">" (the next count would take more than `limit`
    seconds; its seconds: the last count's)."""
    points = dict(known or {})
    n = start
    t, e = yield from _at(points, n)
    if e <= target:
        return t, "<=", points
    while e > target:  # up, by the count 1/sqrt(samples) predicts (at least doubling)
        want = n * (e / target) ** 2
        nxt = max(2 * n, 2 ** math.ceil(math.log2(want)))
        if t * nxt / n > limit:
            nxt = 2 * n  # the prediction may overshoot: try the next count within the limit
            if t * nxt / n > limit:
                return t, ">", points
        n = nxt
        t, e = yield from _at(points, n)
    hi = n  # error at the target or below; bisect (over powers of 2) down to its neighbour
    lo = max(m for m in points if m < hi and points[m][1] > target)
    while hi > 2 * lo:
        mid = 2 ** ((int(math.log2(lo)) + int(math.log2(hi))) // 2)
        _, e = yield from _at(points, mid)
        lo, hi = (mid, hi) if e > target else (lo, mid)
        lo = max(m for m in points if m < hi and points[m][1] > target)
    (t1, e1), (t2, e2) = points[lo], points[hi]
    if e2 <= 0:
        return t2, "=", points
    p = math.log(t2 / t1) / math.log(e1 / e2)  # error ~ time^(-1/p) between the two
    return t1 * (e1 / target) ** p, "=", points


def interleave(searches, measure):
    """Run the searches {name: generator} one render of each at a time; measure(name, n) -> (seconds,
    error). Returns {name: the search's result}."""
    results, asked = {}, {}
    for name, gen in searches.items():
        try:
            asked[name] = gen.send(None)
        except StopIteration as done:
            results[name] = done.value
    while asked:
        for name in list(asked):
            try:
                asked[name] = searches[name].send(measure(name, asked[name]))
            except StopIteration as done:
                results[name] = done.value
                del asked[name]
    return results


def label(options):
    lp = options.get("light_paths", 0)
    if options.get("light_map", None) is None:
        parts = ["visibility maps" + (f", light_paths {lp}" if lp else "")]
    else:
        parts = ["exact light" if lp == 0 else f"light_paths {lp}"]
    if options.get("noise_threshold"):
        parts.append(f"adaptive {options['noise_threshold']:.2g}")
    if options.get("denoise"):
        parts.append("denoise")
    return " + ".join(parts)


def cell(old_seconds, found):
    seconds, bound, _ = found
    ratio = old_seconds / seconds
    sign = {"=": "", "<=": ">=", ">": "<"}[bound]
    return f"{sign}{ratio:.2g}x"


def measure_part(sid, part, args, new, old, out):
    bounces = 0 if part == "direct" else args.bounces
    size = args.size if part == "direct" else args.bounce_size
    n_old = args.direct_target if part == "direct" else args.bounce_target
    ref_samples = args.direct_reference if part == "direct" else args.bounce_reference
    ref = Reference(new, sid, size, bounces, ref_samples, args.cache, args.fresh)
    where = "cached" if ref.cached else f"rendered, {ref.seconds:.0f} s"
    tag = f"{sid:<14} {part:<8}"
    print(
        f"{tag} reference: {ref_samples} spp exact light ({where}), own noise {math.sqrt(ref.variance):.4f}",
        flush=True,
    )

    clock = 1 if args.clock == "wall" else 0  # the renders give (CPU seconds, wall seconds)
    t_old1, c_old = old(sid, size, n_old, bounces)
    t_old1 = t_old1[clock]
    target = ref.error(c_old)
    t_exact, c_exact = new(sid, size, n_old, bounces, **EXACT)
    t_exact = t_exact[clock]
    same = float(np.max(np.abs(c_exact - c_old)))
    limit = args.limit * t_old1

    def render_ladder(options):
        return lambda n: (lambda t_c: (t_c[0][clock], ref.error(t_c[1])))(new(sid, size, n, bounces, **options))

    ways = {f"light_paths {lp}": dict(light_paths=lp, light_map=0) for lp in args.light_paths}
    if new.maps(sid):  # this build's default: the visibility maps (with bounces, sampled emitters too)
        ways["visibility maps"] = {}
    searches = {name: search(target, limit) for name in ways}
    measure = lambda name, n: render_ladder(ways[name])(n)
    found = interleave(searches, measure)
    e_exact = ref.error(c_exact)  # the previous build's error where the images agree
    found["exact light"] = (t_exact, "=" if e_exact <= target * 1.001 else ">", {n_old: (t_exact, e_exact)})
    ways["exact light"] = EXACT
    light = min(found, key=lambda name: found[name][0] if found[name][1] != ">" else math.inf)
    best = ways[light]
    threshold = args.adaptive_fraction * target
    combos = {
        "+ adaptive": dict(best, noise_threshold=threshold),
        "+ denoise": dict(best, denoise=True),
        "+ adaptive + denoise": dict(best, noise_threshold=threshold, denoise=True),
    }
    # adaptive sampling takes every sample up to its min_samples (4): those counts are the renders without it
    upto4 = lambda points: {n: v for n, v in points.items() if n <= 4}
    measure = lambda name, n: render_ladder(combos[name])(n)
    searches = {
        "+ adaptive": search(target, limit, known=upto4(found[light][2])),
        "+ denoise": search(target, limit),
    }
    found.update(interleave(searches, measure))
    searches = {"+ adaptive + denoise": search(target, limit, known=upto4(found["+ denoise"][2]))}
    found.update(interleave(searches, measure))
    t_old, again = t_old1, ""
    if args.old_twice:
        t_old2, c_old2 = old(sid, size, n_old, bounces)
        t_old2 = t_old2[clock]
        t_old = (t_old1 + t_old2) / 2
        again = f" / {t_old2:.2f} s (again, differs by {float(np.max(np.abs(c_old2 - c_old))):.2g})"
    print(
        f"{tag} previous build, {n_old} spp: {t_old1:.2f} s{again}, error {target:.4f} (the target); this "
        f"build's exact light: {t_exact:.2f} s, differs by {same:.2g}",
        flush=True,
    )
    for name in [*ways, *combos]:
        seconds, bound, points = found[name]
        what = label(ways[name] if name in ways else combos[name])
        ladder = "  ".join(f"{n}:{t:.2f}s/{e:.4f}" for n, (t, e) in sorted(points.items()))
        print(f"{tag}   {what:<40} {ladder:<70} -> {bound}{seconds:.2f} s, {cell(t_old, found[name])}", flush=True)
    row = dict(
        space=sid,
        part=part,
        size=list(size),
        old_samples=n_old,
        old_seconds=t_old,
        target=target,
        exact=cell(t_old, found["exact light"]),
        light=light,
        cells={name: cell(t_old, found[name]) for name in [*ways, *combos]},
        found={name: [found[name][0], found[name][1], sorted(found[name][2].items())] for name in found},
        same=same,
    )
    out.append(row)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="320x180", help="direct light's image size")
    ap.add_argument("--bounce-size", default="160x90", help="the path-traced part's image size")
    ap.add_argument("--spaces", default="torus,poincare,seifert_weber,nil,sl2")
    ap.add_argument("--parts", default="direct,bounces")
    ap.add_argument("--bounces", type=int, default=4)
    ap.add_argument("--direct-target", type=int, default=4, help="the previous build's samples setting the target")
    ap.add_argument("--bounce-target", type=int, default=16)
    ap.add_argument("--direct-reference", type=int, default=64, help="the reference's samples per pixel")
    ap.add_argument("--bounce-reference", type=int, default=64)
    ap.add_argument("--light-paths", default="2,4,8")
    ap.add_argument("--adaptive-fraction", type=float, default=0.5, help="noise threshold / target error")
    ap.add_argument("--clock", choices=("cpu", "wall"), default="cpu", help="process CPU seconds or wall seconds")
    ap.add_argument("--old-twice", action="store_true", help="the previous build's render again after the others")
    ap.add_argument("--limit", type=float, default=1.5, help="no render past this x the previous build's time")
    ap.add_argument("--baseline", default=str(HERE.parent / "base" / ".venv"), help="the previous build's virtualenv")
    ap.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "thurston_bench_clean"))
    ap.add_argument("--fresh", action="store_true", help="render the references again")
    ap.add_argument("--json", help="write the results here too")
    ap.add_argument("--quick", action="store_true", help="a smoke run (96x54, torus and poincare, light_paths 4)")
    ap.add_argument("--serve", action="store_true", help=argparse.SUPPRESS)  # the baseline's child
    args = ap.parse_args()
    if args.serve:
        return serve()
    if args.quick:
        args.size = args.bounce_size = "96x54"
        args.spaces, args.light_paths = "torus,poincare", "4"
        args.bounce_target, args.direct_reference, args.bounce_reference = 4, 16, 32
    args.size = tuple(int(v) for v in args.size.split("x"))
    args.bounce_size = tuple(int(v) for v in args.bounce_size.split("x"))
    args.light_paths = [int(v) for v in args.light_paths.split(",")]
    t0 = time.perf_counter()
    print(
        f"load average {os.getloadavg()[0]:.1f} at the start; {THREADS} threads; {args.clock} seconds; "
        f"baseline {args.baseline}"
    )
    new = Renderer()
    with tempfile.TemporaryDirectory() as tmp:
        old = Baseline(args.baseline, tmp)
        for sid in args.spaces.split(","):  # warm up: tracers built, lights' copies found, OIDN loaded
            old(sid, (16, 9), 1, args.bounces)
            new(sid, (16, 9), 1, args.bounces, light_paths=4, denoise=True)
        rows = []
        for part in args.parts.split(","):
            for sid in args.spaces.split(","):
                measure_part(sid, part, args, new, old, rows)
        old.close()
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end; {time.perf_counter() - t0:.0f} s in all\n")
    names = ["light sampling", "+ adaptive", "+ denoise", "+ adaptive + denoise"]
    print("| space | part | target: previous build's error (spp, s) | exact light | " + " | ".join(names) + " |")
    print("|---|---|---|---|" + "---|" * len(names))
    for r in rows:
        light = r["cells"][r["light"]] + (f" ({r['light']})" if r["light"] != "exact light" else " (exact)")
        cells = [light] + [r["cells"][name] for name in names[1:]]
        print(
            f"| {r['space']} | {r['part']} | {r['target']:.4f} ({r['old_samples']}, {r['old_seconds']:.2f} s) "
            f"| {r['exact']} | " + " | ".join(cells) + " |"
        )
    print(
        "\ntime ratio: the previous build's time / this build's time to the same error (>=: met at 1 spp, "
        f"<: not met within {args.limit}x the previous build's time); light sampling: the best of "
        f"light_paths {args.light_paths} and the exact sum, the others add to it"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
