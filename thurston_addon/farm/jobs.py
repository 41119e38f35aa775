"""A farm's job (what is rendered) and its parts (what one Ray task renders): horizontal tiles
of the image, or sample passes (each pass some of the render's samples, with their own random
numbers), and the key of a job's contents that its finished parts are kept under."""

from __future__ import annotations

import dataclasses
import hashlib
import math
import pickle
from dataclasses import dataclass
from pathlib import Path

from .. import render, scenes, spaces
from .cluster import FarmError

# Shading modes scaled over the whole image (depth: its 95th percentile; crossings: its largest
# count): a tile of them is not the same part of the whole image
IMAGE_SCALED_SHADING = ("depth", "crossings")


@dataclass(frozen=True)
class Job:
    """One render: what a single process's render.render(space, scene, settings, camera) takes.
    Shipped once to the object store; every task of the job reads it from there."""

    space: spaces.Space
    scene: scenes.Scene
    settings: render.Settings
    camera: scenes.Camera

    def key(self, parts: list[Part]) -> str:
        """A hash of the job's contents and its split: a changed space (its file), scene, setting
        or split gives another key (threads are left out: they change no pixel). The space counts
        by its file and generators, not by its pickle, which holds what renders cached on it."""
        settings = dataclasses.replace(self.settings, threads=0)
        source = Path(self.space.source)
        space = (self.space.source, source.read_bytes() if source.is_file() else None, self.space.generators)
        content = pickle.dumps((space, self.scene, settings, self.camera, parts), protocol=5)
        return hashlib.sha256(content).hexdigest()[:24]


@dataclass(frozen=True)
class Part:
    """What one task renders: its index in the job, and a window of the image (tiles) or a set
    of sample indices of the render's samples per pixel (sample passes); `centre`: this part also
    renders the passes taken from the pixel centre (depth, normal, ...), one pass does."""

    index: int
    region: tuple[int, int, int, int] | None = None
    samples: tuple[int, ...] | None = None
    centre: bool = False
    # adaptive sampling over sample passes: the parts of a round run once the earlier rounds have
    # decided which pixels still take samples
    round: int = 0

    @property
    def label(self) -> str:
        return "tile" if self.region is not None else "sample pass"

    @property
    def plural(self) -> str:
        return "tiles" if self.region is not None else "sample passes"


def split(settings: render.Settings, tiles: int = 1, sample_passes: int = 1) -> list[Part]:
    """The parts of a render: `tiles` bands of rows, or `sample_passes` passes, sample k of the
    render's n in pass k mod sample_passes (each pass spread over the pixel's strata); under
    adaptive sampling in rounds (Part.round)."""
    if tiles < 1 or sample_passes < 1:
        raise FarmError(f"tiles and sample passes must be at least 1, got {tiles} and {sample_passes}")
    if tiles > 1 and sample_passes > 1:
        raise FarmError("split a render into tiles or into sample passes, not both")
    if settings.region is not None:
        raise FarmError("a farm renders the whole image: leave the render region out")
    if settings.time_limit:
        raise FarmError("--time-limit cannot be kept by a farm (its tasks run at once, each on its own clock)")
    if sample_passes > 1:
        n = settings.samples_per_pixel
        if sample_passes > n:
            raise FarmError(f"{sample_passes} sample passes need at least as many samples per pixel, got {n}")
        if settings.projection != "perspective":
            raise FarmError(
                f"sample passes shift the camera's lens by each sample's sub-pixel position, which the "
                f"{settings.projection} projection has not: split it into tiles"
            )
        if settings.noise_threshold <= 0:
            return [Part(p, samples=tuple(range(p, n, sample_passes)), centre=p == 0) for p in range(sample_passes)]
        # adaptive: the first min_samples in the first round, then a sample per pass and round, each
        # round deciding from the pooled samples of those before it which pixels take more
        first = settings.min_samples_per_pixel
        rounds = [range(first)] + [range(c, min(c + sample_passes, n)) for c in range(first, n, sample_passes)]
        parts = []
        for r, samples in enumerate(rounds):
            for p in range(sample_passes):
                if samples[p::sample_passes]:
                    parts.append(Part(len(parts), samples=tuple(samples[p::sample_passes]), centre=not parts, round=r))
        return parts
    if tiles > settings.height:
        raise FarmError(f"{tiles} tiles need an image at least {tiles} rows high, got {settings.height}")
    if tiles > 1 and settings.shading in IMAGE_SCALED_SHADING:
        raise FarmError(
            f"--shading {settings.shading} is scaled over the whole image, so tiles would not match: "
            "use sample passes or one tile"
        )
    rows = [settings.height * t // tiles for t in range(tiles + 1)]
    if settings.light_budget > 0:
        # sampled light learns visibility over blocks of pixel ids (render.ray_block): bands of whole
        # blocks are then traced as in the whole image (fewer bands where the image is small)
        block = render.ray_block()
        step = block // math.gcd(settings.width, block)
        rows = sorted({0, settings.height} | {min(settings.height, round(r / step) * step) for r in rows})
    return [Part(t, region=(0, a, settings.width, b - a)) for t, (a, b) in enumerate(zip(rows, rows[1:]))]
