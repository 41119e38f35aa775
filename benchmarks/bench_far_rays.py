"""Far rays: what one ray far outside the domain costs a batch of rays. N rays (default 1M) from
random points of the domain, and the same N with one of them started 1000 domains away: the
seconds to bring them into the domain (what `thurston trace` does with RAYS.npy: long double, the
face pairings) and to trace them (the space's default scene, no shading), with this checkout and,
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
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import best_of  # noqa: E402

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


def measure(sid, n, far, repeat):
    """(seconds to move the rays in, seconds to trace them)."""
    import numpy as np

    from thurston_addon import render, spaces
    from thurston_addon.scene import default_scene

    space = spaces.load(sid)
    g = space.geometry
    chart = rays(space, n, far)

    def move_in():
        x = np.asarray(chart[:, :3], np.longdouble)
        X = g.to_model(x)
        V = g.normalize_tangent(X, g.tangent_to_model(x, np.asarray(chart[:, 3:], np.longdouble)))
        X, V, _ = space.move_inside(X, V)
        return np.ascontiguousarray(X, np.float64), np.ascontiguousarray(V, np.float64)

    move_seconds, (X, V) = best_of(repeat, move_in)
    tracer = render.make_tracer(space, default_scene(space))
    tolerances = render.Settings(quality="preview").tolerances(space, render.REFERENCE_PIXEL_ANGLE)
    trace_seconds, _ = best_of(repeat, lambda: render.trace(tracer, X, V, space.max_distance, space.max_crossings,
                                                           *tolerances, shade=False))
    return move_seconds, trace_seconds


def baseline(sid, n, far, repeat, folder):
    command = [sys.executable, __file__, "--measure", sid, "--rays", str(n), "--repeat", str(repeat), "--build", folder]
    if far:
        command.append("--far")
    return json.loads(subprocess.run(command, capture_output=True, text=True, check=True).stdout)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--rays", type=int, default=1_000_000)
    p.add_argument("--spaces", default="torus,nil")
    p.add_argument("--baseline", default="1ef33a8", help="git revision to compare with ('' for none)")
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--measure", help=argparse.SUPPRESS)
    p.add_argument("--far", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--build", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.measure:  # the child: time one case with the baseline's thurston_addon
        sys.meta_path[:] = [f for f in sys.meta_path if "Redirecting" not in type(f).__name__]  # the editable install
        sys.path.insert(0, args.build)
        move, trace = measure(args.measure, args.rays, args.far, args.repeat)
        print(json.dumps({"move": move, "trace": trace}))
        return
    with tempfile.TemporaryDirectory() as folder:
        if args.baseline:
            archive = subprocess.run(["git", "-C", str(REPO), "archive", args.baseline, "thurston_addon"],
                                     capture_output=True, check=True).stdout
            subprocess.run(["tar", "-x", "-C", folder], input=archive, check=True)
        print(f"| space | build | rays | move in s | trace s | total s | x without the far ray |")
        print("|---|---|---|---|---|---|---|")
        for sid in args.spaces.split(","):
            builds = [("this", None)] + ([(args.baseline, folder)] if args.baseline else [])
            for name, build in builds:
                totals = {}
                for far in (False, True):
                    if build is None:
                        move, trace = measure(sid, args.rays, far, args.repeat)
                    else:
                        timed = baseline(sid, args.rays, far, args.repeat, build)
                        move, trace = timed["move"], timed["trace"]
                    totals[far] = move + trace
                    label = f"{args.rays - 1} + 1 far" if far else str(args.rays)
                    print(f"| {sid} | {name} | {label} | {move:.2f} | {trace:.2f} | {move + trace:.2f} | "
                          f"{totals[far] / totals[False]:.2f} |", flush=True)


if __name__ == "__main__":
    main()
