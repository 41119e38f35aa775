"""From a space and a scene to passes: the settings (settings), the scene compiled for the tracer
with the copies that objects sticking out of the domain need (compilation) and the lights' copies
(lights), the C++ tracer (tracer), the camera's rays (camera, by the table of projections), the
render loop (loop, colourised by the pass table: thurston_addon/passes.py) and the render's
statistics: cost and accuracy (statistics). This module re-exports the public API."""

from ..passes import PASSES, SHADING, STOP_REASONS
from .camera import camera_frame, camera_rays, clip_range, view_directions
from .compilation import compile_scene, geodesic_loop, own_hits
from .lights import LIGHT_TILE_LIMIT, cover_copies, default_light_reach, light_copies, light_reach_for, light_tiles
from .loop import CENTRE, render, render_eyes, sample_offsets
from .projections import PROJECTIONS
from .settings import (
    BYTES_PER_PIXEL,
    EYES,
    MAX_BOUNCES,
    MAX_MAP_TEXELS,
    MAX_THREADS,
    MIN_TOLERANCE,
    NEAR_FRACTION,
    PATH_TRACED_LIGHT_PATHS,
    QUALITY,
    REFERENCE_PIXEL_ANGLE,
    STEREO_LAYOUTS,
    STEREO_MODES,
    STEREO_PIVOTS,
    Cancelled,
    Quality,
    RenderError,
    Settings,
    Stereo,
    footprint,
    memory_needed,
)
from .statistics import Result, noise_of, pixel_errors, pixel_noise
from .stereo import eye_camera, side_by_side
from .tracer import core_scene, make_tracer, ray_block, trace

__all__ = [
    "BYTES_PER_PIXEL",
    "CENTRE",
    "EYES",
    "Cancelled",
    "LIGHT_TILE_LIMIT",
    "MAX_BOUNCES",
    "MAX_MAP_TEXELS",
    "MAX_THREADS",
    "MIN_TOLERANCE",
    "NEAR_FRACTION",
    "PASSES",
    "PATH_TRACED_LIGHT_PATHS",
    "PROJECTIONS",
    "QUALITY",
    "Quality",
    "REFERENCE_PIXEL_ANGLE",
    "RenderError",
    "Result",
    "SHADING",
    "STEREO_LAYOUTS",
    "STEREO_MODES",
    "STEREO_PIVOTS",
    "STOP_REASONS",
    "Settings",
    "Stereo",
    "camera_frame",
    "camera_rays",
    "clip_range",
    "compile_scene",
    "cover_copies",
    "default_light_reach",
    "footprint",
    "geodesic_loop",
    "eye_camera",
    "light_copies",
    "light_reach_for",
    "light_tiles",
    "core_scene",
    "make_tracer",
    "memory_needed",
    "noise_of",
    "own_hits",
    "pixel_errors",
    "pixel_noise",
    "ray_block",
    "render",
    "render_eyes",
    "side_by_side",
    "sample_offsets",
    "trace",
    "view_directions",
]
