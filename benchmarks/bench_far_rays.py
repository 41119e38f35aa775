"""Far rays: what one ray far outside the domain costs a batch of rays. N rays (default 1M) from
random points of the domain, and the same N with one of them started 1000 domains away: the
seconds to bring them into the domain (what `thurston trace` does with RAYS.npy: long double, the
face pairings) and to trace them (the space's default scene, no shading; the two batches timed in
turn, least of --repeat), with this checkout and,
side by side in the same run, with the revision --baseline (its thurston_addon from git, in a
child process; the core is this checkout's).
Run: .venv/bin/python benchmarks/bench_far_rays.py [--rays 1000000] [--spaces torus,nil]
     [--baseline 1ef33a8] [--repeat 1]
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import least_interleaved, use_build  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
FAR = 1000  # domains away


def rays(space, n, far):
    """n chart rays (origin, direction) from random points of the domain; the first FAR domain
    extents away along x if far."""
    import numpy as np

    rng = np.random.default_rng(7)
    origins = space._interior_points(rng, min(n, 1000))[rng.integers(0, min(n, 1000), n)]
    directions = rng.normal(size=(n, 3))
    if far:
        origins[0, 0] += FAR * space.extent
    return np.hstack([origins, directions])


def measure(sid, n, repeat):
    """{far: (seconds to move the rays in, seconds to trace them)} for far False and True, the two
    batches timed in turn (interleaved: a drift of the machine's load falls on each alike)."""
    import numpy as np

    from thurston_addon import render, spaces
    from thurston_addon.scenes import default_scene

    space = spaces.load(sid)
    g = space.geometry

    def move_in(chart):
        x = np.asarray(chart[:, :3], np.longdouble)
        X = g.to_model(x)
        V = g.normalize_tangent(X, g.tangent_to_model(x, np.asarray(chart[:, 3:], np.longdouble)))
        X, V, _ = space.move_inside(X, V)
        return np.ascontiguousarray(X, np.float64), np.ascontiguousarray(V, np.float64)

    charts = [rays(space, n, far) for far in (False, True)]
    move_seconds, moved = least_interleaved([lambda c=c: move_in(c) for c in charts], repeat, time.perf_counter)
    tracer = render.make_tracer(space, default_scene(space))
    tolerances = render.Settings(quality="preview").tolerances(space, render.REFERENCE_PIXEL_ANGLE)
    trace_seconds, _ = least_interleaved(
        [
            lambda X=X, V=V: render.trace(
                tracer, X, V, space.max_distance, space.max_crossings, *tolerances, shade=False
            )
            for X, V in moved
        ],
        repeat,
        time.perf_counter,
    )
    return {far: (move_seconds[far], trace_seconds[far]) for far in (False, True)}


def baseline(sid, n, repeat, folder):
    command = [sys.executable, __file__, "--measure", sid, "--rays", str(n), "--repeat", str(repeat), "--build", folder]
    timed = json.loads(subprocess.run(command, capture_output=True, text=True, check=True).stdout)
    return {far: tuple(timed[str(far)]) for far in (False, True)}


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--rays", type=int, default=1_000_000)
    p.add_argument("--spaces", default="torus,nil")
    p.add_argument("--baseline", default="1ef33a8", help="git revision to compare with ('' for none)")
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--measure", help=argparse.SUPPRESS)
    p.add_argument("--build", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.measure:  # the child: time one case with the baseline's thurston_addon
        use_build(args.build)
        print(json.dumps({str(far): timed for far, timed in measure(args.measure, args.rays, args.repeat).items()}))
        return
    with tempfile.TemporaryDirectory() as folder:
        if args.baseline:
            archive = subprocess.run(
                ["git", "-C", str(REPO), "archive", args.baseline, "thurston_addon"], capture_output=True, check=True
            ).stdout
            subprocess.run(["tar", "-x", "-C", folder], input=archive, check=True)
        print("| space | build | rays | move in s | trace s | total s | x without the far ray |")
        print("|---|---|---|---|---|---|---|")
        for sid in args.spaces.split(","):
            builds = [("this", None)] + ([(args.baseline, folder)] if args.baseline else [])
            for name, build in builds:
                timed = (
                    measure(sid, args.rays, args.repeat)
                    if build is None
                    else baseline(sid, args.rays, args.repeat, build)
                )
                totals = {far: sum(timed[far]) for far in (False, True)}
                for far in (False, True):
                    move, trace = timed[far]
                    label = f"{args.rays - 1} + 1 far" if far else str(args.rays)
                    print(
                        f"| {sid} | {name} | {label} | {move:.2f} | {trace:.2f} | {move + trace:.2f} | "
                        f"{totals[far] / totals[False]:.2f} |",
                        flush=True,
                    )


if __name__ == "__main__":
    main()
