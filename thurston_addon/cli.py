"""Command line: `thurston spaces`, `thurston render`, `thurston trace`."""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import signal
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from . import checks, files, images, render, scenes, spaces


class CommandError(Exception):
    pass


class Terminated(BaseException):
    """SIGTERM or SIGHUP, raised in the main thread like Ctrl-C's KeyboardInterrupt: the render
    stops and a file being written is removed on the way out."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _terminate(signum, frame):
    raise Terminated(signum)


def _triple(text: str):
    try:
        v = [float(t) for t in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y,z, got {text!r}") from None
    if len(v) != 3 or not np.all(np.isfinite(v)):
        raise argparse.ArgumentTypeError(f"expected three finite numbers x,y,z, got {text!r}")
    return np.array(v)


def _size(text: str):
    try:
        w, h = (int(t) for t in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 640x360, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"image size must be positive, got {text!r}")
    return w, h


def _passes(text: str):
    names = list(dict.fromkeys(t.strip() for t in text.split(",") if t.strip()))  # each pass once
    bad = [n for n in names if n not in render.PASSES]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"unknown pass(es) {', '.join(bad) or text!r}; known: {', '.join(render.PASSES)}"
        )
    return names


class Progress:
    """A progress bar on stderr (only when it is a terminal, or every 10% otherwise)."""

    def __init__(self, label: str):
        self.label, self.start, self.shown = label, time.perf_counter(), -1
        self.tty = sys.stderr.isatty()

    def __call__(self, done: int, total: int) -> bool:
        frac = done / max(total, 1)
        step = int(frac * (100 if self.tty else 10))
        if step != self.shown:
            self.shown = step
            bar = "#" * int(frac * 30)
            end = "\r" if self.tty and done < total else "\n"
            print(
                f"{self.label} [{bar:<30}] {frac * 100:5.1f}% {time.perf_counter() - self.start:6.1f} s",
                end=end,
                file=sys.stderr,
                flush=True,
            )
        return True


def cmd_spaces(args):
    rows = [spaces.load(i).summary() for i in spaces.preset_ids()]
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        for r in rows:
            print(f"{r['id']:<16} {r['geometry']:<3}  {r['description']}")
        print("\nfamilies (a member's space file is written to the cache folder; see docs/catalogue.md):")
        for f in spaces.FAMILIES:
            print(f"{f.key + '(...)':<16} {f.geometry:<3}  {f.summary}; parameters: {f.parameters}; e.g. {f.example}")
        print(f"{'snappy:NAME':<16} H3   {spaces.SNAPPY_SUMMARY}")


def _load_world(args):
    space = spaces.load(args.space)
    scene = scenes.load_scenes(args.scene) if args.scene else scenes.default_scene(space)
    if args.scene and not scene.objects:
        warnings.warn("the scene files hold no objects: only the background will show")
    return space, scene


def cmd_render(args):
    out = files.check_output(args.out, args.overwrite)
    if out.suffix.lower() not in (".exr", ".png", ".jpg", ".jpeg", ".tif", ".tiff"):
        raise CommandError(f"output {str(out)!r}: use .exr (all passes) or .png/.jpg/.tif (colour)")
    space, scene = _load_world(args)
    cam = scene.camera or scenes.Camera(space.camera.position, space.camera.forward, space.camera.up, space.camera.fov)
    given = {"position": args.camera_position, "forward": args.camera_forward, "up": args.camera_up, "fov": args.fov}
    camera = dataclasses.replace(cam, **{k: v for k, v in given.items() if v is not None})
    w, h = args.size
    settings = render.Settings(
        width=w,
        height=h,
        projection=args.projection,
        quality=args.quality,
        samples=args.samples,
        shading=args.shading,
        max_distance=args.max_distance,
        max_crossings=args.max_crossings,
        fog=args.fog,
        light_reach=args.light_reach,
        light_samples=args.light_samples,
        light_paths=args.light_paths,
        bounces=args.bounces,
        threads=args.threads,
        tolerance=args.tolerance,
        noise_threshold=args.noise_threshold,
        min_samples=args.min_samples,
        time_limit=args.time_limit,
        denoise=args.denoise,
    )
    lambert = settings.shading == "lambert"
    render.camera_frame(space, camera)  # a camera that cannot be used is refused before the notes on it
    for note in checks.before_render(space, scene, camera, lambert):
        warnings.warn(note.message)
    result = render.render(space, scene, settings, camera=camera, progress=Progress(f"render {space.id}"))
    for note in checks.after_render(scene, result.passes, lambert):
        warnings.warn(note.message)
    images.write(
        out,
        result.passes,
        names=args.passes,
        overwrite=args.overwrite,
        metadata={"space": space.id, "quality": args.quality, "summary": result.summary()},
    )
    print(f"{out}: {w}x{h} {space.id}; {result.summary()}")


def read_rays(path, space) -> tuple[np.ndarray, np.ndarray]:
    """The rays of a RAYS.npy file, (N, 6) float64 chart origins and directions, as model points
    moved into the domain and unit tangents there (float64); CommandError naming the file and the
    ray where they cannot be."""
    rays = files.load_npy(path, "rays file", CommandError)
    if rays.ndim != 2 or rays.shape[1] != 6 or rays.dtype != np.float64:
        raise CommandError(f"{path}: expected a float64 array of shape (N, 6), got {rays.dtype} {rays.shape}")
    if len(rays) == 0:
        raise CommandError(f"{path}: holds no rays; give at least one row (origin x, y, z, direction x, y, z)")
    bad = ~np.all(np.isfinite(rays), axis=1)
    if bad.any():
        raise CommandError(f"{path}: ray {int(np.argmax(bad))} has a NaN or infinite value")
    g = space.geometry
    outside = ~g.in_chart(rays[:, :3])
    if outside.any():
        raise CommandError(f"{path}: ray {int(np.argmax(outside))} starts outside the chart of {g.name}")
    largest = np.max(np.abs(rays[:, 3:]), axis=1)
    if np.any(largest == 0):
        raise CommandError(f"{path}: ray {int(np.argmax(largest == 0))} has a zero direction")
    # moved in with extended precision: far origins (Sol at |z| = 20) would lose digits in float64;
    # directions scaled to at most 1 first, so that normalising them cannot overflow
    x = np.asarray(rays[:, :3], np.longdouble)
    try:
        X = space.to_model(x, label="ray")
        V = g.normalize_tangent(X, g.tangent_to_model(x, np.asarray(rays[:, 3:] / largest[:, None], np.longdouble)))
        X, V, _ = space.move_inside(X, V, label="ray")
    except spaces.SpaceError as exc:
        raise CommandError(f"{path}: {exc}") from None
    return np.ascontiguousarray(X, np.float64), np.ascontiguousarray(V, np.float64)


def cmd_trace(args):
    out = files.check_output(args.out, args.overwrite)
    space, scene = _load_world(args)
    X, V = read_rays(args.rays, space)
    settings = render.Settings(
        max_distance=args.max_distance,
        max_crossings=args.max_crossings,
        threads=args.threads,
        quality=args.quality,
        tolerance=args.tolerance,
    )
    settings.check()
    # make_tracer and trace raise what the core rejects as RenderError (exit 2)
    tracer = render.make_tracer(space, scene, args.threads)
    result = render.trace(
        tracer,
        X,
        V,
        space.max_distance if args.max_distance is None else args.max_distance,
        space.max_crossings if args.max_crossings is None else args.max_crossings,
        *settings.tolerances(space, render.REFERENCE_PIXEL_ANGLE),
        shade=False,
        progress=Progress(f"trace {len(X)} rays"),
    )
    result["position"], result["normal"] = render.own_hits(space, result)
    hits = io.BytesIO()  # in memory first: the file is then written whole or not at all
    np.savez(hits, **{name: result[key] for name, key in TRACE_OUTPUTS.items()})
    files.write_bytes(out, hits.getbuffer(), args.overwrite)
    hit = result["stop"] == 0
    print(
        f"{out}: {len(X)} rays, {hit.mean() * 100:.1f}% hits, {result['crossings'].mean():.2f} crossings/ray, "
        f"{result['ray_chords'].mean():.2f} chords/ray"
    )


# HITS.npz: its arrays by the names of the core's outputs
TRACE_OUTPUTS = {
    "depth": "depth",
    "object": "object",
    "position": "position",
    "normal": "normal",
    "crossings": "crossings",
    "stop": "stop",
    "chords": "ray_chords",
    "error_estimate": "error",
}


def cmd_render_blend(args):
    try:
        from .blender import batch, export
    except ImportError:
        raise CommandError(
            "render-blend needs Blender's Python module: pip install bpy==5.0.1, "
            "or run inside Blender: blender -b FILE.blend -E THURSTON -f 1"
        ) from None
    try:
        batch.render_frames(
            Path(args.blend),
            args.frames,
            Path(args.out),
            args.format,
            args.overwrite,
            lambda label: Progress(label),
            lambda line: print(line),
        )
    except export.ExportError as exc:
        raise CommandError(str(exc)) from None


def build_parser():
    p = argparse.ArgumentParser(
        prog="thurston", description="Inside views of 3-manifolds modeled on Thurston's geometries."
    )
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("spaces", help="list the preset spaces and the families of spaces")
    s.add_argument("--json", action="store_true")
    s.set_defaults(run=cmd_spaces)

    def world(q):
        q.add_argument(
            "--space",
            required=True,
            help="preset id, family member such as lens(7,2), snappy:NAME (see `thurston spaces`) or a space file (.toml)",
        )
        q.add_argument(
            "--scene",
            action="append",
            metavar="FILE",
            help="mesh file (.obj .ply .stl .glb .gltf) or scene file (.toml); repeatable; default: the space's default scene",
        )
        q.add_argument("--max-distance", type=float, help="geodesic length at which a ray stops (default: the space's)")
        q.add_argument(
            "--max-crossings", type=int, help="face crossings after which a ray stops (default: the space's)"
        )
        q.add_argument("--threads", type=int, default=0, help="0: all cores")
        q.add_argument(
            "--quality",
            choices=tuple(render.QUALITY),
            default="standard",
            help="samples per pixel and the bound of the hit-position error as a fraction of the pixel "
            "footprint (where geodesics bend): "
            + ", ".join(f"{k} {v.samples} / {v.footprint_fraction:g}" for k, v in render.QUALITY.items()),
        )
        q.add_argument(
            "--tolerance",
            type=float,
            metavar="T",
            help="chord tolerance in chart units (overrides the quality's bound)",
        )
        q.add_argument("--overwrite", action="store_true", help="replace the output file if it exists")

    r = sub.add_parser("render", help="render a view to an image (.exr with all passes, or .png)")
    world(r)
    r.add_argument("--camera-position", type=_triple, metavar="X,Y,Z")
    r.add_argument("--camera-forward", type=_triple, metavar="X,Y,Z")
    r.add_argument("--camera-up", type=_triple, metavar="X,Y,Z")
    r.add_argument("--fov", type=float, help="horizontal field of view in degrees")
    r.add_argument("--size", type=_size, default=(640, 360), metavar="WxH")
    r.add_argument("--projection", choices=tuple(render.PROJECTIONS), default=render.Settings.projection)
    r.add_argument(
        "--passes", type=_passes, help=f"EXR passes, comma separated (default all: {','.join(render.PASSES)})"
    )
    r.add_argument("--samples", type=int, help="samples per pixel (overrides --quality)")
    r.add_argument(
        "--noise-threshold",
        type=float,
        default=render.Settings.noise_threshold,
        help="adaptive sampling: a pixel stops taking samples once the standard error of its mean "
        "brightness is below this, after --min-samples (default 0: off)",
    )
    r.add_argument(
        "--min-samples",
        type=int,
        default=render.Settings.min_samples,
        help="samples every pixel takes before adaptive sampling may stop it (default 0: automatic, 4)",
    )
    r.add_argument(
        "--time-limit",
        type=float,
        help="seconds: no sample pass starts after this (the pass under way finishes; default: none)",
    )
    r.add_argument(
        "--denoise",
        action="store_true",
        help="denoise the colour with Intel Open Image Denoise (RT filter, albedo and normal guides); "
        "the colour before it is the EXR's Noisy Image; needs the 'denoise' extra (pyoidn)",
    )
    r.add_argument("--shading", choices=render.SHADING, default="lambert")
    r.add_argument("--fog", type=float, help="distance at which colour falls to 1/e")
    r.add_argument(
        "--light-reach",
        type=float,
        help="light along every geodesic to every copy of a light up to "
        "this long (default: the space's, see docs/lighting.md)",
    )
    r.add_argument(
        "--light-samples",
        type=int,
        default=render.Settings.light_samples,
        help="points sampled on the emissive meshes (and area lights) per shaded point and sample",
    )
    r.add_argument(
        "--light-paths",
        type=int,
        help="shadow walks per shaded point for direct light: the strongest geodesics to the lights' "
        "copies always, the rest sampled in proportion to their light (unbiased); 0: every geodesic, "
        "the exact sum (default: 8 with --bounces, else 0; see docs/lighting.md)",
    )
    r.add_argument(
        "--bounces",
        type=int,
        default=render.Settings.bounces,
        help="bounces after each camera hit: global illumination by path tracing, any quality "
        "(default 0: direct light only)",
    )
    r.add_argument("--out", required=True, metavar="FILE")
    r.set_defaults(run=cmd_render)

    t = sub.add_parser("trace", help="batch ray queries: RAYS.npy (N,6) float64 -> HITS.npz")
    world(t)
    t.add_argument("--rays", required=True, metavar="RAYS.npy")
    t.add_argument("--out", required=True, metavar="HITS.npz")
    t.set_defaults(run=cmd_trace)

    b = sub.add_parser("render-blend", help="render a .blend file's frames with its Thurston settings (needs bpy)")
    b.add_argument("blend", metavar="FILE.blend")
    b.add_argument("--frames", metavar="A..B", help="frame or range (default: the scene's frame range)")
    b.add_argument(
        "--out",
        default=".",
        metavar="DIR",
        help="folder for <name>_<frame>.<format>, created where missing (default: .)",
    )
    b.add_argument("--format", choices=("exr", "png"), default="exr")
    b.add_argument("--overwrite", action="store_true", help="replace existing frame files")
    b.set_defaults(run=cmd_render_blend)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    warnings.showwarning = lambda msg, *a, **k: print(f"thurston: warning: {msg}", file=sys.stderr)
    previous = {signum: signal.signal(signum, _terminate) for signum in (signal.SIGTERM, signal.SIGHUP)}
    try:
        args.run(args)
    except (CommandError, spaces.SpaceError, scenes.SceneError, render.RenderError, files.OutputError) as exc:
        print(f"thurston: error: {exc}", file=sys.stderr)
        return 2
    except render.Cancelled:
        print("thurston: cancelled", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print("\nthurston: interrupted", file=sys.stderr)
        return 130
    except Terminated as exc:
        print(f"\nthurston: stopped by {exc}", file=sys.stderr)
        return 128 + exc.signum
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return 0


if __name__ == "__main__":
    sys.exit(main())
