"""What a Ray task runs on a worker: one part of a job rendered by the single-process render,
with the job's tracer built once per worker process (not once per task)."""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import progressive, render
from .jobs import Job, Part

# per worker process: the tracer of the job it last rendered (job key -> tracer)
_tracers: dict = {}

# the passes a sample pass sums over its samples (the render's means of its samples)
SUMMED_PASSES = ("color", "alpha", "albedo", "guide_normal")


def tracer_for(job: Job, key: str):
    if key not in _tracers:
        _tracers.clear()  # a worker holds one job's scene at a time
        s = job.settings
        _tracers[key] = render.make_tracer(job.space, job.scene, s.threads, render.light_reach_for(job.space, s))
    return _tracers[key]


def render_part(job: Job, key: str, part: Part, active=None) -> dict:
    """{"arrays": name -> array, "stats": [render statistics]}: a tile's passes (and the samples
    its pixels took), or a sample pass's sums over its samples of the SUMMED_PASSES ("sum:NAME")
    and of the squared brightness ("squares", the noise estimate's second moment) and the samples
    each pixel took ("taken"; `active`, (h, w) bool: the pixels that take samples, None: all),
    with the pixel centre's passes where part.centre. Denoising is the merged image's, not a part's."""
    tracer = tracer_for(job, key)
    settings = dataclasses.replace(job.settings, denoise=False)
    if part.region is not None:
        result = render.render(
            job.space, job.scene, dataclasses.replace(settings, region=part.region), job.camera, tracer=tracer
        )
        return {"arrays": {**result.passes, "samples_taken": result.samples_taken}, "stats": [result.stats]}
    n = settings.samples_per_pixel
    took = np.ones((settings.height, settings.width)) if active is None else np.asarray(active, np.float64)
    sums, stats = {"taken": len(part.samples) * took.astype(np.int64)}, []
    for k in part.samples:  # sample k of the n-sample render: its sub-pixel position and random numbers
        camera, one = progressive.one_sample(job.camera, settings, k, n)
        result = render.render(job.space, job.scene, one, camera, tracer=tracer)
        for name in SUMMED_PASSES:
            value = result.passes[name].astype(np.float64)
            sums[f"sum:{name}"] = sums.get(f"sum:{name}", 0.0) + value * took.reshape(
                took.shape + (1,) * (value.ndim - 2)
            )
        brightness = result.passes["color"].astype(np.float64).mean(axis=-1) * took
        sums["squares"] = sums.get("squares", 0.0) + brightness**2
        stats.append(result.stats)
    if part.centre:  # the passes of the ray through each pixel's centre: the unshaded centre sample
        centre = dataclasses.replace(
            settings, samples=1, shading="normal", bounces=0, noise_threshold=0.0, min_samples=0
        )
        result = render.render(job.space, job.scene, centre, job.camera, tracer=tracer)
        sums.update({name: a for name, a in result.passes.items() if name not in SUMMED_PASSES})
    return {"arrays": sums, "stats": stats}
