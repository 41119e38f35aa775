"""What stereo costs (issue 24 point 6): a stereo pair against the mono render (perspective), an
omni-directional stereo panorama against the mono panorama, interleaved in one run (the least
process CPU time of --repeat rounds, all threads: the machine's other work does not count), one
tracer per space built beforehand; and the time of an 8K x 8K top-bottom ODS panorama (two eyes of
8192 x 4096) on this machine, from --bands bands of 8192 x --band-rows rows spread over each eye's
height (render regions, as a farm's tiles), scaled by the rows (a full 8K eye needs about 21 GiB
here, more than this machine's memory allows in one piece).

Run: .venv/bin/python benchmarks/bench_stereo.py [--spaces poincare,nil] [--quality draft] [--repeat 3]
"""

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from timing import least_interleaved  # noqa: E402

from thurston_addon import render, scenes, spaces  # noqa: E402


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--spaces", default="poincare,nil")
    p.add_argument("--quality", default="draft")
    p.add_argument("--size", default="320x180", help="perspective size (panoramas: its width x width/2)")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--bands", type=int, default=4)
    p.add_argument("--band-rows", type=int, default=8)
    args = p.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    stereo = render.Stereo()
    print(f"quality {args.quality}; least process CPU seconds of {args.repeat} interleaved rounds, 2 threads\n")
    print(f"{'space':<10} {'view':<26} {'mono s':>8} {'stereo s':>9} {'ratio':>6}")
    for sid in args.spaces.split(","):
        space = spaces.load(sid)
        scene = scenes.default_scene(space)
        tracer = render.make_tracer(space, scene, 2, render.light_reach_for(space, render.Settings()))
        for projection, size in (("perspective", (w, h)), ("equirect", (w, w // 2))):
            mono = render.Settings(
                width=size[0], height=size[1], projection=projection, quality=args.quality, threads=2
            )
            pair = render.Settings(**{**mono.__dict__, "stereo": stereo})
            (t_mono, t_pair), _ = least_interleaved(
                [
                    lambda: render.render(space, scene, mono, tracer=tracer),
                    lambda: render.render_eyes(space, scene, pair, tracer=tracer),
                ],
                args.repeat,
            )
            label = f"{projection} {size[0]}x{size[1]}" + (" (ODS)" if projection == "equirect" else "")
            print(f"{sid:<10} {label:<26} {t_mono:>8.2f} {t_pair:>9.2f} {t_pair / t_mono:>6.2f}")
    print()
    sid = args.spaces.split(",")[0]
    space = spaces.load(sid)
    scene = scenes.default_scene(space)
    tracer = render.make_tracer(space, scene, 2, render.light_reach_for(space, render.Settings()))
    W, H = 8192, 4096
    rows = 0
    seconds = 0.0
    for eye in render.EYES:
        for k in range(args.bands):
            top = int((k + 0.5) * H / args.bands) - args.band_rows // 2
            s = render.Settings(
                width=W,
                height=H,
                projection="equirect",
                quality=args.quality,
                threads=2,
                stereo=stereo,
                eye=eye,
                region=(0, top, W, args.band_rows),
            )
            t = time.perf_counter()
            render.render(space, scene, s, tracer=tracer)
            seconds += time.perf_counter() - t
            rows += args.band_rows
    total = seconds * (2 * H) / rows
    print(
        f"8K x 8K top-bottom ODS ({sid}, {args.quality}): {rows} rows of 8192 rendered in {seconds:.1f} s wall; "
        f"the whole 8192 x 8192 about {total / 3600:.1f} h on this machine"
    )


if __name__ == "__main__":
    main()
