"""A render's result and statistics: cost, light, the accuracy it promises and the errors measured
(re-traced rays, the reference geodesic), the noise, and their summary in words."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..scenes import Scene
from ..spaces import Space, SpaceError
from .settings import QUALITY, RETRACE_FACTOR, RenderError, Settings, footprint
from .tracer import make_tracer, trace


@dataclass
class Result:
    passes: dict  # name -> (h, w, C) or (h, w) arrays of the rendered window, rows top-down
    stats: dict = field(default_factory=dict)
    # (h, w): the colour samples each pixel took (fewer than the samples per pixel where adaptive
    # sampling or the time limit stopped it); None where not recorded
    samples_taken: np.ndarray | None = None

    def summary(self) -> str:
        s = self.stats
        rays = s.get("rays_traced", s["rays"])
        return (
            f"{rays} rays, {s['crossings_per_ray']:.2f} crossings/ray, {s['chords_per_ray']:.2f} chords/ray, "
            f"{s['hit_fraction'] * 100:.1f}% hits, {s['seconds']:.2f} s "
            f"({rays / max(s['seconds'], 1e-9) / 1e6:.2f} Mrays/s, {s['threads']} threads); "
            f"accuracy: {s['samples_per_pixel']} samples/pixel, pixel footprint {s['footprint']:.2e} "
            f"chart units at median depth; {s['bound']}; measured error {s['measured_error']:.1e} "
            f"chart units = {s['measured_error_pixels']:.2g} pixel footprints (re-traced at 1/{RETRACE_FACTOR} "
            f"of the tolerance; {s['retrace_changed'] * 100:.1f}% of them met another object), geodesic error "
            f"{s['geodesic_error']:.1e} (against the reference geodesic); {light_summary(s)}; "
            f"{illumination_summary(s)}"
        )


def illumination_summary(s: dict) -> str:
    bounces = (
        f"path tracing, bounce limit {s['bounces']} ({s['bounce_paths_per_point']:.2f} bounce geodesics per camera hit)"
        if s["bounces"]
        else "direct light only"
    )
    noise = (
        "noise: one sample per pixel, not estimated"
        if s["noise"] is None
        else f"noise {s['noise']:.2e} (RMS standard error of the pixel means, from {s['samples_per_pixel']} samples)"
    )
    if s.get("noise_threshold") or s.get("time_limit_reached"):
        noise += f"; samples per pixel used: mean {s['samples_mean']:.2f}, max {s['samples_max']}"
        if s.get("noise_threshold"):
            noise += f" (adaptive, noise threshold {s['noise_threshold']:g})"
        if s.get("time_limit_reached"):
            noise += f"; time limit {s['time_limit']:g} s reached"
    if s.get("denoised"):
        noise += "; denoised (Open Image Denoise, albedo and normal guides; noise measured before)"
    return f"{bounces}, {noise}"


def light_summary(s: dict) -> str:
    emitters = (
        f"; {s['emitter_triangles']} emissive triangles in {s['emitter_copies']} copies, "
        f"{s['light_samples']} points sampled on them per shaded point"
        if s["emitter_triangles"]
        else ""
    )
    estimate = (
        f"sampled: {s['shadow_walks_per_point']:.1f} shadow walks per shaded point, the strongest always "
        f"(--light-paths {s['light_budget']})"
        if s["light_budget"]
        else "exact sum, a shadow walk each"
    )
    if s["light_map"]:
        estimate = (
            f"the point lights' answered by visibility maps of {s['light_map']}x{s['light_map']} texels a cube "
            f"face (--light-map), wrong on {s['map_error']:.2%} of the light of the {s['map_checks']} geodesics "
            f"walked to check them"
            + ("" if not s["light_budget"] and not s["emitter_triangles"] else f"; the rest {estimate}")
        )
    return (
        f"light: {s['light_copies']} copies within reach {s['light_reach']:.3g} ({s['light_paths_per_point']:.1f} "
        f"geodesics per shaded point; {estimate}), energy beyond the reach up to the distance limit about "
        f"{s['light_energy_left_out']:.3g} x the summed (estimate){emitters}"
    )


def pixel_noise(color_sum, brightness_squares, n: int) -> float | None:
    """The RMS over the pixels of the standard error of each pixel's mean brightness (mean of RGB),
    from the spread of its n samples (None for one sample). The samples of a pixel are stratified
    over it, so across its edges this overstates the error of the mean; inside surfaces it measures
    the Monte Carlo noise (light samples, bounces)."""
    if n < 2:
        return None
    mean = color_sum.mean(axis=1) / n
    variance = np.maximum(brightness_squares / n - mean**2, 0.0) * n / (n - 1)
    return float(np.sqrt(np.mean(variance / n)))


def pixel_errors(color_sum, brightness_squares, taken) -> np.ndarray:
    """Per pixel: the standard error of its mean brightness from the spread of the `taken` samples it
    took (inf where it took fewer than 2)."""
    n = np.asarray(taken, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = color_sum.mean(axis=1) / n
        variance = np.maximum(brightness_squares / n - mean**2, 0.0) * n / (n - 1)
        error = np.sqrt(variance / n)
    return np.where(n >= 2, error, np.inf)


def noise_of(color_sum, brightness_squares, taken) -> float | None:
    """pixel_noise for pixels that took different numbers of samples: the RMS of their standard
    errors (None where a pixel took one sample)."""
    if np.min(taken) < 2:
        return None
    return float(np.sqrt(np.mean(pixel_errors(color_sum, brightness_squares, taken) ** 2)))


# The core's counts that a render sums over its passes (thurston_core.Tracer.trace's scalars).
CORE_COUNTS = (
    "chords",
    "light_failures",
    "light_paths",
    "light_energy",
    "emitter_paths",
    "emitter_energy",
    "bounce_paths",
    "shadow_walks",
    "shadowed_walks",
    "map_lookups",
    "map_checks",
    "map_texels",
    "map_checked_light",
    "map_error_light",
)


def light_stats(space: Space, settings: Settings, tracer, counts: dict, shaded: int, map_texels: int) -> dict:
    """The light a render summed (`counts`: the core's CORE_COUNTS over its passes, at `shaded`
    points; the visibility maps' `map_texels`): its reach, the copies of the lights the tracer has, the light paths
    per shaded point, how their visibility was found (walks, visibility maps), and the energy left
    out beyond the reach (up to the distance limit D, within
    the geometry's longest geodesic to a light: 2 pi in S3), relative to what was summed (the paths
    arriving at the points' fronts, before cosines and shadows, averaged over the shaded points). The estimate takes the copies of a light
    of power p as spread uniformly, 1/vol per volume: a shell of radius r holds area(r) / vol of
    them and each sends p / area(r), so the part from R to D is 4 pi p (D - R) / vol in E3, H3
    and S3 alike (with fog f: 4 pi p f (exp(-R/f) - exp(-D/f)) / vol), and in every geometry: averaged
    over the points of the space, the geodesics from the light of lengths in [r, r + dr] bring
    4 pi dr p / vol (the exponential map's Jacobian, which the falloff divides by, is the change of
    variables from the light's directions to the points). Without the limit the sum diverges
    (Olbers) wherever it is not cut at S3's two arcs."""
    paths = counts["light_paths"] + counts["emitter_paths"]
    energy = counts["light_energy"] + counts["emitter_energy"]
    shadow_walks, shadowed = counts["shadow_walks"], counts["shadowed_walks"]
    reach = tracer.light_reach
    longest = min(settings.max_distance or space.max_distance, 2 * space.geometry.diameter)
    if reach >= longest:
        left_out = 0.0
    else:
        f = settings.fog
        shell = f * (math.exp(-reach / f) - math.exp(-longest / f)) if f else longest - reach
        # half of it: the summed paths are those arriving at the points' fronts
        left_out = 2 * math.pi * tracer.light_power * shell / space.volume
    summed = energy / shaded if shaded else 0.0
    return {
        "light_copies": tracer.num_light_lifts,
        "light_paths_per_point": paths / shaded if shaded else 0.0,
        # how the direct light was estimated: the point lights' from visibility maps or not, and
        # the geodesics walked: every one, or a sample of them
        "light_estimate": ("visibility maps, " if counts["map_lookups"] else "")
        + ("sampled" if settings.light_budget else "exact sum"),
        "light_budget": settings.light_budget,
        "shadow_walks_per_point": shadow_walks / shaded if shaded else 0.0,
        "shadowed_fraction": shadowed / shadow_walks if shadow_walks else 0.0,  # walks that met a blocker
        "emitter_triangles": tracer.num_emitter_triangles,
        "emitter_copies": tracer.num_emitter_copies,
        "light_samples": settings.light_samples,
        "light_reach": reach,
        "light_energy_left_out": left_out / summed if summed > 0 else (0.0 if left_out == 0 else math.inf),
        # visibility maps: texels per cube-face edge (0: none), the point lights' geodesics looked
        # up, the share of them walked, the checks drawn and how many found the map wrong
        "light_map": map_texels if counts["map_lookups"] else 0,
        "map_lookups_per_point": counts["map_lookups"] / shaded if shaded else 0.0,
        "map_checks": counts["map_checks"],
        # the share of the checked geodesics' light that the map answered wrongly
        "map_error": counts["map_error_light"] / counts["map_checked_light"] if counts["map_checked_light"] else 0.0,
        "map_texels": counts["map_texels"],
    }


def accuracy_bound(space: Space, settings: Settings, tolerances) -> str:
    """The accuracy a render promises, in words."""
    if space.geometry.projective:
        return "geodesics exact (chart lines)"
    if settings.tolerance is not None:
        return f"hit positions within {settings.tolerance:.1e} chart units of the geodesic's"
    return (
        f"hit positions within {QUALITY[settings.quality].footprint_fraction:g} of the pixel footprint "
        f"(chord tolerance {tolerances[0]:.1e} + {tolerances[1]:.1e} per unit distance)"
    )


ERROR_SAMPLES = 1000  # hit pixels checked for the measured errors


def error_sample(out, geometry, n=ERROR_SAMPLES):
    """Indices of up to n hit rays within the geometry's reference depth, drawn at random (fixed
    seed)."""
    ok = (out["stop"] == 0) & (out["depth"] <= geometry.reference_depth)
    hit = np.flatnonzero(ok)
    if len(hit) > n:
        hit = np.sort(np.random.default_rng(2024).choice(hit, n, replace=False))
    return hit


def _image_distance(space: Space, X, Z) -> np.ndarray:
    """The distance between model points X and the nearest copy of Z around the domain (points on
    a face have two images), for nearby points."""
    g = space.geometry
    best = np.full(len(X), np.inf)
    for M in space.neighbourhood(1):
        best = np.minimum(best, np.asarray(g.chord_distance(X, Z @ np.asarray(M, Z.dtype).T), float))
    return best


PATH_SAMPLES = 200  # of them, hits whose path error is measured (one re-trace each)


def retrace_error(space: Space, tracer, origins, directions, out, sample, limits, pixel_angle):
    """The measured error: sampled hit rays traced again at 1/RETRACE_FACTOR of the tolerance.
    Returns (error, pixels, changed): the largest distance between a hit point and the re-traced
    geodesic at the hit's arclength (chart units, and over the pixel footprint there), and the
    fraction of the sampled rays that met another object (or none) when re-traced with the scene:
    silhouettes the chords moved."""
    if len(sample) == 0:
        return 0.0, 0.0, 0.0
    max_distance, max_crossings, tolerance, per_distance = limits
    fine = (tolerance / RETRACE_FACTOR, per_distance / RETRACE_FACTOR)
    P, D = np.ascontiguousarray(origins), np.ascontiguousarray(directions)
    again = trace(tracer, P, D, max_distance, max_crossings, *fine, shade=False)
    changed = float(np.mean(again["object"] != out["object"][sample]))
    g = space.geometry
    path = make_tracer(space, Scene(), threads=1)  # the geodesics alone, one ray at a time
    paths = np.linspace(0, len(sample) - 1, min(len(sample), PATH_SAMPLES)).astype(int)
    depth = out["depth"][sample][paths]
    ends = np.array(
        [
            trace(path, P[i : i + 1], D[i : i + 1], depth[k], max_crossings, *fine, shade=False)["end"][0]
            for k, i in enumerate(paths)
        ]
    )
    error = _image_distance(space, g.to_model(out["position"][sample][paths]), g.to_model(ends))
    return float(error.max()), float((error / footprint(space, pixel_angle, depth)).max()), changed


def geodesic_error(space: Space, origins, directions, depth, position) -> float:
    """The largest distance between traced hit points (chart, in the domain) and the reference
    geodesic: the point at the hit's arclength along the geodesic from the ray's origin with its
    direction, computed by the geometry's own reference (closed forms in extended precision for
    E3, S3, H3; Nil's closed form; Sol's integrator) in the universal cover, brought into the
    domain by the face pairings and matched over the ring of copies around the domain. What this
    measures is the drift the tracer accumulates chord by chord through the pairings' matrices,
    renormalisations and flows; it does not see errors of the scene's triangles (those move the
    hit along the geodesic, not off it). 0.0 where there are no hits."""
    if len(depth) == 0:
        return 0.0
    g = space.geometry
    ld = np.longdouble
    Y, _ = g.geodesic(np.asarray(origins, ld), np.asarray(directions, ld), np.asarray(depth, ld))
    try:
        Z, _, _ = space.move_inside(Y)
    except SpaceError as exc:
        raise RenderError(f"measuring the geodesic error: {exc}") from None
    X = np.asarray(g.to_model(np.asarray(position, float)), ld)
    return float(_image_distance(space, X, Z).max())
