"""The direct-light tests' scene: a small ball, faintly emissive (so it casts no shadow on point
lights' light), lit by one point light; and the traced colour of one ray onto it."""

from __future__ import annotations

import math

import numpy as np
import trimesh

from thurston_addon import render
from thurston_addon.scenes import PointLight, Scene, SceneObject

RHO, GLOW = 0.5, 1e-3  # the ball's base colour and its faint emission (which makes it cast no shadow)


def ball_scene(centre, light, power=1.0):
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.02)
    return Scene(
        objects=[SceneObject("ball", ball.vertices + centre, ball.faces, (RHO,) * 3, emission=(GLOW,) * 3)],
        lights=[PointLight(np.asarray(light, float), np.ones(3), power)],
    )


def shade_one(space, scene, origin, target, light_reach, fog=math.inf):
    """The traced colour, model hit point and model unit normal of the ray from origin to target,
    and the trace's output."""
    g = space.geometry
    tracer = render.make_tracer(space, scene, threads=1, light_reach=light_reach)
    o, d = np.array([origin], float), np.array([target], float) - np.array([origin], float)
    P = g.to_model(o)
    D = g.normalize_tangent(P, g.tangent_to_model(o, d))
    out = tracer.trace(P, D, 2.0, 20, shade=True, fog=fog)
    assert out["stop"][0] == 0 and out["object"][0] == 0
    x, n = out["position"][0], out["normal"][0].astype(float)
    H = g.normalize_point(g.to_model(x[None]))[0]
    N = g.normalize_tangent(H[None], g.tangent_to_model(x[None], n[None]))[0]
    return out["color"][0].astype(float), H, N, out
