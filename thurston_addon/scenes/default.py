"""The default scene of a space."""

from __future__ import annotations

import math

import numpy as np

from .model import PointLight, Scene, SceneObject

TUBE_HALVINGS = 8  # the most times a tube that would leave the chart or the copies around the domain is halved


def default_scene(space) -> Scene:
    """The domain drawn as thin tubes coloured by class (as in the paper's figures: edges by edge
    class, or face frames by face class, see Space.outline), a torus ring and a sphere off the
    centre, and a light near the camera."""
    import trimesh

    # the domain's size, but no more than twice its inscribed ball (SL2's fibre is long beside its disk)
    size = min(space.extent, 4 * space.chart_inradius)
    radius = 0.012 * size
    palette = np.array(
        [
            [0.9, 0.25, 0.2],
            [0.2, 0.7, 0.3],
            [0.25, 0.45, 0.95],
            [0.95, 0.8, 0.2],
            [0.8, 0.3, 0.85],
            [0.2, 0.8, 0.85],
            [0.95, 0.55, 0.2],
            [0.6, 0.6, 0.6],
            [0.55, 0.35, 0.2],
            [0.9, 0.5, 0.65],
        ]
    )
    objects = []
    # trimesh merges a mesh's vertices on a grid of 1e-8 in int64: a domain spanning more than about
    # 1e6 (S2xR's wide shells) has its meshes built at a power-of-two scale (exact) and scaled back
    unit = 1.0 if size < 1e6 else 2.0 ** round(math.log2(size))
    around = {space.geometry.element_key(M) for M in space.neighbourhood(1)}
    for c, segments in enumerate(space.outline(inset=2 * radius)):
        tubes = trimesh.util.concatenate(_tubes(space, segments, radius, unit, around))
        objects.append(SceneObject(f"edges {c}", tubes.vertices * unit, tubes.faces, palette[c % len(palette)]))
    inr = space.chart_inradius
    cam = space.camera
    forward = np.asarray(cam.forward, float) / np.linalg.norm(cam.forward)
    side = np.cross(forward, cam.up)
    side /= np.linalg.norm(side)
    up = np.cross(side, forward)
    ring = trimesh.creation.torus(
        major_radius=0.22 * inr / unit, minor_radius=0.07 * inr / unit, major_sections=48, minor_sections=16
    )
    ring.apply_transform(trimesh.geometry.align_vectors([0, 0, 1], forward + 0.6 * side + 0.4 * up))
    objects.append(
        SceneObject(
            "ring",
            ring.vertices * unit + cam.position + inr * (0.7 * forward + 0.25 * side),
            ring.faces,
            (0.95, 0.75, 0.3),
        )
    )
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.12 * inr / unit)
    objects.append(
        SceneObject(
            "sphere",
            ball.vertices * unit + cam.position + inr * (0.5 * forward - 0.45 * side - 0.1 * up),
            ball.faces,
            (0.3, 0.6, 0.95),
        )
    )
    g = space.geometry
    if not g.point_lights:  # (graph: the pseudo-colour modes only)
        return Scene(objects=objects, lights=[])
    # behind and above the camera; bright enough to light the walls one domain away
    position = np.asarray(cam.position, float) + 0.3 * inr * (up - 0.5 * forward)
    X = g.to_model(position)
    falloff = float(g.falloff_along(X, g.normalize_tangent(X, g.tangent_to_model(position, forward)), space.inradius))
    if space.group_order is not None:
        # a finite group: every copy lights every point (render/lights.py). An exposure choice: the
        # copies within two circumradii of the light (the ones the domain's tubes do not hide),
        # summed at the point one inradius ahead, give 0.5 there
        ahead = g.geodesic(X, g.normalize_tangent(X, g.tangent_to_model(position, forward)), space.inradius)[0]
        d = g.distance(ahead, np.array([M @ X for M in space.elements_within(2 * space.circumradius)]))
        falloff = float(np.sum(g.falloff(d)))
    light = PointLight(position, np.ones(3), 0.5 / falloff)
    return Scene(objects=objects, lights=[light])


def _tubes(space, segments, radius, unit, around: set) -> list:
    """Tubes along the segments (p, q), each halved in radius while it would leave the chart or
    the copies of the domain around it (`around`: their element keys), of which the render shows
    only those (a many-sided polygon's corners in H2xR's and SL2~'s disk lie within a tube's
    width of its rim: genus 3's at Klein radius 0.9974). All vertices are brought in at once."""
    import trimesh

    g = space.geometry
    radii = np.full(len(segments), radius)
    tubes = [None] * len(segments)
    todo = np.arange(len(segments))
    for _ in range(TUBE_HALVINGS):
        if not len(todo):
            break
        for i in todo:
            p, q = segments[i]
            tubes[i] = trimesh.creation.cylinder(radius=radii[i] / unit, segment=[p / unit, q / unit], sections=10)
        V = np.concatenate([tubes[i].vertices for i in todo]) * unit
        owner = np.repeat(todo, [len(tubes[i].vertices) for i in todo])
        ok = g.in_chart(V)
        # the isometries that bring the vertices in: few distinct, one per face or corner crossed
        homes = space.move_inside(g.to_model(V[ok]))[2].reshape(-1, 16)
        distinct, inverse = np.unique(homes, axis=0, return_inverse=True)
        known = [g.element_key(g.reorthonormalize(np.linalg.inv(M))) in around for M in distinct.reshape(-1, 4, 4)]
        ok[ok] = np.array(known, bool)[inverse.ravel()]
        todo = np.unique(owner[~ok])
        radii[todo] /= 2
    return tubes
