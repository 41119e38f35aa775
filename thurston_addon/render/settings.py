"""A render's settings: the quality levels, the Settings a render takes and their checks, the
limits of what can be rendered, and the errors a render raises."""

from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass

import numpy as np

from ..files import physical_memory
from ..passes import SHADING
from ..spaces import Space
from .projections import PROJECTIONS


@dataclass(frozen=True)
class Quality:
    """A quality level: samples per pixel (antialiasing), the bound of the hit-position error
    as a fraction of the pixel footprint at the hit's distance (where geodesics bend in the chart
    and are followed in chords; in E3, S3 and H3 they are exact chart lines), and the angle of a
    visibility map's texel at its light in pixels (Settings.map_texels)."""

    samples: int
    footprint_fraction: float
    texel_pixels: float = 1.0


# The same names are used by the add-on. The fractions keep what the chords do to the image below
# what the sampling does at each quality (benchmarks/bench_curved.py, its image table); the texels
# what the maps do to the light near what the sampling does (docs/lighting.md, "Visibility maps").
QUALITY = {
    "draft": Quality(1, 1.0, 2.0),
    "preview": Quality(2, 0.5, 1.4),
    "standard": Quality(4, 0.25, 1.0),
    "final": Quality(16, 0.1, 0.7),
}
# Shadow walks per shaded point where light_paths is automatic and bounces follow: in path tracing
# the bounces' noise dominates and the walks the cost, and 8 sampled walks beat the exact sum at
# equal time (2.6x the efficiency in the Poincare space, 2 bounces; direct light alone, where the
# exact sum is as good, stays exact: docs/lighting.md, "Sampled direct light").
PATH_TRACED_LIGHT_PATHS = 8
# The visibility maps' automatic texels per face edge (Settings.map_texels) are kept within these;
# the share of the answered geodesics also walked to measure the maps' error.
MAP_TEXELS = (64, 2048)
MAP_BYTES_PER_TEXEL = 24  # per texels^2: six faces of float32 distances
MAP_MEMORY = 512 * 2**20  # the automatic maps of a scene's point lights at most
MAP_CHECK = 1 / 256
MAX_MAP_TEXELS = 4096  # the core's limit
# `thurston trace` has no pixels: its qualities use the pixel of the default view (640 pixels
# across 90 degrees).
REFERENCE_PIXEL_ANGLE = math.radians(90.0) / 640
# The bound stays positive at the camera: distances are counted from this fraction of the
# domain's metric extent behind it.
NEAR_FRACTION = 0.05
RETRACE_FACTOR = 100  # the measured error: sampled rays traced again at tolerance / this
# A chord tolerance's chords grow as 1 / sqrt(tolerance) (Nil: about 65 a ray at 1e-6), and the
# measured error retraces at tolerance / RETRACE_FACTOR: below this a ray takes unbounded time.
MIN_TOLERANCE = 1e-10


# Peak memory of render() per pixel, whatever the sample count (samples are traced one after the
# other): the rays of one sample (origins, directions and their temporaries), the tracer's output
# for it and for the centre ray, and the sums of the colour and of the denoising guides (albedo,
# normal). Measured at about 580 bytes (2000 x 1000, all shading modes and projections;
# tests/render/test_render.py measures it again); rounded up.
BYTES_PER_PIXEL = 640
MAX_BOUNCES = 1024
DENOISE_MISSING = (
    "denoising needs Intel Open Image Denoise's Python binding: install the 'denoise' extra "
    "(pip install 'thurston[denoise]', or pip install pyoidn)"
)
MEMORY_FRACTION = 0.8  # refuse renders that would need more than this share of physical memory
# More threads than this gain nothing on any machine, and starting them all could take every
# process id of the system for a moment (each thread has one; 32768 by default).
MAX_THREADS = 4096


def memory_needed(width: int, height: int) -> int:
    return BYTES_PER_PIXEL * int(width) * int(height)


class RenderError(ValueError):
    """Input that cannot be rendered, with a message naming the problem."""


class Cancelled(RuntimeError):
    pass


# Blender's stereo convergence modes (Camera > Stereoscopy), its view layouts (Output > Views
# Format: two files, or Stereo 3D side by side / top-bottom) and its eyes
STEREO_MODES = ("off-axis", "parallel", "toe-in")
STEREO_LAYOUTS = ("side-by-side", "top-bottom", "separate")
STEREO_PIVOTS = ("center", "left", "right")  # where the camera is: between the eyes, or at one
EYES = ("left", "right")


@dataclass(frozen=True)
class Stereo:
    """Two eyes, as Blender's Stereoscopy places them: each offset from the camera by half the
    interocular distance (chart units; Blender's 0.065 and 1.95 are its defaults in metres) along
    the geodesic in the camera's right direction (pivot center; left or right: that eye at the
    camera, the other the whole distance from it; panoramas: center always). Perspective: off-axis (parallel eyes, lenses
    shifted so the views agree at the convergence distance), parallel, or toe-in (eyes turned to
    the point at the convergence distance). Panoramas: omni-directional stereo, each column's eye on
    the circle about the camera, the offset faded to 0 towards the poles between the pole-merge
    angles (degrees; None: no merging), and converged unless the mode is parallel. Layout: None is
    the projection's (side by side; top-bottom for panoramas, as headset players read them)."""

    interocular: float = 0.065
    convergence: float = 1.95
    mode: str = "off-axis"
    layout: str | None = None
    pole_merge: tuple[float, float] | None = (60.0, 75.0)
    pivot: str = "center"

    def layout_for(self, projection: str) -> str:
        """The layout asked for, else the projection's."""
        return self.layout or PROJECTIONS[projection].stereo_layout

    def offset(self, eye: str) -> float:
        """The eye's signed offset from the camera along its right direction (perspective)."""
        left = {"center": -0.5, "left": 0.0, "right": -1.0}[self.pivot] * self.interocular
        return left if eye == "left" else left + self.interocular

    def check(self):
        if not (isinstance(self.interocular, (int, float)) and 0 < self.interocular < math.inf):
            raise RenderError(f"stereo interocular distance must be a positive number, got {self.interocular}")
        if not (isinstance(self.convergence, (int, float)) and 0 < self.convergence < math.inf):
            raise RenderError(f"stereo convergence distance must be a positive number, got {self.convergence}")
        if self.mode not in STEREO_MODES:
            raise RenderError(f"unknown stereo mode {self.mode!r} ({', '.join(STEREO_MODES)})")
        if self.pivot not in STEREO_PIVOTS:
            raise RenderError(f"unknown stereo pivot {self.pivot!r} ({', '.join(STEREO_PIVOTS)})")
        if self.layout is not None and self.layout not in STEREO_LAYOUTS:
            raise RenderError(f"unknown stereo layout {self.layout!r} ({', '.join(STEREO_LAYOUTS)})")
        if self.pole_merge is not None:
            start, end = self.pole_merge
            if not 0 <= start < end <= 90:
                raise RenderError(
                    f"stereo pole merge angles must satisfy 0 <= from < to <= 90 degrees, got {start}, {end}"
                )


@dataclass
class Settings:
    width: int = 640
    height: int = 360
    projection: str = "perspective"  # a name in PROJECTIONS
    quality: str = "standard"
    samples: int | None = None  # samples per pixel; None: the quality's
    shading: str = "lambert"
    max_distance: float | None = None  # None: the space's default
    max_crossings: int | None = None
    fog: float | None = None  # distance at which colour falls to 1/e; None: no fog
    # geodesics to lights longer than this are not summed; None: default_light_reach
    light_reach: float | None = None
    threads: int = 0
    tolerance: float | None = None  # chord tolerance in chart units (S2xR: metric); None: the quality's bound
    light_samples: int = 4  # points sampled on the emissive meshes per shaded point (each sample)
    # shadow walks per shaded point for direct light: the strongest geodesics to the lights' copies
    # always, the rest sampled by their unshadowed light (unbiased); 0: every geodesic (the exact
    # sum); None: automatic (PATH_TRACED_LIGHT_PATHS with bounces, else the exact sum)
    light_paths: int | None = None
    # texels per cube-face edge of each point light's visibility map, which answers whether the
    # light reaches a point along a geodesic in place of its shadow walk (0: none, every geodesic
    # walked; None: automatic, map_texels)
    light_map: int | None = None
    bounces: int = 0  # bounces after each camera hit (path tracing, any quality); 0: direct light only
    seed: int = 0  # sample k's random numbers (light samples, bounces) come from seed + k
    transparent: bool = False  # alpha: the share of a pixel's samples that hit something (else 1)
    # (x, y, w, h): render only this window of the width x height image, x, y its top-left pixel
    # (rows top-down); None: the whole image
    region: tuple[int, int, int, int] | None = None
    # adaptive sampling (Cycles' meaning): a pixel stops taking samples once the standard error of
    # its mean brightness is below noise_threshold, after min_samples (0: automatic, min(4, samples));
    # 0: off, every pixel takes every sample
    noise_threshold: float = 0.0
    min_samples: int = 0
    # seconds: no sample pass starts after this much time (the pass under way finishes); None: no limit
    time_limit: float | None = None
    # denoise the colour with Intel Open Image Denoise (its RT filter, guided by the albedo and the
    # normal passes) after the samples; the colour before it is kept as the noisy pass
    denoise: bool = False
    # the OIDN shared library to denoise with (Blender's own); None: the pyoidn binding's
    denoiser: str | None = None
    # two eyes (render/stereo.py); a render is one eye's view: `eye` is one of EYES (None: the
    # camera's own view)
    stereo: Stereo | None = None
    eye: str | None = None

    @property
    def window(self) -> tuple[int, int, int, int]:
        return self.region or (0, 0, self.width, self.height)

    @property
    def samples_per_pixel(self) -> int:
        """The samples per pixel: the given count, else the quality's."""
        return self.samples or QUALITY[self.quality].samples

    @property
    def light_budget(self) -> int:
        """Shadow walks per shaded point (0: the exact sum): the given count, else automatic."""
        if self.light_paths is not None:
            return self.light_paths
        return PATH_TRACED_LIGHT_PATHS if self.bounces else 0

    def map_texels(self, space: Space, pixel_angle: float, lights: int = 1) -> int:
        """Texels per cube-face edge of the point lights' visibility maps: the given count, else
        where geodesics are straight in the chart (E3, S3, H3) a texel the quality's texel_pixels
        pixels wide (at a face's centre, 2 / texels radians), within MAP_TEXELS and the `lights`
        maps' MAP_MEMORY; none in the other geometries, whose lookup needs the geodesic flowed to
        the light (docs/lighting.md, "Visibility maps")."""
        if self.light_map is not None:
            return self.light_map
        if not space.geometry.projective or self.shading != "lambert":
            return 0
        texels = min(
            2.0 / (QUALITY[self.quality].texel_pixels * pixel_angle),
            math.sqrt(MAP_MEMORY / (MAP_BYTES_PER_TEXEL * max(lights, 1))),
        )
        return int(min(max(round(texels), MAP_TEXELS[0]), MAP_TEXELS[1]))

    @property
    def min_samples_per_pixel(self) -> int:
        """The samples a pixel takes before adaptive sampling may stop it."""
        return min(self.min_samples or 4, self.samples_per_pixel)

    def check(self):
        if self.width < 1 or self.height < 1:
            raise RenderError(f"image size {self.width}x{self.height} is not usable")
        if self.region is not None:
            x, y, w, h = self.region
            if not (
                all(_whole(v) for v in self.region)
                and w >= 1
                and h >= 1
                and 0 <= x
                and x + w <= self.width
                and 0 <= y
                and y + h <= self.height
            ):
                raise RenderError(
                    f"render region {self.region} is not a window of the {self.width}x{self.height} image"
                )
        need, have = memory_needed(*self.window[2:]), physical_memory()  # only the window is rendered
        if have is not None and need > MEMORY_FRACTION * have:
            raise RenderError(
                f"{'render region' if self.region else 'image size'} {self.window[2]}x{self.window[3]} needs about {need / 2**30:.1f} GiB of memory "
                f"to render, more than {MEMORY_FRACTION:.0%} of this machine's {have / 2**30:.1f} GiB"
            )
        if self.width * self.height > 2**28:
            raise RenderError(f"image size {self.width}x{self.height} is not usable (more than 2^28 pixels)")
        if self.projection not in PROJECTIONS:
            raise RenderError(f"unknown projection {self.projection!r} ({', '.join(PROJECTIONS)})")
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
        if self.light_reach is not None and not self.light_reach >= 0:
            raise RenderError(
                f"light reach must be a distance >= 0 (None: the space's default), got {self.light_reach}"
            )
        if not (_whole(self.light_samples) and 1 <= self.light_samples <= 4096):
            raise RenderError(f"light samples must be a whole number between 1 and 4096, got {self.light_samples}")
        if self.light_map is not None and not (_whole(self.light_map) and 0 <= self.light_map <= MAX_MAP_TEXELS):
            raise RenderError(
                f"light map must be a whole number of texels per cube-face edge from 0 (none: every geodesic "
                f"walked) to {MAX_MAP_TEXELS}, got {self.light_map}"
            )
        if self.light_paths is not None and not (_whole(self.light_paths) and 0 <= self.light_paths <= 2**20):
            raise RenderError(
                f"light paths must be a whole number of shadow walks per shaded point from 0 (every "
                f"geodesic: the exact sum) to {2**20}, got {self.light_paths}"
            )
        if not (_whole(self.bounces) and 0 <= self.bounces <= MAX_BOUNCES):
            raise RenderError(
                f"bounces must be a whole number between 0 (direct light only) and {MAX_BOUNCES}, got {self.bounces}"
            )
        if not (_whole(self.seed) and 0 <= self.seed < 2**63):
            raise RenderError(f"seed must be a whole number >= 0, got {self.seed}")
        if not (_whole(self.threads) and 0 <= self.threads <= MAX_THREADS):
            raise RenderError(f"threads must be a whole number from 0 (all cores) to {MAX_THREADS}, got {self.threads}")
        if self.tolerance is not None and not (MIN_TOLERANCE <= self.tolerance < math.inf):
            raise RenderError(
                f"tolerance must be a number of chart units of at least {MIN_TOLERANCE:g} (None: the "
                f"quality's), got {self.tolerance}"
            )

        if not (isinstance(self.noise_threshold, (int, float)) and 0 <= self.noise_threshold < math.inf):
            raise RenderError(f"noise threshold must be a number >= 0 (0: off), got {self.noise_threshold}")
        if not (_whole(self.min_samples) and 0 <= self.min_samples <= self.samples_per_pixel):
            raise RenderError(
                f"min samples must be a whole number from 0 (automatic) to the samples per pixel "
                f"({self.samples_per_pixel}), got {self.min_samples}"
            )
        if self.time_limit is not None and not (
            isinstance(self.time_limit, (int, float)) and 0 <= self.time_limit < math.inf
        ):
            raise RenderError(f"time limit must be a number of seconds >= 0 (None or 0: none), got {self.time_limit}")
        if self.stereo is not None:
            self.stereo.check()
        if self.eye is not None and (self.eye not in EYES or self.stereo is None):
            raise RenderError(f"eye {self.eye!r} needs stereo settings and is one of {', '.join(EYES)}")
        if self.denoise and self.denoiser is None and importlib.util.find_spec("pyoidn") is None:
            raise RenderError(DENOISE_MISSING)  # refused before the render, not after it

    def tolerances(self, space: Space, pixel_angle: float) -> tuple[float, float]:
        """(tolerance at distance 0, growth per unit of distance) of the chords, chart units (S2xR:
        metric, which its walk scales to the chart): the given tolerance, or the quality's fraction
        of the pixel footprint (footprint()) times the geometry's chord_scale, which
        benchmarks/bench_front.py derives from the measured error/time front (docs/front.md, "The
        chord rule")."""
        if self.tolerance is not None:
            return self.tolerance, 0.0
        fraction = space.geometry.chord_scale * QUALITY[self.quality].footprint_fraction
        return fraction * footprint(space, pixel_angle, 0.0), fraction * pixel_angle


def footprint(space: Space, pixel_angle: float, depth):
    """The pixel footprint at geodesic distance depth that the qualities' bounds are fractions of
    (a straight-line view's, with distances counted from NEAR_FRACTION of the domain's metric
    extent behind the camera)."""
    return pixel_angle * (depth + NEAR_FRACTION * space.metric_extent)


def _whole(n) -> bool:
    return isinstance(n, (int, np.integer)) and not isinstance(n, bool)
