"""Command line: `thurston spaces`, `thurston render`, `thurston trace`."""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import io
import json
import os
import signal
import subprocess
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
    scene = scenes.load_scenes(args.scene, args.allow_files_outside) if args.scene else scenes.default_scene(space)
    if args.scene and not scene.objects:
        warnings.warn("the scene files hold no objects: only the background will show")
    return space, scene


def cmd_render(args):
    stereo = _stereo(args)
    layout = None if stereo is None else stereo.layout_for(args.projection)
    outs = [files.check_output(path, args.overwrite) for path in view_paths(args.out, layout)]
    for out in outs:
        if out.suffix.lower() not in (".exr", ".png", ".jpg", ".jpeg", ".tif", ".tiff"):
            raise CommandError(f"output {str(out)!r}: use .exr (all passes) or .png/.jpg/.tif (colour)")
    space, scene = _load_world(args)
    cam = scene.camera or scenes.Camera(space.camera.position, space.camera.forward, space.camera.up, space.camera.fov)
    given = {"position": args.camera_position, "forward": args.camera_forward, "up": args.camera_up, "fov": args.fov}
    camera = dataclasses.replace(cam, **{k: v for k, v in given.items() if v is not None})
    w, h = args.size
    shading = args.shading or ("lambert" if space.geometry.point_lights else "normal")
    if not args.shading and shading != "lambert":
        print(
            f"thurston: {space.geometry.name} spaces render in pseudo-colour (here --shading normal): their "
            "geodesics to a light have no closed form, so light paths are not traced",
            file=sys.stderr,
        )
    settings = render.Settings(
        width=w,
        height=h,
        projection=args.projection,
        quality=args.quality,
        samples=args.samples,
        shading=shading,
        max_distance=args.max_distance,
        max_crossings=args.max_crossings,
        fog=args.fog,
        light_reach=args.light_reach,
        light_samples=args.light_samples,
        light_paths=args.light_paths,
        light_map=args.light_map,
        bounces=args.bounces,
        threads=args.threads,
        tolerance=args.tolerance,
        noise_threshold=args.noise_threshold,
        min_samples=args.min_samples,
        time_limit=args.time_limit,
        denoise=args.denoise,
        stereo=stereo,
    )
    if render.PROJECTIONS[args.projection].omni_stereo and w != 2 * h:
        warnings.warn(f"a {w}x{h} panorama is not 2:1: panorama viewers and headsets show it stretched")
    lambert = settings.shading == "lambert"
    render.camera_frame(space, camera)  # a camera that cannot be used is refused before the notes on it
    walk = checks.long_walk(
        space,
        w * h * settings.samples_per_pixel * (1 if stereo is None else 2),  # (each eye its rays)
        settings.max_distance or space.max_distance,
        space.max_crossings if settings.max_crossings is None else settings.max_crossings,
        settings.threads or os.cpu_count() or 1,
    )
    for note in checks.before_render(space, scene, camera, lambert) + ([walk] if walk else []):
        warnings.warn(note.message)
    if (args.tiles or args.sample_passes != 1) and not args.cluster:
        raise CommandError("--tiles and --sample-passes split a render for --cluster: give --cluster ADDRESS")

    def write(results):
        for result in results:
            for note in checks.after_render(scene, result.passes, lambert, stats=result.stats):
                warnings.warn(note.message)
        summary = "; ".join(
            (f"{eye} eye: " if stereo else "") + result.summary() for eye, result in zip(render.EYES, results)
        )
        views = [r.passes for r in results] if layout in (None, "separate") else [render.side_by_side(*results, layout)]
        omni = render.PROJECTIONS[args.projection].omni_stereo
        for out, passes in zip(outs, views):
            images.write(
                out,
                passes,
                names=args.passes,
                overwrite=args.overwrite,
                metadata={"space": space.id, "quality": args.quality, "summary": summary}
                | ({} if stereo is None else {"stereo": f"{layout}; {stereo}"}),
                xmp=images.panorama_xmp(w, h, None if layout == "separate" else layout) if omni else None,
            )
            if stereo is None:
                print(f"{out}: {w}x{h} {space.id}; {summary}")
            else:
                print(f"{out}: {w}x{h} per eye, {layout}, {space.id}")
        if stereo is not None:
            print(summary)

    if args.cluster:  # each eye a job on the cluster; the files written when the last is merged
        eyes = render.EYES if stereo else (None,)
        done = []
        for eye in eyes:
            last = (lambda result: write(done + [result])) if eye == eyes[-1] else None
            done.append(_farm_render(args, space, scene, dataclasses.replace(settings, eye=eye), camera, outs[0], last))
        return
    progress = Progress(f"render {space.id}")
    if stereo is None:
        write([render.render(space, scene, settings, camera=camera, progress=progress)])
    else:
        write(render.render_eyes(space, scene, settings, camera=camera, progress=progress))


def view_paths(out: str, layout: str | None) -> list[str]:
    """The output files of a render: OUT, or for stereo views as two files OUT_L and OUT_R (Blender's
    Individual views format and its view suffixes)."""
    if layout != "separate":
        return [out]
    path = Path(out)
    return [str(path.with_name(f"{path.stem}{suffix}{path.suffix}")) for suffix in ("_L", "_R")]


def _stereo(args) -> render.Stereo | None:
    """The stereo settings the arguments ask for; None without --stereo (CommandError where a stereo
    option is given without it)."""
    given = [
        name
        for name in ("interocular", "convergence", "stereo_mode", "stereo_pivot", "stereo_layout", "pole_merge")
        if getattr(args, name) is not None
    ]
    if not args.stereo:
        if given:
            raise CommandError(f"--{given[0].replace('_', '-')} needs --stereo")
        return None
    defaults = render.Stereo()
    return render.Stereo(
        interocular=defaults.interocular if args.interocular is None else args.interocular,
        convergence=defaults.convergence if args.convergence is None else args.convergence,
        mode=args.stereo_mode or defaults.mode,
        layout=args.stereo_layout,
        pivot=args.stereo_pivot or defaults.pivot,
        pole_merge=defaults.pole_merge if args.pole_merge is None else args.pole_merge or None,
    )


def _pole_merge(text: str):
    """FROM,TO in degrees, or off."""
    if text == "off":
        return ()
    try:
        start, end = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected FROM,TO in degrees or off, got {text!r}") from None
    return start, end


def _farm_render(args, space, scene, settings, camera, out, write):
    """The render on a Ray cluster (thurston_addon/farm, docs/farm.md): Ray is imported only here."""
    from . import farm

    try:
        return farm.render(space, scene, settings, camera, args.cluster, out, args.tiles, args.sample_passes, write)
    except farm.FarmError as exc:
        raise CommandError(str(exc)) from None


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
        if args.cluster:  # the frames on a Ray cluster (docs/farm.md)
            from . import farm
            from .blender import farm_frames

            try:
                farm_frames.render_blend(
                    Path(args.blend), args.frames, Path(args.out), args.format, args.overwrite, args.cluster
                )
            except farm.FarmError as exc:
                raise CommandError(str(exc)) from None
            return
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
        q.add_argument(
            "--allow-files-outside",
            action="append",
            default=[],
            metavar="FOLDER",
            help="a folder (and below) the files a scene refers to (materials, textures, buffers, meshes) "
            "may also be read from; repeatable; default: only the scene file's own folder and below",
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
    r.add_argument(
        "--shading",
        choices=render.SHADING,
        help="lambert (lit), or a pseudo-colour: normal, depth, position, object, crossings (default: lambert; "
        "normal in spaces whose light paths are not traced: the graphs of Gaussians)",
    )
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
        "--light-map",
        type=int,
        help="texels per cube-face edge of each point light's visibility map, which answers whether "
        "light reaches a point along each geodesic in place of its shadow walk; 0: none, every geodesic "
        "walked (default: E3, S3 and H3 a texel per pixel angle, the other geometries 0; see docs/lighting.md)",
    )
    r.add_argument(
        "--bounces",
        type=int,
        default=render.Settings.bounces,
        help="bounces after each camera hit: global illumination by path tracing, any quality "
        "(default 0: direct light only)",
    )
    st = r.add_argument_group("stereo", "two eyes, as Blender's Stereoscopy places them (docs/command-line.md)")
    st.add_argument(
        "--stereo",
        action="store_true",
        help="render a left and a right view: each eye half the interocular distance from the camera along "
        "the geodesic to its right, its frame carried by parallel transport; panoramas: omni-directional stereo",
    )
    st.add_argument("--interocular", type=float, help="distance between the eyes, chart units (default 0.065)")
    st.add_argument(
        "--convergence", type=float, help="distance at which the eyes' views agree, chart units (default 1.95)"
    )
    st.add_argument("--stereo-mode", choices=render.STEREO_MODES, help="Blender's convergence mode (default off-axis)")
    st.add_argument(
        "--stereo-pivot",
        choices=render.STEREO_PIVOTS,
        help="where the camera is: between the eyes (default), or at the left or right eye (perspective)",
    )
    st.add_argument(
        "--stereo-layout",
        choices=render.STEREO_LAYOUTS,
        help="the two views side by side (left first) or top-bottom (left on top) in one image, or as OUT_L and "
        "OUT_R (default: side-by-side; top-bottom for panoramas)",
    )
    st.add_argument(
        "--pole-merge",
        type=_pole_merge,
        metavar="FROM,TO",
        help="panoramas: fade the eye offset to 0 between these altitudes, degrees, or off (default 60,75)",
    )
    r.add_argument("--out", required=True, metavar="FILE", help="the image (stereo as two files: FILE_L and FILE_R)")
    r.add_argument(
        "--cluster",
        metavar="ADDRESS",
        help="render on a Ray cluster: local[:N] (N workers on this machine) or HOST:PORT "
        "(a running cluster); needs the 'farm' extra (docs/farm.md)",
    )
    r.add_argument("--tiles", type=int, help="with --cluster: bands of rows, a task each (default: 16)")
    r.add_argument("--sample-passes", type=int, default=1, help="with --cluster: passes of the samples, a task each")
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
        help="folder for <name>_<frame>.<format>, or a path whose '#' run is the frame number "
        "(frames/shot_### -> frames/shot_001.<format>), created where missing (default: .)",
    )
    b.add_argument("--format", choices=("exr", "png"), default="exr")
    b.add_argument("--overwrite", action="store_true", help="replace existing frame files")
    b.add_argument(
        "--cluster",
        metavar="ADDRESS",
        help="render the frames on a Ray cluster: local[:N] or HOST:PORT; a job stopped and started again "
        "renders only the frames it has not finished (docs/farm.md)",
    )
    b.set_defaults(run=cmd_render_blend)
    return p


def is_local_cluster(args) -> bool:
    from .farm.cluster import is_local  # (no Ray: that is imported only when a farm runs)

    return is_local(getattr(args, "cluster", None))


def _private_network(argv) -> int | None:
    """This command again in a network namespace of its own, for a local cluster (Ray's servers listen
    on every interface they see: there only loopback); its exit status, or None where the system
    allows no such namespace (the cluster then runs here, with a warning)."""
    from .farm import cluster

    if importlib.util.find_spec("ray") is None:  # its absence said here, not by the command run again
        raise CommandError(cluster.RAY_MISSING)
    command = cluster.private_network_command([sys.executable, "-m", "thurston_addon.cli", *(argv or sys.argv[1:])])
    if command is None:
        return None
    with subprocess.Popen(command, env={**os.environ, cluster.PRIVATE_NETWORK: "1"}) as child:
        while True:
            try:
                return child.wait()
            except KeyboardInterrupt:
                continue  # the child has it too (one process group): it cancels its tasks and ends
            except Terminated as exc:
                child.send_signal(exc.signum)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    warnings.showwarning = lambda msg, *a, **k: print(f"thurston: warning: {msg}", file=sys.stderr)
    previous = {signum: signal.signal(signum, _terminate) for signum in (signal.SIGTERM, signal.SIGHUP)}
    try:
        if is_local_cluster(args):
            private = _private_network(argv)
            if private is not None:
                return private
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
