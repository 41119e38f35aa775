"""Stereo views (settings.Stereo): each eye placed along the geodesic from the camera in the
direction of its offset (the exponential map at the camera), its frame carried there by parallel
transport and then, with the eye, into the domain by the face pairings (so an eye whose offset
leaves the domain sees from where it is in the manifold, its frame turned as the pairing turns it);
and the two views laid out in one image (loop.render_eyes renders both with one tracer)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..geometries.frames import orthonormalize, parallel_transport
from ..scenes import Camera
from ..spaces import Space
from .projections import PROJECTIONS
from .settings import Settings
from .statistics import Result


def eye_sign(eye: str) -> float:
    """The side of the camera an eye is on, along its right direction."""
    return -1.0 if eye == "left" else 1.0


def eye_view(space: Space, camera: Camera, settings: Settings, frame):
    """The camera, frame and per-pixel eyes (OmniEyes, or None) of settings.eye's view, from the
    camera's own frame (camera_frame). Perspective: the eye's frame at its point, offset by
    Stereo.offset; off-axis shifts the lens by Blender's formula, the offset over twice the
    convergence distance, in image widths at unit distance, towards the camera's axis; toe-in turns
    the eye by atan(offset / convergence) to the point at the convergence distance on the camera's
    axis (both as Blender's Stereoscopy does, in the camera's tangent space)."""
    stereo = settings.stereo
    if PROJECTIONS[settings.projection].omni_stereo:
        return camera, frame, OmniEyes(space, settings, frame, eye_sign(settings.eye))
    X, (f, r, u) = frame
    offset = stereo.offset(settings.eye)
    points, (f, r, u) = carried_frames(
        space, X[None], math.copysign(1.0, offset) * r[None], abs(offset), np.stack([f, r, u])[None]
    )
    eye_frame = (points[0], [f[0], r[0], u[0]])
    if stereo.mode == "toe-in":
        turn = math.atan(offset / stereo.convergence)
        c, s = math.cos(turn), math.sin(turn)
        eye_frame = (points[0], [c * f[0] - s * r[0], c * r[0] + s * f[0], u[0]])
    return eye_camera(camera, settings), eye_frame, None


def eye_camera(camera: Camera, settings: Settings) -> Camera:
    """The camera of settings.eye's perspective view: off-axis, its lens shifted."""
    stereo = settings.stereo
    if stereo.mode != "off-axis" or PROJECTIONS[settings.projection].omni_stereo:
        return camera
    shift = -stereo.offset(settings.eye) / (2 * stereo.convergence * math.tan(math.radians(camera.fov) / 2))
    return dataclasses.replace(camera, shift=(camera.shift[0] + shift, camera.shift[1]))


def carried_frames(space: Space, X, V, t: float, vectors):
    """From model points X (N, 4) along the unit tangents V (N, 4) for arclength t: the end points
    and the frames vectors (N, k, 4) carried there by parallel transport, both moved into the
    domain, the frames by the pairings' isometries; the frames as a list of k arrays (N, 4)."""
    g = space.geometry
    points, _, carried = parallel_transport(g, X, V, t, vectors)
    moved, _, M = space.move_inside(points, label="stereo eye")
    turned = np.einsum("nij,nkj->nki", np.asarray(M, float), carried)
    moved = np.asarray(moved, float)
    return moved, list(np.moveaxis(orthonormalize(g, moved, turned), 1, 0))


def pole_fade(altitude, angles):
    """Blender's pole merging: the eye offset's factor at view altitudes (radians, >= 0): 1 below
    the first angle, 0 above the second, cos(pi/2 s) between (s from 0 to 1); 1 without merging."""
    if angles is None:
        return np.ones_like(altitude)
    start, end = np.radians(angles)
    s = np.clip((altitude - start) / (end - start), 0.0, 1.0)
    return np.where(altitude > end, 0.0, np.cos(s * math.pi / 2))


class OmniEyes:
    """Omni-directional stereo (Cycles' spherical stereo): the eye of a pixel is on the circle of
    radius interocular / 2 about the camera in its horizontal plane, offset along side = the view
    direction x up (the right of the pixel's longitude), by the pole-merge factor of its latitude;
    converged (unless the mode is parallel) by turning each ray to the point at the convergence
    distance along its direction from the camera, as Cycles does. The eye is placed for the pixel's
    centre (its samples share it: a sample's own longitude would move the eye by at most half a
    pixel's angle times interocular / 2), so the eyes and their frames are carried once per render,
    one per column and offset length."""

    def __init__(self, space: Space, settings: Settings, frame, sign: float):
        stereo = settings.stereo
        X, (f, r, u) = frame
        x0, y0, w, h = settings.window
        lon = (2 * (x0 + np.arange(w) + 0.5) / settings.width - 1) * math.pi
        lat = (0.5 - (y0 + np.arange(h) + 0.5) / settings.height) * math.pi
        lengths = stereo.interocular / 2 * pole_fade(np.abs(lat), stereo.pole_merge)
        distinct, self.row_eyes = np.unique(lengths, return_inverse=True)
        # the side direction of each column: components on (forward, right, up), and as a model vector
        side = np.stack([-np.sin(lon), np.cos(lon), np.zeros(w)], axis=1)
        V = sign * (side[:, :1] * f + side[:, 1:2] * r)
        start = np.broadcast_to(X, (w, 4))
        vectors = np.broadcast_to(np.stack([f, r, u]), (w, 3, 4))
        points, frames = [], []
        for length in distinct:
            p, axes = carried_frames(space, start, V, float(length), vectors)
            points.append(p)
            frames.append(np.stack(axes, axis=1))
        self.points = np.stack(points)  # (offset lengths, w, 4)
        self.frames = np.stack(frames)  # (offset lengths, w, 3, 4)
        # each pixel's offset from the camera in the camera's frame, for convergence
        self.offsets = (sign * lengths)[:, None, None] * side[None]
        self.convergence = None if stereo.mode == "parallel" else stereo.convergence

    def rays(self, a, b, c):
        """Origins and unit directions (model) of the window's pixels for view directions with
        components (forward, right, up), each (h, w)."""
        D = np.stack([a, b, c], axis=-1)
        if self.convergence is not None:
            D = self.convergence * D - self.offsets
            D /= np.linalg.norm(D, axis=-1, keepdims=True)
        origins = self.points[self.row_eyes]
        directions = np.einsum("hwk,hwkj->hwj", D, self.frames[self.row_eyes])
        return np.ascontiguousarray(origins.reshape(-1, 4)), np.ascontiguousarray(directions.reshape(-1, 4))


def side_by_side(left: Result, right: Result, layout: str) -> dict:
    """The two views' passes in one image: left beside right (left on the left), or left above
    right, as Blender's Stereo 3D side-by-side and top-bottom formats and headset players lay them."""
    axis = 1 if layout == "side-by-side" else 0
    return {name: np.concatenate([left.passes[name], right.passes[name]], axis=axis) for name in left.passes}
