"""The camera: its point and frame in the domain, the view directions of the pixels (by the
projection's table entry), the rays, and the clip range along them."""

from __future__ import annotations

import math

import numpy as np

from ..geometries.frames import orthonormalize
from ..scenes import Camera
from ..spaces import Space, SpaceError
from .projections import PROJECTIONS
from .settings import RenderError, Settings


def camera_frame(space: Space, camera: Camera):
    """Camera point (model) brought into the domain and an orthonormal frame (forward, right, up)
    there in the metric."""
    g = space.geometry
    p = np.asarray(camera.position, float)
    if not (np.all(np.isfinite(p)) and g.in_chart(p)):
        raise RenderError(f"camera position {p.tolist()} is not a point of {g.name}")
    f, u = np.asarray(camera.forward, float), np.asarray(camera.up, float)
    for label, v in (("forward", f), ("up", u)):
        if not np.all(np.isfinite(v)) or not np.any(v):
            raise RenderError(f"camera {label} {v.tolist()} must be a finite non-zero vector")
    f, u = f / np.abs(f).max(), u / np.abs(u).max()  # only the directions count (1e200 or 1e-200 alike)
    r = np.cross(f, u)
    if not np.linalg.norm(r) > 1e-12 * np.linalg.norm(f) * np.linalg.norm(u):
        raise RenderError(
            f"camera forward {np.asarray(camera.forward, float).tolist()} and up "
            f"{np.asarray(camera.up, float).tolist()} are parallel"
        )
    frame = [g.tangent_to_model(p, v) for v in (f, r, u)]
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # (an isometry that overflows is refused below)
            X, _, M = space.bring_inside(space.to_model(p[None], label=None)[0])
    except SpaceError as exc:
        raise RenderError(f"camera: {exc}") from None
    far = RenderError(
        f"camera position {p.tolist()} is too far out: the isometry that brings it into the domain "
        "overflows float64; place the camera nearer the domain (the view is the same from the copy there)"
    )
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        if not (np.all(np.isfinite(M)) and np.all(np.isfinite(X))):
            raise far
        basis = list(orthonormalize(g, X, np.stack([M @ v for v in frame])))
    if not all(np.all(np.isfinite(b)) for b in basis):
        raise far
    return X, basis


def view_directions(camera: Camera, settings: Settings, jitter=(0.5, 0.5)):
    """Unit directions of the window's pixels in the camera's orthonormal frame: the components
    (forward, right, up), each (h, w), rows top-down. The forward component is the cosine between a
    ray's initial direction and the optical axis."""
    W, H = settings.width, settings.height
    x0, y0, w, h = settings.window
    j = (x0 + np.arange(w) + jitter[0]) / W
    i = (y0 + np.arange(h) + jitter[1]) / H
    return PROJECTIONS[settings.projection].directions(camera, j, i, W, H)


def camera_rays(space: Space, camera: Camera, settings: Settings, jitter=(0.5, 0.5), frame=None, view=None, eyes=None):
    """Origins and unit directions (model) for every pixel of the window, rows top-down. `frame`:
    the result of camera_frame(space, camera), computed once per render and passed in for every
    sample; `view`: view_directions(camera, settings, jitter), where the caller has it; `eyes`: an
    omni-directional stereo view's eyes (stereo.OmniEyes), one per pixel. Rays start at their clip
    start (clip_range) along their geodesics, moved into the domain."""
    g = space.geometry
    X, (f, r, u) = frame if frame is not None else camera_frame(space, camera)
    a, b, c = view if view is not None else view_directions(camera, settings, jitter)
    if eyes is not None:
        origins, D = eyes.rays(a, b, c)
    else:
        D = np.ascontiguousarray((a[..., None] * f + b[..., None] * r + c[..., None] * u).reshape(-1, 4))
        origins = np.broadcast_to(X, (len(D), 4)).copy()
    if camera.clip_start > 0:
        origins, D = g.geodesic(origins, D, clip_range(camera, settings, a, math.inf)[0])
        origins, D, _ = space.move_inside(origins, D)
        origins, D = np.ascontiguousarray(origins, float), np.ascontiguousarray(D, float)
    return origins, D


def clip_range(camera: Camera, settings: Settings, along_axis, reach: float):
    """Per ray of the window, the geodesic distances (start, end) between which it sees: Blender's
    clipping, by planes square to the view axis at the clip distances (the ray's distance over its
    cosine to the axis, `along_axis`: view_directions' first part; panoramas: spheres), the end no
    farther than `reach`."""
    cos = np.ravel(along_axis) if PROJECTIONS[settings.projection].planar_clip else 1.0
    start = np.broadcast_to(camera.clip_start / cos, (settings.window[2] * settings.window[3],))
    return start, np.minimum(reach, (camera.clip_end or math.inf) / cos)


def camera_space_normals(space: Space, camera: Camera, settings: Settings, frame, view, origins, carried, hit):
    """The guide normal of each ray (the denoiser's, Blender's camera space): the hit's shading
    normal in the camera's frame (right, up, back = -forward) carried along the ray, from the
    core's carried_normal (the normal carried back to the ray's origin, as its chart image there);
    0 where nothing is hit. The frame is carried to a ray's origin as the core carries vectors:
    exactly in E3, S3 and H3 (in the model a vector normal to the geodesic's plane is parallel along
    it, and the part along the ray turns with its tangent), the same formula in the model for the
    marching geometries (an approximation there), then by the pairings that moved the origin into
    the domain."""
    g = space.geometry
    X, (f, r, u) = frame
    axes = (r, u, f)
    n = len(origins)
    if camera.clip_start > 0:
        a, b, c = view
        D = (a[..., None] * f + b[..., None] * r + c[..., None] * u).reshape(-1, 4)
        starts = np.broadcast_to(X, (n, 4))
        P, T = g.geodesic(starts, D, clip_range(camera, settings, a, math.inf)[0])
        moved, _, M = space.move_inside(P, T)
        carried_axes = []
        for w in axes:
            along = g.dot(starts, np.broadcast_to(w, (n, 4)), D)[:, None]
            moved_w = along * T + (w - along * D)
            carried_axes.append(np.einsum("nij,nj->ni", np.asarray(M, float), np.asarray(moved_w, float)))
        axes = carried_axes
        O = np.asarray(moved, float)
    else:
        O = np.broadcast_to(X, (n, 4))
        axes = [np.broadcast_to(w, (n, 4)) for w in axes]
    out = np.zeros((n, 3))
    if hit.any():
        Oh = np.asarray(O[hit], float)
        N = g.normalize_tangent(Oh, g.tangent_to_model(g.to_chart(Oh), np.asarray(carried[hit], float)))
        for k, w in enumerate(axes):
            out[hit, k] = g.dot(Oh, N, np.asarray(w[hit], float))
        out[hit, 2] *= -1.0
    return np.nan_to_num(out)
