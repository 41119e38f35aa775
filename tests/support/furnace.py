"""The white furnace of the path-tracing tests (test_gi.py, test_light_sampling.py): a closed
emissive sphere of albedo rho about the camera point, rays from its centre, and the mean of
samples with its standard error."""

from __future__ import annotations

import math

import numpy as np
import trimesh

from thurston_addon import render
from thurston_addon.scenes import Scene, SceneObject

LE = 1.0


def random_rays(space, centre, n, seed, down=False):
    """n rays from centre in random directions (down: only downwards, towards mis_scene's slabs)."""
    g = space.geometry
    d = np.random.default_rng(seed).normal(size=(n, 3))
    if down:
        d[:, 2] = -np.abs(d[:, 2]) - 0.8
    d /= np.linalg.norm(d, axis=1)[:, None]
    o = np.repeat(np.asarray(centre, float)[None], n, axis=0)
    P = g.to_model(o)
    return np.ascontiguousarray(P), np.ascontiguousarray(g.normalize_tangent(P, g.tangent_to_model(o, d)))


def furnace_tracer(space, rho):
    """A finely divided chart sphere (sharp edges make the emitters' estimate heavy-tailed) around
    the default camera point, and a light reach over its metric diameter (farther copies are hidden
    behind it)."""
    centre = np.asarray(space.camera.position, float)
    radius = 0.4 * space.chart_inradius
    ball = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    walls = SceneObject("walls", ball.vertices + centre, ball.faces, (rho,) * 3, (LE,) * 3)
    g = space.geometry
    ends = g.to_model(centre + radius * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]))
    reach = 1.5 * float(max(g.distance_bound(ends[2 * a], ends[2 * a + 1]) for a in range(3)))
    return render.make_tracer(space, Scene(objects=[walls], lights=[]), threads=2, light_reach=reach), centre


def mean_and_error(values):
    values = np.asarray(values, float)
    return values.mean(), values.std(ddof=1) / math.sqrt(len(values))
