"""Rendering graphs of Gaussians (geometries/graph.py, src/core/graph.hpp): with f = 0 the image and
hits equal E3's (the same torus traced by the projective kernel); on every preset each pixel's hit,
re-traced here at 1/100 of the tolerance, stays within the stated bound; the shading is the
pseudo-colour modes only, and a lit render is refused with one clear error."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from thurston_addon import render, scenes, spaces

SETTINGS = dict(width=48, height=32, quality="draft", shading="normal")
GRAPHS = ("graph_flat", "graph_local", "graph_global", "graph_two", "graph_r3")


def euclidean_twin(name):
    """The preset's torus as an E3 space (the same generators, faces and camera)."""
    data = tomllib.loads(spaces.preset_path(name).read_text())
    data = {k: v for k, v in data.items() if k != "graph"}
    return spaces.from_data({**data, "geometry": "E3", "id": f"{name}_e3"}, f"{name}_e3.toml")


def test_flat_graph_renders_as_e3():
    graph, flat = spaces.load("graph_flat"), euclidean_twin("graph_flat")
    scene = scenes.default_scene(graph)
    settings = render.Settings(**SETTINGS)
    got = render.render(graph, scene, settings).passes
    want = render.render(flat, scene, settings).passes
    assert np.array_equal(got["object"], want["object"])
    hit = got["object"] >= 0
    assert hit.mean() > 0.5
    np.testing.assert_allclose(got["depth"][hit], want["depth"][hit], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(got["position"][hit], want["position"][hit], rtol=0, atol=1e-9)


def test_a_bump_bends_the_rays():
    """graph_local: the image differs from the flat one where the bump lies."""
    space = spaces.load("graph_local")
    settings = render.Settings(**{**SETTINGS, "width": 32, "height": 20})
    result = render.render(space, scenes.default_scene(space), settings)
    flat = render.render(spaces.load("graph_flat"), scenes.default_scene(space), settings)
    changed = np.any(result.passes["position"] != flat.passes["position"], axis=-1)
    assert 0.05 < changed.mean()


@pytest.mark.parametrize("name", GRAPHS)
def test_hits_within_the_stated_bound_of_a_retrace_at_a_hundredth(name):
    """Every pixel's hit (the centre rays of a preview render, 32x20) against the same ray traced
    again here at 1/100 of the render's chord tolerance: where both meet the same object, the hits
    lie within the bound the render states (the quality's fraction of the pixel footprint at the
    hit's distance), as does the render's own measured error (its sample of re-traced rays)."""
    space = spaces.load(name)
    scene = scenes.default_scene(space)
    settings = render.Settings(width=32, height=20, quality="preview", shading="normal", threads=2)
    result = render.render(space, scene, settings)
    fraction = render.QUALITY["preview"].footprint_fraction
    assert f"hit positions within {fraction:g} of the pixel footprint" in result.stats["bound"]
    assert result.stats["measured_error_pixels"] <= fraction

    camera = scene.camera or space.camera
    camera = scenes.Camera(camera.position, camera.forward, camera.up, camera.fov)
    pixel_angle = render.PROJECTIONS["perspective"].width_angle(camera) / settings.width
    tolerance, per_distance = settings.tolerances(space, pixel_angle)
    origins, directions = render.camera_rays(space, camera, settings, render.CENTRE)
    fine = render.trace(
        render.make_tracer(space, scene, 2),
        origins,
        directions,
        space.max_distance,
        space.max_crossings,
        tolerance / 100,
        per_distance / 100,
        shade=False,
    )
    passes = result.passes
    same = (passes["object"].ravel() == fine["object"]) & (fine["object"] >= 0)
    assert same.mean() > 0.25 and (passes["object"].ravel() != fine["object"]).mean() < 0.03  # silhouettes
    g = space.geometry
    hit = g.to_model(passes["position"].reshape(-1, 3)[same])
    again = g.to_model(fine["position"][same])
    # (a hit on a face has an image on the paired face: the nearest copy counts)
    error = np.min(
        [np.linalg.norm(g.to_chart(hit) - g.to_chart(again @ M.T), axis=-1) for M in space.neighbourhood(1)], 0
    )
    bound = fraction * render.footprint(space, pixel_angle, fine["depth"][same])
    assert np.all(error <= bound), f"{(error / bound).max():.3g} of the bound"
    if name != "graph_flat":  # the bumps bend the rays: the check measures something
        assert error.max() > 1e-9


def test_lit_renders_are_refused():
    space = spaces.load("graph_local")
    with pytest.raises(render.RenderError, match="pseudo-colour"):
        render.render(space, scenes.default_scene(space), render.Settings(width=8, height=8, quality="draft"))
    lit = scenes.default_scene(spaces.load("torus"))
    with pytest.raises(scenes.SceneError, match="no point lights"):
        render.render(space, lit, render.Settings(width=8, height=8, quality="draft", shading="normal"))


# --- R^3 (an open space: no generators) -------------------------------------------------------------
def box(name, centre, size):
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * size / 2
    faces = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1]]
    faces += [[2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    return scenes.SceneObject(name, corners + centre, np.array(faces), (0.7, 0.7, 0.7))


def straight_hits(origins, directions, objects):
    """(object, distance) of each chart ray's first hit on the objects' triangles (Moller-Trumbore),
    (-1, inf) for none."""
    best, which = np.full(len(origins), np.inf), np.full(len(origins), -1)
    for k, obj in enumerate(objects):
        for a, b, c in obj.vertices[obj.triangles]:
            e1, e2 = b - a, c - a
            p = np.cross(directions, e2)
            det = p @ e1
            s = origins - a
            u = np.sum(s * p, axis=1) / det
            q = np.cross(s, e1)
            v = np.sum(directions * q, axis=1) / det
            t = q @ e2 / det
            hit = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t < best)
            best[hit], which[hit] = t[hit], k
    return which, best


def test_r3_with_f_zero_is_e3s_straight_lines_to_the_distance_limit():
    """graph_r3 with no bump: every ray is a chart line, its hit the nearest triangle along it
    (boxes in and far beyond the region, one beyond the distance limit), no crossing, and the rays
    that meet nothing run to the distance limit."""
    data = tomllib.loads(spaces.preset_path("graph_r3").read_text())
    space = spaces.from_data({**data, "graph": {}, "id": "r3_flat"}, "r3_flat.toml")
    objects = [
        box("near", (0.6, 1.5, 0.3), 0.5),
        box("beyond the region", (-3.5, 7.0, 1.0), 2.0),
        box("far", (4.0, 10.0, 1.5), 2.0),
        box("beyond the limit", (0.5, 13.5, 0.5), 3.0),
    ]
    scene = scenes.Scene(objects=objects)
    settings = render.Settings(width=32, height=20, quality="draft", shading="normal", threads=2)
    passes = render.render(space, scene, settings).passes
    cam = space.camera
    camera = scenes.Camera(cam.position, cam.forward, cam.up, cam.fov)
    origins, directions = render.camera_rays(space, camera, settings, render.CENTRE)
    g = space.geometry
    x, d = g.to_chart(origins), g.tangent_to_chart(origins, directions)
    which, t = straight_hits(x, d, objects)
    hit = t <= space.max_distance
    assert set(which[hit]) == {0, 1, 2} and (which == 3).any()  # the last only beyond the limit
    np.testing.assert_array_equal(passes["object"].ravel(), np.where(hit, which, -1))
    np.testing.assert_allclose(passes["depth"].ravel()[hit], t[hit], rtol=0, atol=1e-9)
    np.testing.assert_allclose(passes["position"].reshape(-1, 3)[hit], (x + t[:, None] * d)[hit], rtol=0, atol=1e-9)
    assert np.all(passes["crossings"] == 0)
    stop = np.asarray(render.STOP_REASONS)[passes["stop"].ravel()]
    assert np.all(stop[hit] == "hit") and np.all(stop[~hit] == "distance")


def test_r3_refuses_what_its_rays_could_not_see_as_r3():
    """A longer max distance than the file's, a camera outside the region, an object beyond the
    cube the rays never leave: one clear error each (never a copy that R^3 does not have)."""
    space = spaces.load("graph_r3")
    near = scenes.Scene(objects=[box("near", (0.6, 1.5, 0.3), 0.5)])
    quick = dict(width=8, height=6, quality="draft", shading="normal")
    with pytest.raises(render.RenderError, match="max distance 30 is longer than 'graph_r3' allows"):
        render.render(space, near, render.Settings(**quick, max_distance=30))
    with pytest.raises(render.RenderError, match="outside the region of interest"):
        render.render(
            space, near, render.Settings(**quick), camera=scenes.Camera([0, 0, 3.5], [0, 1, 0], [0, 0, 1], 60)
        )
    far = scenes.Scene(objects=[box("far", (0.0, space.half + 4, 0.0), 1.0)])
    with pytest.raises(scenes.SceneError, match="object 'far'.*beyond the reach of the rays"):
        render.render(space, far, render.Settings(**quick))
