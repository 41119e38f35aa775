"""Direct light along every geodesic: what the light reach costs. For each space, the default view of
its default scene rendered at multiples of the default light reach: the copies of the light the
tracer has, the geodesics to lights per shaded point, the render time (least of --repeat; the tile
search of a reach, and the coordinate domains' copy search of a light and reach, are cached on the space,
so their first time is given apart), and the estimated
energy beyond the reach (times the summed). With --baseline DIR (an unpacked wheel of an earlier
build: its thurston_addon and thurston_core, e.g. from `pip wheel --no-deps` of a checkout from before
this change) the same render with that build (each light's nearest copy) is timed in a child
process, for the ratio.
Run: .venv/bin/python benchmarks/bench_light.py [--size 320x180] [--repeat 3]
     [--spaces torus,poincare,seifert_weber,genus2xs1,s2xs1,nil,sol,sl2] [--baseline /tmp/base/wheel]
"""

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import best_of, use_build  # noqa: E402

FACTORS = {
    "S3": (0.25, 0.5, 1.0),
    "E3": (0.5, 1.0, 2.0, 4.0),
    "H3": (0.5, 1.0, 2.0, 4.0),
    "H2xR": (0.5, 1.0, 1.5),
    "S2xR": (0.5, 1.0, 2.0),
    "Nil": (0.5, 1.0, 1.5),
    "Sol": (0.5, 1.0, 1.5),
    "SL2": (0.5, 1.0, 1.5),
}


def view(sid, size, repeat, reach_factor=None):
    """(least seconds, stats) of the default view; reach_factor None: the build's own default."""
    from thurston_addon import render, spaces
    from thurston_addon.scenes import default_scene

    space = spaces.load(sid)
    scene = default_scene(space)
    settings = render.Settings(width=size[0], height=size[1], quality="draft")
    if reach_factor is not None:
        settings.light_reach = reach_factor * render.default_light_reach(space)
    seconds, result = best_of(repeat, lambda: render.render(space, scene, settings))
    return seconds, result.stats


def baseline_view(sid, size, repeat, build):
    """(seconds, light copies) of view() in a child process importing the baseline build instead of
    this checkout."""
    command = [
        sys.executable,
        __file__,
        "--time-of",
        sid,
        "--size",
        f"{size[0]}x{size[1]}",
        "--repeat",
        str(repeat),
        "--build",
        build,
    ]
    result = json.loads(subprocess.run(command, capture_output=True, text=True, check=True).stdout)
    return result["seconds"], result["copies"]


def copy_search(space, reach):
    """The first search for the copies of the default scene's lights within the reach: E3, H3 the
    tile walk (cached per reach afterwards), the coordinate domains (H2xR, S2xR, Nil, Sol, SL2) the
    walk over copies (cached per light and reach)."""
    from thurston_addon import render
    from thurston_addon.scenes import default_scene

    if space.group_order is not None:
        return
    if space.geometry.projective:
        render.light_tiles(space, reach)
        return
    for light in default_scene(space).lights:
        L, _, _ = space.bring_inside(space.geometry.to_model(light.position))
        render.cover_copies(space, L, reach)


def table(space_ids, size, repeat, baseline):
    from thurston_addon import render, spaces

    print(
        f"{'space':<14} {'reach':>12} {'copies':>7} {'geodesics/pt':>12} {'search s':>8} {'render s':>8} "
        f"{'x nearest':>9} {'left out':>9}"
    )
    for sid in space_ids:
        space = spaces.load(sid)
        old, old_copies = baseline_view(sid, size, repeat, baseline) if baseline else (None, None)
        if old is not None:
            print(f"{sid:<14} {'nearest copy':>12} {old_copies:>7} {1:>12} {'':>8} {old:>8.2f} {1:>9.2f} {'':>9}")
        for factor in FACTORS[space.geometry.name]:
            reach = factor * render.default_light_reach(space)
            t0 = time.perf_counter()
            try:
                copy_search(space, reach)
            except render.RenderError:
                print(
                    f"{sid:<14} {reach:>12.3g} refused: more than {render.LIGHT_TILE_LIMIT} tiles or copies within "
                    "the reach"
                )
                continue
            search = time.perf_counter() - t0
            seconds, s = view(sid, size, repeat, factor)
            ratio = f"{seconds / old:>9.2f}" if old else f"{'':>9}"
            label = f"{reach:.3g}" + (" (default)" if factor == 1.0 else "")
            print(
                f"{sid:<14} {label:>12} {s['light_copies']:>7} {s['light_paths_per_point']:>12.1f} {search:>8.2f} "
                f"{seconds:>8.2f} {ratio} {s['light_energy_left_out']:>9.3g}"
            )
    print(
        f"{size[0]}x{size[1]} draft, the default scene and view, all threads; render s: least of {repeat}; "
        "left out: estimated energy beyond the reach up to the distance limit, times the summed"
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--spaces", default="torus,poincare,seifert_weber,genus2xs1,s2xs1,nil,sol,sl2")
    ap.add_argument("--baseline", metavar="DIR", help="an earlier build (unpacked wheel) to time the nearest copy with")
    ap.add_argument("--time-of", help=argparse.SUPPRESS)  # the child's one measurement, as JSON
    ap.add_argument("--build", help=argparse.SUPPRESS)
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    if args.time_of:
        use_build(args.build)
        seconds, stats = view(args.time_of, size, args.repeat)
        print(json.dumps({"seconds": seconds, "copies": stats["light_copies"]}))
        return
    table(args.spaces.split(","), size, args.repeat, args.baseline)


if __name__ == "__main__":
    main()
