"""The render's passes, in one table (PASS_TABLE): each pass's name (the core's output it comes
from, the key of a render's passes, the command line's --passes name, the add-on's Passes item),
its EXR channels, the pseudo-colour mode that shows it (the Shading menu) and the Blender passes
the engine fills from it. Everything else that lists passes is derived from it here. The colour's
alpha (Blender's Combined) is no pass of its own."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class BlenderPass:
    """A render pass the engine fills besides Combined."""

    name: str  # Blender's pass name
    chan_id: str  # Blender's channel letters; their number is the channel count
    type: str  # VALUE, VECTOR or COLOR
    flag: str  # the view layer property that enables it
    addon_flag: bool  # the flag is on view_layer.thurston (the add-on's), not on the view layer
    description: str = ""  # the add-on's own flag's tooltip (addon_flag)
    label: str = ""  # the add-on's own flag's name where several passes share it (else the pass's name)
    source: str = ""  # the render pass it comes from; render-blend enables it from the settings (set below)


@dataclass(frozen=True)
class ShadingMode:
    """A Shading menu entry: a pseudo-colour image of a pass, from the core's output `out` of the
    rays (arrays per ray) and the rays that hit."""

    name: str
    place: int  # in the Shading menu
    colour: Callable  # (out, hit, space) -> (n, 3) float64 colours


@dataclass(frozen=True)
class Pass:
    name: str
    channels: tuple[str, ...]  # EXR channel names (Blender-like layer.channel names)
    shading: ShadingMode | None = None
    blender: tuple[BlenderPass, ...] = ()
    length: bool = False  # a length in chart units (Blender: in world units, times the scale)


def _lambert(out, hit, space):
    return out["color"].astype(np.float64)


def _normal(out, hit, space):
    return np.where(hit[:, None], 0.5 + 0.5 * np.nan_to_num(out["normal"]), 0.0)


def _position(out, hit, space):
    lo, hi = space.domain.vertices.min(axis=0), space.domain.vertices.max(axis=0)
    return np.where(hit[:, None], np.clip((np.nan_to_num(out["position"]) - lo) / (hi - lo), 0, 1), 0.0)


def _depth(out, hit, space):
    d = np.where(hit, out["depth"], 0.0)
    scale = np.percentile(d[hit], 95) if hit.any() else 1.0
    return np.repeat(np.where(hit, 1 - np.clip(d / max(scale, 1e-12), 0, 1), 0.0)[:, None], 3, axis=1)


def _crossings(out, hit, space):
    n = out["crossings"].astype(np.float64)
    return np.repeat((n / max(1.0, n.max()))[:, None], 3, axis=1)


def _object(out, hit, space):
    """A distinct hue per object index, base colour for lookups."""
    idx = out["object"]
    hue = (idx * 0.618034) % 1.0
    return np.where(hit[:, None], np.stack([_hue(hue + o) for o in (0, 1 / 3, 2 / 3)], axis=1), 0.0)


def _hue(h):
    return 0.5 + 0.5 * np.cos(2 * math.pi * h)


# Cycles' "Denoising Data" switch of a view layer: the denoiser's guides and the noisy colour.
_DENOISING_DATA = (
    "denoising_store_passes",
    True,
    "Write the denoiser's guides (Denoising Albedo, Denoising Normal) and the colour before "
    "denoising (Noisy Image), for the compositor's Denoise node",
    "Denoising Data",
)

PASS_TABLE = (
    Pass("color", ("R", "G", "B"), ShadingMode("lambert", 0, _lambert)),
    Pass(
        "depth",
        ("Z",),
        ShadingMode("depth", 3, _depth),
        (
            BlenderPass("Depth", "Z", "VALUE", "use_pass_z", False),
            BlenderPass(
                "Geodesic Distance",
                "X",
                "VALUE",
                "use_pass_geodesic_distance",
                True,
                "The length of the geodesic from the camera to the hit (Blender units)",
            ),
        ),
        length=True,
    ),
    Pass(
        "normal",
        ("Normal.X", "Normal.Y", "Normal.Z"),
        ShadingMode("normal", 1, _normal),
        (BlenderPass("Normal", "XYZ", "VECTOR", "use_pass_normal", False),),
    ),
    Pass(
        "position",
        ("Position.X", "Position.Y", "Position.Z"),
        ShadingMode("position", 2, _position),
        (BlenderPass("Position", "XYZ", "VECTOR", "use_pass_position", False),),
        length=True,
    ),
    Pass(
        "object",
        ("IndexOB",),
        ShadingMode("object", 5, _object),
        (BlenderPass("IndexOB", "X", "VALUE", "use_pass_object_index", False),),
    ),
    Pass(
        "crossings",
        ("Crossings",),
        ShadingMode("crossings", 4, _crossings),
        (
            BlenderPass(
                "Crossings",
                "X",
                "VALUE",
                "use_pass_crossings",
                True,
                "How many times the ray crossed a face of the domain before the hit",
            ),
        ),
    ),
    Pass("stop", ("Stop",)),
    # The denoiser's guides (Cycles' denoising data): the first hit's diffuse albedo and its shading
    # normal in the camera's frame (right, up, back: Blender's camera space, carried back along the
    # ray), each averaged over the colour samples like the colour; 0 where nothing is hit.
    Pass(
        "albedo",
        ("Denoising Albedo.R", "Denoising Albedo.G", "Denoising Albedo.B"),
        blender=(BlenderPass("Denoising Albedo", "RGB", "COLOR", *_DENOISING_DATA),),
    ),
    Pass(
        "guide_normal",
        ("Denoising Normal.X", "Denoising Normal.Y", "Denoising Normal.Z"),
        blender=(BlenderPass("Denoising Normal", "XYZ", "VECTOR", *_DENOISING_DATA),),
    ),
    # The colour before denoising (only where the render was denoised: Settings.denoise).
    Pass(
        "noisy",
        ("Noisy Image.R", "Noisy Image.G", "Noisy Image.B"),
        blender=(BlenderPass("Noisy Image", "RGB", "COLOR", *_DENOISING_DATA),),
    ),
)

PASSES = tuple(p.name for p in PASS_TABLE)
CHANNELS = {p.name: p.channels for p in PASS_TABLE}  # EXR channels, in the order they are written
SHADING_MODES = {m.name: m for m in sorted((p.shading for p in PASS_TABLE if p.shading), key=lambda m: m.place)}
SHADING = tuple(SHADING_MODES)
# Every Blender pass the engine can fill: the engine registers and fills them, the View Layer panel
# shows their switches, render-blend turns them on from the settings' passes.
BLENDER_PASSES = tuple(replace(b, source=p.name) for p in PASS_TABLE for b in p.blender)
LENGTHS = tuple(p.name for p in PASS_TABLE if p.length)
STOP_REASONS = ("hit", "distance", "crossings", "cancelled")  # the stop pass's values, by index


def colorize(out, settings, space):
    """The colour of each ray in the settings' shading mode, dimmed by their fog."""
    hit = out["stop"] == 0
    color = SHADING_MODES[settings.shading].colour(out, hit, space)
    if settings.fog is not None:
        color = color * np.exp(-np.where(hit, out["depth"], 0.0) / settings.fog)[:, None]
    return color
