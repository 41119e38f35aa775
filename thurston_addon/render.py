"""From a space and a scene to passes: the scene compiled for the tracer (with the copies that
objects sticking out of the domain need), camera rays, the C++ trace, pseudo-colour modes, and the
render's statistics (cost and accuracy)."""
from __future__ import annotations

import math
import os
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from .scene import Camera, Scene, SceneError
from .spaces import Space, SpaceError

# Quality: samples per pixel (antialiasing, the only approximation for straight-chart geometries,
# whose geodesics are exact up to float64 rounding). The same names are used by the add-on.
QUALITY = {"draft": 1, "preview": 1, "standard": 4, "final": 16}
SHADING = ("lambert", "normal", "position", "depth", "crossings", "object")
PASSES = ("color", "depth", "normal", "position", "object", "crossings", "stop")
STOP_REASONS = ("hit", "distance", "crossings", "cancelled")


# Peak memory of render() per pixel, whatever the sample count (samples are traced one after the
# other): the rays of one sample (origins, directions and their temporaries), the tracer's output
# for it and for the centre ray, and the colour sum. Measured at about 245 bytes (2000 x 1000, all
# shading modes and projections; tests/test_render.py measures it again); rounded up.
BYTES_PER_PIXEL = 300
MEMORY_FRACTION = 0.8  # refuse renders that would need more than this share of physical memory


def memory_needed(width: int, height: int) -> int:
    return BYTES_PER_PIXEL * int(width) * int(height)


def physical_memory() -> int | None:
    """Bytes of physical memory, None where the system does not tell (no sysconf)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


class RenderError(ValueError):
    """Input that cannot be rendered, with a message naming the problem."""


class Cancelled(RuntimeError):
    pass


@dataclass
class Settings:
    width: int = 640
    height: int = 360
    projection: str = "perspective"  # or "equirect"
    quality: str = "standard"
    samples: int | None = None  # samples per pixel; None: the quality's
    shading: str = "lambert"
    max_distance: float | None = None  # None: the space's default
    max_crossings: int | None = None
    fog: float | None = None  # distance at which colour falls to 1/e; None: no fog
    threads: int = 0

    def check(self):
        if self.width < 1 or self.height < 1:
            raise RenderError(f"image size {self.width}x{self.height} is not usable")
        need, have = memory_needed(self.width, self.height), physical_memory()
        if have is not None and need > MEMORY_FRACTION * have:
            raise RenderError(f"image size {self.width}x{self.height} needs about {need / 2**30:.1f} GiB of memory "
                              f"to render, more than {MEMORY_FRACTION:.0%} of this machine's {have / 2**30:.1f} GiB")
        if self.width * self.height > 2**28:
            raise RenderError(f"image size {self.width}x{self.height} is not usable (more than 2^28 pixels)")
        if self.projection not in ("perspective", "equirect"):
            raise RenderError(f"unknown projection {self.projection!r} (perspective, equirect)")
        if self.quality not in QUALITY:
            raise RenderError(f"unknown quality {self.quality!r} ({', '.join(QUALITY)})")
        if self.samples is not None and not 1 <= self.samples <= 4096:
            raise RenderError(f"samples per pixel must be between 1 and 4096, got {self.samples}")
        if self.shading not in SHADING:
            raise RenderError(f"unknown shading {self.shading!r} ({', '.join(SHADING)})")
        if self.max_distance is not None and not (self.max_distance > 0 and math.isfinite(self.max_distance)):
            raise RenderError(f"max distance must be a positive number, got {self.max_distance}")
        if self.max_crossings is not None and not (_whole(self.max_crossings) and 0 <= self.max_crossings <= 2**31 - 1):
            raise RenderError(f"max crossings must be a whole number >= 0, got {self.max_crossings}")
        if self.fog is not None and not (self.fog > 0 and math.isfinite(self.fog)):
            raise RenderError(f"fog distance must be a positive number (None: no fog), got {self.fog}")
        if not (_whole(self.threads) and 0 <= self.threads <= 2**31 - 1):
            raise RenderError(f"threads must be a whole number >= 0 (0: all cores), got {self.threads}")


def _whole(n) -> bool:
    return isinstance(n, (int, np.integer)) and not isinstance(n, bool)


@dataclass
class Result:
    passes: dict  # name -> (H, W, C) or (H, W) arrays, rows top-down
    stats: dict = field(default_factory=dict)

    def summary(self) -> str:
        s = self.stats
        rays = s.get("rays_traced", s["rays"])
        return (f"{rays} rays, {s['crossings_per_ray']:.2f} crossings/ray, {s['chords']} chords, "
                f"{s['hit_fraction'] * 100:.1f}% hits, {s['seconds']:.2f} s "
                f"({rays / max(s['seconds'], 1e-9) / 1e6:.2f} Mrays/s, {s['threads']} threads); "
                f"accuracy: {s['samples_per_pixel']} samples/pixel, pixel footprint {s['footprint']:.2e} "
                f"chart units at median depth, geodesic error {s['geodesic_error']:.1e} (measured)")


# --- compiling the scene -------------------------------------------------------------------------------
# Copies of the domain searched for an object's parts: rings of copies around D, more for larger
# objects; hyperbolic rings grow too fast for more than one.
MAX_RINGS = {1: 3, 0: 3, -1: 1}


def _object_copies(space: Space, obj, C):
    """The copies g(obj) that can reach the domain, each as (model vertices, kept triangles), and
    whether every vertex of the object is brought into the domain by one of them."""
    g = space.geometry
    X = g.to_model(obj.vertices)
    T = obj.triangles
    for rings in range(1, MAX_RINGS[g.curvature] + 1):
        copies = []
        covered = np.zeros(len(X), bool)
        for M in space.neighbourhood(rings):
            Y = X @ M.T
            ok = Y[:, 3] > 1e-9 * np.linalg.norm(Y, axis=1)  # the copy stays on the chart's side
            outside = (Y / np.linalg.norm(Y, axis=1)[:, None]) @ C.T > 1e-9
            covered |= ok & ~outside.any(axis=1)
            # drop triangles wholly outside one face plane: they cannot meet the domain
            keep = ~np.any(outside[T[:, 0]] & outside[T[:, 1]] & outside[T[:, 2]], axis=1) & ok[T].all(axis=1)
            if keep.any():
                copies.append((Y, T[keep]))
        if covered.all():
            break
    return copies, covered


def compile_scene(space: Space, scene: Scene):
    """Tracer arrays: triangles of every object and of its copies g(object) that can reach the domain
    (parts sticking out re-enter through the paired faces), and the lights' copies near the domain."""
    g = space.geometry
    C = space.domain.covectors()
    C = C / np.linalg.norm(C, axis=1)[:, None]
    # Light copies: the tracer lights a point by each light's nearest copy among these. S3: the
    # group is finite, so all of it (120 elements for Poincare) and the nearest copy is exact.
    # E3: the copies around the domain hold the nearest copy (exact). H3: the same ring of copies,
    # an approximation: for points near vertices a copy beyond it can be nearer (the ring grows
    # exponentially, so more rings would cost much more per shaded point).
    if g.curvature > 0:
        elements = space.elements_within(math.pi + 1e-6)
    else:
        elements = space.neighbourhood(1)
    verts, tris, owner = [], [], []
    offset = 0
    for index, obj in enumerate(scene.objects):
        if not np.all(g.in_chart(obj.vertices)):
            raise SceneError(f"object {obj.name!r} has vertices outside the chart of {g.name} (the Klein chart is the open unit ball)")
        copies, covered = _object_copies(space, obj, C)
        for Y, T in copies:
            used, local = np.unique(T, return_inverse=True)
            verts.append(g.to_chart(Y[used]))
            tris.append(local.reshape(-1, 3) + offset)
            owner.append(np.full(len(T), index, np.int32))
            offset += len(used)
        if not copies:
            warnings.warn(f"object {obj.name!r} lies outside the domain and its neighbouring copies: not shown", stacklevel=2)
        elif not covered.all():
            warnings.warn(f"object {obj.name!r} reaches beyond the copies of the domain around it: "
                          f"{int((~covered).sum())} of its vertices are farther out and parts of it are missing", stacklevel=2)
    V = np.vstack(verts) if verts else np.zeros((0, 3))
    T = np.vstack(tris).astype(np.int32) if tris else np.zeros((0, 3), np.int32)
    O = np.concatenate(owner) if owner else np.zeros(0, np.int32)
    colors = np.array([o.color for o in scene.objects], np.float32).reshape(-1, 3)
    emission = np.array([o.emission for o in scene.objects], np.float32).reshape(-1, 3)
    lifts, of_lift, radiance = [], [], []
    for i, light in enumerate(scene.lights):
        if not np.all(g.in_chart(light.position)):
            raise SceneError(f"light {i} at {light.position} is outside the chart of {g.name}")
        if not (math.isfinite(light.power) and light.power >= 0):
            raise SceneError(f"light {i}: power must be a finite number >= 0, got {light.power}")
        try:  # its copies are taken around the domain, so start from the copy inside
            L, _, _ = space.bring_inside(g.to_model(light.position))
        except SpaceError as exc:
            raise SceneError(f"light {i}: {exc}") from None
        for M in elements:
            Y = M @ L
            lifts.append(Y)
            of_lift.append(i)
        radiance.append(np.asarray(light.color, float) * light.power)
    return dict(
        geometry=g.name, face_covectors=np.ascontiguousarray(space.domain.covectors()),
        face_maps=np.ascontiguousarray(np.array([f.pairing for f in space.domain.faces])),
        vertices=np.ascontiguousarray(V, np.float64), triangles=np.ascontiguousarray(T),
        triangle_object=np.ascontiguousarray(O), object_color=colors, object_emission=emission,
        light_lifts=np.array(lifts, np.float64).reshape(-1, 4), light_of_lift=np.array(of_lift, np.int32),
        light_radiance=np.array(radiance, np.float32).reshape(-1, 3),
    )


def make_tracer(space: Space, scene: Scene, threads: int = 0):
    """The C++ tracer for a scene; what the core rejects (ValueError) is raised as RenderError."""
    import thurston_core

    data = compile_scene(space, scene)
    try:
        return thurston_core.Tracer(**data, threads=threads)
    except ValueError as exc:
        raise RenderError(f"the tracer rejected the scene: {exc}") from None


def trace(tracer, origins, directions, max_distance, max_crossings, shade=True, progress=None):
    """tracer.trace, with what the core rejects (ValueError) raised as RenderError. Exceptions
    from the progress callback pass through unchanged (they are the caller's, not the input's)."""
    raised = []

    def report(done, total):
        try:
            return progress(done, total)
        except BaseException as exc:
            raised.append(exc)
            raise

    try:
        return tracer.trace(origins, directions, max_distance, max_crossings, shade=shade,
                            progress=None if progress is None else report)
    except ValueError as exc:
        if raised:
            raise
        raise RenderError(f"the tracer rejected the rays: {exc}") from None


# --- camera --------------------------------------------------------------------------------------------
def camera_frame(space: Space, camera: Camera):
    """Camera point (model) brought into the domain and an orthonormal frame (forward, right, up)
    there in the metric."""
    g = space.geometry
    p = np.asarray(camera.position, float)
    if not (np.all(np.isfinite(p)) and g.in_chart(p)):
        raise RenderError(f"camera position {p.tolist()} is not a point of {g.name}")
    f, u = np.asarray(camera.forward, float), np.asarray(camera.up, float)
    r = np.cross(f, u)
    if not (np.all(np.isfinite(r)) and np.linalg.norm(r) > 1e-12 * np.linalg.norm(f) * np.linalg.norm(u)):
        raise RenderError(f"camera forward {f.tolist()} and up {u.tolist()} must be finite, non-zero and not parallel")
    X = g.to_model(p)
    frame = [g.tangent_to_model(p, v) for v in (f, r, u)]
    try:
        X, _, M = space.bring_inside(X)
    except SpaceError as exc:
        raise RenderError(f"camera: {exc}") from None
    basis = []
    for v in frame:
        v = M @ v
        for b in basis:
            v = v - g.inner(v, b) * b
        basis.append(g.normalize_tangent(X, v))
    return X, basis


def camera_rays(space: Space, camera: Camera, settings: Settings, jitter=(0.5, 0.5), frame=None):
    """Origins and unit directions (model) for every pixel, rows top-down. `frame`: the result of
    camera_frame(space, camera), computed once per render and passed in for every sample."""
    X, (f, r, u) = frame if frame is not None else camera_frame(space, camera)
    W, H = settings.width, settings.height
    j = (np.arange(W) + jitter[0]) / W
    i = (np.arange(H) + jitter[1]) / H
    if settings.projection == "perspective":
        t = math.tan(math.radians(camera.fov) / 2)
        sx = (2 * j - 1) * t
        sy = (1 - 2 * i) * t * H / W
        a, b, c = np.ones((H, W)), np.broadcast_to(sx, (H, W)), np.broadcast_to(sy[:, None], (H, W))
        n = np.sqrt(a * a + b * b + c * c)
        a, b, c = a / n, b / n, c / n
    else:  # equirectangular: longitude 0 is forward, increasing to the right; latitude up
        lon = (2 * j - 1) * math.pi
        lat = (0.5 - i) * math.pi
        a = np.cos(lat)[:, None] * np.cos(lon)[None, :]
        b = np.cos(lat)[:, None] * np.sin(lon)[None, :]
        c = np.broadcast_to(np.sin(lat)[:, None], (H, W))
    D = a[..., None] * f + b[..., None] * r + c[..., None] * u
    origins = np.broadcast_to(X, (H * W, 4)).copy()
    return origins, np.ascontiguousarray(D.reshape(-1, 4))


CENTRE = (0.5, 0.5)


def _sample_offsets(n):
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
    return offsets


# --- rendering -----------------------------------------------------------------------------------------
def render(space: Space, scene: Scene, settings: Settings, camera: Camera | None = None,
           progress=None, tracer=None) -> Result:
    """Render a view. progress(done, total) -> bool is called during tracing (False cancels).
    Raises RenderError for settings that cannot be rendered, a size too large for this machine's
    memory (checked before anything is allocated) and a MemoryError on the way."""
    settings.check()
    try:
        return _render(space, scene, settings, camera, progress, tracer)
    except MemoryError:
        raise RenderError(f"out of memory rendering {settings.width}x{settings.height} "
                          f"(about {memory_needed(settings.width, settings.height) / 2**30:.1f} GiB needed)") from None


def _render(space, scene, settings, camera, progress, tracer) -> Result:
    """render() after the settings' check.
    Colour: the average of the stratified samples of _sample_offsets. The other passes (depth,
    normal, position, object, crossings, stop): the ray through the pixel centre, traced unshaded
    on its own unless a colour sample lies at the centre (one sample per pixel, odd counts)."""
    camera = camera or scene.camera or Camera(space.camera.position, space.camera.forward, space.camera.up, space.camera.fov)
    if not (0 < camera.fov < 180):
        raise RenderError(f"camera field of view must be between 0 and 180 degrees, got {camera.fov}")
    max_distance = settings.max_distance or space.max_distance
    max_crossings = space.max_crossings if settings.max_crossings is None else settings.max_crossings
    t0 = time.perf_counter()
    frame = camera_frame(space, camera)  # once: bring_inside and the re-orthonormalised frame
    tracer = tracer or make_tracer(space, scene, settings.threads)
    offsets = _sample_offsets(settings.samples or QUALITY[settings.quality])
    shade = settings.shading == "lambert"
    # (jitter, shade, is colour sample): the centre pass first where no colour sample gives it
    jobs = [(o, shade, True) for o in offsets]
    if CENTRE not in offsets:
        jobs.insert(0, (CENTRE, False, False))
    pixels = settings.width * settings.height
    total = len(jobs) * pixels
    color_sum = None
    first = None
    chords = 0
    for k, (jitter, shaded, colour) in enumerate(jobs):
        origins, directions = camera_rays(space, camera, settings, jitter, frame=frame)
        base = k * pixels
        report = None if progress is None else (lambda done, _n, base=base: progress(base + done, total))
        out = trace(tracer, origins, directions, max_distance, max_crossings, shade=shaded, progress=report)
        if np.any(out["stop"] == 3):
            raise Cancelled("render cancelled")
        chords += int(out["chords"])
        if jitter == CENTRE:
            first = out
            sample = _error_sample(out, space.geometry.curvature)
            probe = (origins[sample], directions[sample], out["depth"][sample], out["position"][sample])
        del origins, directions
        if colour:
            color = _colorize(out, settings, space)
            if color_sum is None:
                color_sum = color
            else:
                color_sum += color
            del color
        del out
    H, W = settings.height, settings.width
    seconds = time.perf_counter() - t0
    passes = {
        "color": (color_sum / len(offsets)).reshape(H, W, 3).astype(np.float32),
        "depth": first["depth"].reshape(H, W),
        "normal": first["normal"].reshape(H, W, 3),
        "position": first["position"].reshape(H, W, 3),
        "object": first["object"].reshape(H, W),
        "crossings": first["crossings"].reshape(H, W),
        "stop": first["stop"].reshape(H, W),
    }
    depth = first["depth"][np.isfinite(first["depth"])]
    median_depth = float(np.median(depth)) if len(depth) else 0.0
    fov = math.radians(camera.fov) if settings.projection == "perspective" else 2 * math.pi
    stats = {
        "rays": len(offsets) * pixels, "rays_traced": total, "chords": chords, "seconds": seconds,
        "threads": tracer.num_threads,
        "crossings_per_ray": float(first["crossings"].mean()), "hit_fraction": float((first["stop"] == 0).mean()),
        "samples_per_pixel": len(offsets), "triangles": tracer.num_triangles,
        # angular size of a pixel over sqrt(samples), at the median hit depth, in chart-scale units
        "footprint": fov / W / math.sqrt(len(offsets)) * median_depth,
        # measured: the largest distance of a (sampled) hit point from the true geodesic
        "geodesic_error": geodesic_error(space, *probe),
        "stop_counts": {name: int((first["stop"] == i).sum()) for i, name in enumerate(STOP_REASONS)},
    }
    return Result(passes, stats)


ERROR_SAMPLES = 1000  # hit pixels checked for the geodesic error


# H3: the reference below goes through the universal cover, where points at distance t have
# coordinates ~e^t and the float64 pairing matrices satisfy the group's relations only to ~1e-16
# of their size: two words for one element differ there by ~1e-16 e^(2t), which is 1e-10 near
# t = 5 and 1e-6 at t = 12, far above the tracer's own drift (renormalised at every crossing).
# So in H3 only hits up to this depth are checked.
H3_CHECK_DEPTH = 5.0


def _error_sample(out, curvature, n=ERROR_SAMPLES):
    """Indices of up to n hit rays, drawn at random (fixed seed)."""
    ok = out["stop"] == 0
    if curvature < 0:
        ok &= out["depth"] <= H3_CHECK_DEPTH
    hit = np.flatnonzero(ok)
    if len(hit) > n:
        hit = np.sort(np.random.default_rng(2024).choice(hit, n, replace=False))
    return hit


def geodesic_error(space: Space, origins, directions, depth, position) -> float:
    """The largest distance between traced hit points (chart, in the domain) and the true geodesic:
    the point at the hit's arclength along the geodesic from the ray's origin with its direction,
    exp_P(t V), computed in the universal cover in closed form (P cos t + V sin t in S3, cosh/sinh
    in H3, P + t V in E3, in extended precision), brought into the domain by the face pairings,
    and matched over the ring of copies around the domain (points on a face have two images).
    What this measures is the drift the tracer accumulates chord by chord through the pairings'
    matrices and renormalisations, which is the error of the method; it does not see errors of
    the scene's triangles (those move the hit along the geodesic, not off it, and are not in the
    arclength). 0.0 where there are no hits. In H3 only hits within H3_CHECK_DEPTH are sampled:
    beyond it the reference itself is no better than the tracer."""
    if len(depth) == 0:
        return 0.0
    g = space.geometry
    k = g.curvature
    ld = np.longdouble
    P, V, t = np.asarray(origins, ld), np.asarray(directions, ld), np.asarray(depth, ld)[:, None]
    if k > 0:
        Y = np.cos(t) * P + np.sin(t) * V
    elif k < 0:
        Y = np.cosh(t) * P + np.sinh(t) * V
    else:
        Y = P + t * V
    try:
        Z, _, _ = space.move_inside(Y)
    except SpaceError as exc:
        raise RenderError(f"measuring the geodesic error: {exc}") from None
    X = np.asarray(g.to_model(np.asarray(position, float)), ld)
    best = np.full(len(X), np.inf)
    for M in space.neighbourhood(1):
        d = X - Z @ np.asarray(M, ld).T
        if k < 0:  # chord lengths: 2 sin(r/2), 2 sinh(r/2), r: the distance r to first order
            chord = np.sqrt(np.maximum(np.sum(d[:, :3] ** 2, axis=1) - d[:, 3] ** 2, 0))
        else:
            chord = np.sqrt(np.sum(d[:, :3] ** 2, axis=1) + (d[:, 3] ** 2 if k > 0 else 0))
        best = np.minimum(best, chord.astype(float))
    return float(best.max())


def _colorize(out, settings: Settings, space: Space):
    hit = out["stop"] == 0
    mode = settings.shading
    if mode == "lambert":
        color = out["color"].astype(np.float64)
    elif mode == "normal":
        color = np.where(hit[:, None], 0.5 + 0.5 * np.nan_to_num(out["normal"]), 0.0)
    elif mode == "position":
        lo, hi = space.domain.vertices.min(axis=0), space.domain.vertices.max(axis=0)
        color = np.where(hit[:, None], np.clip((np.nan_to_num(out["position"]) - lo) / (hi - lo), 0, 1), 0.0)
    elif mode == "depth":
        d = np.where(hit, out["depth"], 0.0)
        scale = np.percentile(d[hit], 95) if hit.any() else 1.0
        color = np.repeat(np.where(hit, 1 - np.clip(d / max(scale, 1e-12), 0, 1), 0.0)[:, None], 3, axis=1)
    elif mode == "crossings":
        n = out["crossings"].astype(np.float64)
        color = np.repeat((n / max(1.0, n.max()))[:, None], 3, axis=1)
    else:  # object: a distinct hue per object index, base colour for lookups
        idx = out["object"]
        hue = (idx * 0.618034) % 1.0
        color = np.where(hit[:, None], np.stack([_hue(hue + o) for o in (0, 1 / 3, 2 / 3)], axis=1), 0.0)
    if settings.fog is not None:
        color = color * np.exp(-np.where(hit, out["depth"], 0.0) / settings.fog)[:, None]
    return color


def _hue(h):
    return 0.5 + 0.5 * np.cos(2 * math.pi * h)
