"""The camera projections, in one table (PROJECTIONS): how each maps the image to view directions,
the angle its width spans, and how it clips."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Projection:
    name: str
    # (camera, j, i, W, H) -> the unit view directions' components (forward, right, up), each (h, w),
    # of the pixels at fractions j (columns, left to right) and i (rows, top-down) of the image W x H
    directions: Callable
    width_angle: Callable  # camera -> the angle the image's width spans, radians
    # clipping by planes square to the view axis (Blender's cameras); else by spheres (panoramas)
    planar_clip: bool
    # stereo: omni-directional (each column's own eye on a circle about the camera: panoramas),
    # else two eyes of one frame each; and the layout of the two views where none is asked for
    omni_stereo: bool
    stereo_layout: str


def _perspective(camera, j, i, W, H):
    h, w = len(i), len(j)
    t = math.tan(math.radians(camera.fov) / 2)
    sx = (2 * j - 1 + 2 * camera.shift[0]) * t
    sy = ((1 - 2 * i) * H / W + 2 * camera.shift[1]) * t
    a, b, c = np.ones((h, w)), np.broadcast_to(sx, (h, w)), np.broadcast_to(sy[:, None], (h, w))
    n = np.sqrt(a * a + b * b + c * c)
    return a / n, b / n, c / n


def _equirect(camera, j, i, W, H):
    """Equirectangular: longitude 0 is forward, increasing to the right; latitude up."""
    h, w = len(i), len(j)
    lon = (2 * j - 1) * math.pi
    lat = (0.5 - i) * math.pi
    return (
        np.cos(lat)[:, None] * np.cos(lon)[None, :],
        np.cos(lat)[:, None] * np.sin(lon)[None, :],
        np.broadcast_to(np.sin(lat)[:, None], (h, w)),
    )


PROJECTIONS = {
    p.name: p
    for p in (
        Projection(
            "perspective",
            _perspective,
            lambda camera: math.radians(camera.fov),
            planar_clip=True,
            omni_stereo=False,
            stereo_layout="side-by-side",
        ),
        Projection(
            "equirect",
            _equirect,
            lambda camera: 2 * math.pi,
            planar_clip=False,
            omni_stereo=True,
            stereo_layout="top-bottom",
        ),
    )
}
