"""The render loop: the sub-pixel samples, each traced and colourised, summed into the passes,
with the render's statistics."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ..passes import STOP_REASONS, colorize
from ..scenes import FLOAT32_MAX, Camera, Scene
from ..spaces import Space
from .camera import camera_frame, camera_rays, camera_space_normals, clip_range, view_directions
from .compilation import own_hits
from .denoise import denoise
from .lights import light_reach_for
from .projections import PROJECTIONS
from .settings import EYES, MAP_CHECK, Cancelled, RenderError, Settings, memory_needed
from .statistics import (
    CORE_COUNTS,
    Result,
    accuracy_bound,
    error_sample,
    geodesic_error,
    light_stats,
    noise_of,
    pixel_errors,
    pixel_noise,
    retrace_error,
)
from .stereo import eye_view
from .tracer import make_tracer, trace


def _miss_beyond(out: dict, limit):
    """Hits farther than each ray's limit (its clip end) become misses at the distance limit."""
    beyond = out["depth"] > limit
    if not beyond.any():
        return
    out["depth"][beyond] = np.inf
    out["stop"][beyond] = STOP_REASONS.index("distance")
    out["object"][beyond] = -1
    out["color"][beyond] = 0
    out["albedo"][beyond] = 0
    out["carried_normal"][beyond] = 0
    for name in ("normal", "position", "error"):
        out[name][beyond] = np.nan


CENTRE = (0.5, 0.5)

# What the outputs of a ray that was not traced (adaptive sampling) hold: a miss's values
UNTRACED = {"depth": np.inf, "position": np.nan, "normal": np.nan, "object": -1, "error": np.nan, "end": np.nan}


def _untraced_as_misses(out: dict, rays, n: int) -> dict:
    """The tracer's outputs for the rays `rays` (indices among n) as outputs for all n rays, those not
    traced holding a miss's values (stop: the distance limit; colour, albedo and counts 0)."""
    full = {}
    for key, value in out.items():
        if isinstance(value, np.ndarray) and value.ndim >= 1:
            fill = UNTRACED.get(key, STOP_REASONS.index("distance") if key == "stop" else 0)
            full[key] = np.full((n, *value.shape[1:]), fill, value.dtype)
            full[key][rays] = value
        else:
            full[key] = value
    return full


def sample_offsets(n):
    """n sub-pixel positions (x, y in [0, 1)) for the colour, stratified and jittered, the jitter
    antithetic: every sample is paired with its mirror image through the pixel centre, so the mean
    position is exactly the centre and no part of the pixel counts twice.
    n = k * k (the quality levels 1, 4, 16): one sample in each of the k x k sub-squares.
    Other n: n-rooks (a Latin square): one sample in each of n columns and in each of n rows of
    width 1/n, the rows a random permutation of the columns that commutes with the mirror.
    A stratum that is its own mirror image (odd k, odd n) has its sample at the centre."""
    rng = np.random.default_rng(12345)
    k = math.isqrt(n)
    if k * k == n:
        m = k
        strata = [(a, b) for a in range(k) for b in range(k)]
    else:  # n-rooks: column i, row sigma(i), sigma(n - 1 - i) = n - 1 - sigma(i)
        m = n
        half = n // 2
        pi = rng.permutation(half)
        flip = rng.random(half) < 0.5
        sigma = np.empty(n, int)
        for i in range(half):
            sigma[i] = n - 1 - pi[i] if flip[i] else pi[i]
            sigma[n - 1 - i] = n - 1 - sigma[i]
        if n % 2:
            sigma[half] = half
        strata = [(i, int(sigma[i])) for i in range(n)]
    index = {s: i for i, s in enumerate(strata)}
    offsets = [None] * n
    for i, (a, b) in enumerate(strata):
        mirror = index[(m - 1 - a, m - 1 - b)]
        if mirror == i:
            offsets[i] = CENTRE
        elif mirror > i:
            ja, jb = rng.random(2)
            offsets[i] = ((a + ja) / m, (b + jb) / m)
            offsets[mirror] = ((m - 1 - a + 1 - ja) / m, (m - 1 - b + 1 - jb) / m)
    return _spread_order(offsets)


def _spread_order(offsets):
    """The same offsets in an order whose every prefix spreads over the pixel (adaptive sampling and
    the time limit stop a pixel after a prefix): the centre first where there is one, then the
    mirror pairs, each the one farthest from those before it (farthest-point order, the pair's
    nearer member counting), so that an even prefix still averages to the centre."""
    points = np.array(offsets, float)
    where = {tuple(np.round(p, 12)): i for i, p in enumerate(points)}
    firsts = [i for i, p in enumerate(points) if i <= where[tuple(np.round(1.0 - p, 12))]]
    mirrors = [where[tuple(np.round(1.0 - points[i], 12))] for i in firsts]
    a, b = points[firsts], points[mirrors]
    start = next((k for k, (i, j) in enumerate(zip(firsts, mirrors)) if i == j), 0)  # the centre
    order, nearest = [start], np.full(len(firsts), np.inf)
    for _ in range(len(firsts) - 1):
        for q in (a[order[-1]], b[order[-1]]):
            nearest = np.minimum(nearest, np.minimum(np.sum((a - q) ** 2, axis=1), np.sum((b - q) ** 2, axis=1)))
        nearest[order] = -1.0
        order.append(int(np.argmax(nearest)))
    return [offsets[i] for k in order for i in dict.fromkeys((firsts[k], mirrors[k]))]


def render(
    space: Space, scene: Scene, settings: Settings, camera: Camera | None = None, progress=None, tracer=None
) -> Result:
    """Render a view. progress(done, total) -> bool is called during tracing (False cancels).
    Raises RenderError for settings that cannot be rendered, a size too large for this machine's
    memory (checked before anything is allocated) and a MemoryError on the way."""
    settings.check()
    try:
        return _render(space, scene, settings, camera, progress, tracer)
    except MemoryError:
        raise RenderError(
            f"out of memory rendering {settings.width}x{settings.height} "
            f"(about {memory_needed(settings.width, settings.height) / 2**30:.1f} GiB needed)"
        ) from None


MAX_LENS_SHIFT = 10.0  # image widths, Blender's range


def _render(space, scene, settings, camera, progress, tracer) -> Result:
    """render() after the settings' check.
    Colour: the average of the stratified samples of sample_offsets. The other passes (depth,
    normal, position, object, crossings, stop): the ray through the pixel centre, traced unshaded
    on its own unless a colour sample lies at the centre (one sample per pixel, odd counts)."""
    camera = (
        camera or scene.camera or Camera(space.camera.position, space.camera.forward, space.camera.up, space.camera.fov)
    )
    if not (0 < camera.fov < 180):
        raise RenderError(f"camera field of view must be between 0 and 180 degrees, got {camera.fov}")
    if not all(abs(s) <= MAX_LENS_SHIFT for s in camera.shift):  # (NaN included)
        raise RenderError(
            f"camera lens shift {[float(s) for s in camera.shift]} must be within ±{MAX_LENS_SHIFT:g} image widths "
            "(as Blender's); a larger one aims every ray along the image plane"
        )
    if settings.shading == "lambert" and not space.geometry.point_lights:
        raise RenderError(
            f"{space.geometry.name} spaces render in the pseudo-colour shadings only (normal, depth, position, "
            "object, crossings): their light paths are not traced; choose one of them"
        )
    reach = settings.max_distance or space.max_distance
    if reach > space.max_reach:
        raise RenderError(
            f"max distance {reach:g} is longer than {space.id!r} allows ({space.max_reach:g}: an open space's rays "
            "stay within the cube it is traced in); give at most that, or a larger max_distance in its file"
        )
    if not (0 <= camera.clip_start < min(reach, camera.clip_end or math.inf)):
        raise RenderError(
            f"camera clip start {camera.clip_start} must be at least 0 and less than the clip end "
            f"({camera.clip_end}) and the distance the rays reach ({reach})"
        )
    max_crossings = space.max_crossings if settings.max_crossings is None else settings.max_crossings
    t0 = time.perf_counter()
    frame = camera_frame(space, camera)  # once: bring_inside and the re-orthonormalised frame
    eyes = None  # an omni-directional stereo eye's per-pixel eyes
    if settings.eye is not None:
        camera, frame, eyes = eye_view(space, camera, settings, frame)
    tracer = tracer or make_tracer(space, scene, settings.threads, light_reach_for(space, settings))
    offsets = sample_offsets(settings.samples_per_pixel)
    W = settings.width
    _, _, w, h = settings.window  # the pixels rendered
    pixel_angle = PROJECTIONS[settings.projection].width_angle(camera) / W
    tolerances = settings.tolerances(space, pixel_angle)
    map_texels = settings.map_texels(space, pixel_angle, len(scene.lights) if scene else 1)
    shade = settings.shading == "lambert"
    # (jitter, shade, is colour sample): the centre pass first where no colour sample gives it
    jobs = [(o, shade, True) for o in offsets]
    if CENTRE not in offsets:
        jobs.insert(0, (CENTRE, False, False))
    pixels = w * h
    total = len(jobs) * pixels
    # a window's rays draw the random numbers of their pixels in the whole image: a window (a
    # render region, a farm's tile) is pixel for pixel the same part of the whole image's render
    x0, y0 = settings.window[:2]
    window_ids = None if settings.region is None else ((y0 + np.arange(h))[:, None] * W + x0 + np.arange(w)).ravel()
    color_sum = None
    # the denoiser's guides, summed over the colour samples as the colour is
    albedo_sum = np.zeros((w * h, 3))
    guide_sum = np.zeros((w * h, 3))
    brightness_squares = np.zeros(w * h)  # per pixel: the sum over samples of (mean of RGB)^2
    hit_sum = np.zeros(w * h)
    first = None
    adaptive = settings.noise_threshold > 0
    limit = settings.time_limit or None
    # per pixel: the colour samples it took (all of them unless adaptive sampling or the time limit stopped it)
    taken = np.zeros(w * h, np.int64)
    active = None  # adaptive: the pixels still taking samples
    passes_done = 0
    limit_reached = False
    counts = dict.fromkeys(CORE_COUNTS, 0)  # the core's counts, summed over the passes
    shaded_points = 0
    for k, (jitter, shaded, colour) in enumerate(jobs):
        view = view_directions(camera, settings, jitter)
        origins, directions = camera_rays(space, camera, settings, jitter, frame=frame, view=view, eyes=eyes)
        # every ray is traced from its clip start, as far as this sample's farthest clip end needs
        start, end = clip_range(camera, settings, view[0], reach)
        limits = (float(np.max(end - start)), max_crossings, *tolerances)
        base = k * pixels
        report = None if progress is None else (lambda done, _n, base=base: progress(base + done, total))
        # adaptive sampling: only the pixels still taking samples are traced (the centre's pass is
        # every pixel's: the other passes come from it)
        rays = None if active is None or jitter == CENTRE else np.flatnonzero(active)
        out = trace(
            tracer,
            origins if rays is None else origins[rays],
            directions if rays is None else directions[rays],
            *limits,
            shade=shaded,
            progress=report,
            fog=settings.fog,
            light_samples=settings.light_samples,
            seed=settings.seed + k,
            bounces=settings.bounces,
            light_budget=settings.light_budget,
            visibility_map=map_texels,
            map_check=MAP_CHECK,
            # a subset's random numbers are those the same pixels draw in a whole pass
            ray_ids=rays if window_ids is None else window_ids if rays is None else window_ids[rays],
        )
        if np.any(out["stop"] == 3):
            raise Cancelled("render cancelled")
        if rays is not None:
            out = _untraced_as_misses(out, rays, pixels)
        _miss_beyond(out, end - start)
        for key in CORE_COUNTS:
            counts[key] += out[key].item()
        shaded_points += int(np.sum(out["stop"] == 0)) if shaded else 0
        if jitter == CENTRE:
            first, first_start, first_limits = out, start, limits
            sample = error_sample(out, space.geometry)
            probe = (origins[sample], directions[sample])
        if colour:
            guides = (
                out["albedo"].astype(np.float64),
                camera_space_normals(
                    space, camera, settings, frame, view, origins, out["carried_normal"], out["stop"] == 0
                ),
            )
        del origins, directions
        if colour:
            color = colorize(out, settings, space)
            if active is not None:  # stopped pixels take no more samples
                color[~active] = 0
                for guide in guides:
                    guide[~active] = 0
                hit_sum += (out["stop"] == 0) & active
                taken += active
            else:
                hit_sum += out["stop"] == 0
                taken += 1
            brightness_squares += color.mean(axis=1) ** 2
            albedo_sum += guides[0]
            guide_sum += guides[1]
            del guides
            if color_sum is None:
                color_sum = color
            else:
                color_sum += color
            del color
            passes_done += 1
            if adaptive and passes_done >= settings.min_samples_per_pixel and passes_done < len(offsets):
                error = pixel_errors(color_sum, brightness_squares, taken)
                active = (
                    error >= settings.noise_threshold
                    if active is None
                    else active & (error >= settings.noise_threshold)
                )
        del out
        if active is not None and not active.any() and CENTRE not in [j for j, _, _ in jobs[k + 1 :]]:
            break  # every pixel has stopped
        if limit is not None and colour and passes_done < len(offsets) and time.perf_counter() - t0 >= limit:
            limit_reached = True
            break
    seconds = time.perf_counter() - t0
    full = bool(np.all(taken == len(offsets)))
    position, normal = own_hits(space, first)
    # light summed beyond float32 (emitters near its limit, their copies adding up) is clamped to
    # its largest value, and counted for the note, rather than written as infinite pixels
    with np.errstate(over="ignore", invalid="ignore"):
        mean_color = color_sum / taken[:, None]
        beyond = np.any(mean_color > FLOAT32_MAX, axis=1)
        mean_color = np.minimum(mean_color, FLOAT32_MAX)
    passes = {
        "color": mean_color.reshape(h, w, 3).astype(np.float32),
        # the colour of a miss is 0, so the colour is premultiplied by this alpha
        "alpha": (hit_sum / taken if settings.transparent else np.ones(w * h)).reshape(h, w).astype(np.float32),
        "depth": (first["depth"] + first_start).reshape(h, w),
        "normal": normal.reshape(h, w, 3),
        "position": position.reshape(h, w, 3),
        "object": first["object"].reshape(h, w),
        "crossings": first["crossings"].reshape(h, w),
        "stop": first["stop"].reshape(h, w),
        "albedo": (albedo_sum / taken[:, None]).reshape(h, w, 3).astype(np.float32),
        "guide_normal": (guide_sum / taken[:, None]).reshape(h, w, 3).astype(np.float32),
    }
    del albedo_sum, guide_sum
    denoised = False
    if settings.denoise:
        passes["noisy"] = passes["color"]
        passes["color"] = denoise(passes["color"], passes["albedo"], passes["guide_normal"], settings.denoiser)
        denoised = True
        seconds = time.perf_counter() - t0
    hits = first["stop"] == 0
    median_depth = float(np.median(first["depth"][hits])) if hits.any() else 0.0
    origins, directions = probe
    measured, measured_pixels, changed = retrace_error(
        space, tracer, origins, directions, first, sample, first_limits, pixel_angle
    )
    stats = {
        "rays": len(offsets) * pixels,
        "rays_traced": total,
        "chords": counts["chords"],
        "seconds": seconds,
        "chords_per_ray": counts["chords"] / total,
        "threads": tracer.num_threads,
        "crossings_per_ray": float(first["crossings"].mean()),
        "hit_fraction": float(hits.mean()),
        "samples_per_pixel": len(offsets),
        "triangles": tracer.num_triangles,
        "instances": tracer.num_instances,
        "instanced_triangles": tracer.num_instanced_triangles,
        # angular size of a pixel over sqrt(samples), at the median hit depth, in chart-scale units
        "footprint": pixel_angle / math.sqrt(len(offsets)) * median_depth,
        "tolerance": tolerances[0],
        "tolerance_per_distance": tolerances[1],
        "bound": accuracy_bound(space, settings, tolerances),
        # the per-ray error estimate of the hits: the largest and the median, chart units
        "error_estimate_max": float(np.max(first["error"][hits])) if hits.any() else 0.0,
        "error_estimate_median": float(np.median(first["error"][hits])) if hits.any() else 0.0,
        # measured: sampled hits traced again at 1/RETRACE_FACTOR of the tolerance (the largest
        # distance of a hit from the re-traced geodesic, in chart units and pixel footprints, and
        # the fraction of them that met another object)
        "measured_error": measured,
        "measured_error_pixels": measured_pixels,
        "retrace_changed": changed,
        # measured: the largest distance of a (sampled) hit point from the reference geodesic
        "geodesic_error": geodesic_error(space, origins, directions, first["depth"][sample], first["position"][sample]),
        "light_failures": counts["light_failures"],
        "bounces": settings.bounces,
        "bounce_paths_per_point": counts["bounce_paths"] / shaded_points if shaded_points else 0.0,
        "noise": pixel_noise(color_sum, brightness_squares, len(offsets))
        if full
        else noise_of(color_sum, brightness_squares, taken),
        "samples_mean": float(taken.mean()),
        "samples_max": int(taken.max()),
        "noise_threshold": settings.noise_threshold,
        "time_limit": settings.time_limit or None,
        "time_limit_reached": limit_reached,
        "denoised": denoised,
        **light_stats(space, settings, tracer, counts, shaded_points, map_texels),
        "stop_counts": {name: int((first["stop"] == i).sum()) for i, name in enumerate(STOP_REASONS)},
        # the limits the notes name (checks.after_render)
        "max_distance": reach,
        "max_crossings": max_crossings,
        "clip_end": camera.clip_end,
        "fog": settings.fog,
        "inradius": float(space.inradius),
        "clamped_pixels": int(beyond.sum()),
    }
    return Result(passes, stats, taken.reshape(h, w))


def render_eyes(space: Space, scene: Scene, settings: Settings, camera=None, progress=None, tracer=None):
    """The left and right views (Results) of a stereo render, traced by one tracer; progress(done,
    total) counts both."""
    tracer = tracer or make_tracer(space, scene, settings.threads, light_reach_for(space, settings))
    results = []
    for k, eye in enumerate(EYES):

        def report(done, total, k=k):
            return progress(k * total + done, 2 * total)

        results.append(
            render(
                space,
                scene,
                dataclasses.replace(settings, eye=eye),
                camera,
                progress=None if progress is None else report,
                tracer=tracer,
            )
        )
    return tuple(results)
