"""The parts of a job merged into the render a single process gives: tiles put in their rows,
sample passes summed into one render of all their samples (the noise estimate from the pooled
per-pixel moments), the statistics combined, then the whole image denoised where asked."""

from __future__ import annotations

import math

import numpy as np

from .. import render
from ..render.denoise import denoise
from .jobs import Job, Part
from .work import SUMMED_PASSES

# statistics combined over parts: summed, or the largest (errors measured on a sample of each part)
SUMMED = ("rays", "rays_traced", "chords", "light_failures")
LARGEST = ("error_estimate_max", "measured_error", "measured_error_pixels", "geodesic_error", "samples_max")


def merge(job: Job, parts: list[Part], results: dict[int, dict], seconds: float) -> render.Result:
    """The Result of the job from every part's work.render_part result (by part index);
    `seconds`: the job's wall time."""
    s = job.settings
    if parts[0].region is not None:
        passes, taken, stats = _tiles(s, parts, results)
    else:
        passes, taken, stats = _sample_passes(s, parts, results)
    stats["seconds"] = seconds
    if s.denoise:
        passes["noisy"] = passes["color"]
        passes["color"] = denoise(passes["color"], passes["albedo"], passes["guide_normal"], s.denoiser)
        stats["denoised"] = True
    return render.Result(passes, stats, taken)


def _tiles(s, parts, results):
    passes = {}
    for part in parts:
        x, y, w, h = part.region
        for name, a in results[part.index]["arrays"].items():
            if name not in passes:
                passes[name] = np.zeros((s.height, s.width, *a.shape[2:]), a.dtype)
            passes[name][y : y + h, x : x + w] = a
    taken = passes.pop("samples_taken")
    pixels = [part.region[2] * part.region[3] for part in parts]
    stats = combine_stats([results[p.index]["stats"][0] for p in parts], pixels)
    return passes, taken, stats


def pooled(parts, results) -> dict:
    """The sample passes' sums over the parts that finished (the centre's passes among them)."""
    sums = {}
    for part in parts:
        if part.index in results:
            for name, a in results[part.index]["arrays"].items():
                sums[name] = a if name not in sums else sums[name] + a
    return sums


def still_sampling(s, sums, active):
    """Adaptive sampling after a round: the pixels (h, w) whose standard error, from the pooled
    samples, is still at or above the noise threshold (and that were still taking samples)."""
    error = render.pixel_errors(sums["sum:color"].reshape(-1, 3), sums["squares"].ravel(), sums["taken"].ravel())
    below = (error < s.noise_threshold).reshape(sums["taken"].shape)
    return ~below if active is None else active & ~below


def _sample_passes(s, parts, results):
    n = s.samples_per_pixel
    sums = pooled(parts, results)
    taken = sums["taken"]
    passes = {name: a for name, a in sums.items() if name in render.PASSES}  # the centre's
    for name in SUMMED_PASSES:
        a = sums[f"sum:{name}"]
        passes[name] = (a / taken.reshape(taken.shape + (1,) * (a.ndim - 2))).astype(np.float32)
    if not s.transparent:
        passes["alpha"] = np.ones_like(passes["alpha"])
    every = [st for p in parts if p.index in results for st in results[p.index]["stats"]]
    stats = combine_stats(every, [1] * len(every))
    colour, squares = sums["sum:color"].reshape(-1, 3), sums["squares"].ravel()
    stats.update(
        samples_per_pixel=n,
        samples_mean=float(taken.mean()),
        samples_max=int(taken.max()),
        noise=render.pixel_noise(colour, squares, n)
        if np.all(taken == n)
        else render.noise_of(colour, squares, taken.ravel()),
        # each sample's own render states its footprint for one sample per pixel
        footprint=every[0]["footprint"] / math.sqrt(n),
    )
    return passes, taken, stats


def combine_stats(stats: list[dict], weights) -> dict:
    """One render's statistics from its parts': counts summed, measured errors the largest,
    per-ray and per-pixel figures weighted by the parts' pixels (medians so averaged), the noise
    as the RMS over every pixel; the rest (settings, light) the first part's."""
    w = np.asarray(weights, float) / np.sum(weights)
    out = dict(stats[0])
    for key, first in stats[0].items():
        values = [st[key] for st in stats]
        if key in SUMMED:
            out[key] = sum(values)
        elif key in LARGEST:
            out[key] = max(values)
        elif key == "stop_counts":
            out[key] = {name: sum(v[name] for v in values) for name in first}
        elif key == "noise":
            out[key] = None if None in values else float(np.sqrt(np.dot(w, np.square(values))))
        elif isinstance(first, float) and not isinstance(first, bool):
            out[key] = float(np.dot(w, values))
    out["chords_per_ray"] = out["chords"] / max(out["rays_traced"], 1)
    return out
