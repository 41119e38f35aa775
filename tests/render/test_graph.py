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
GRAPHS = ("graph_flat", "graph_local", "graph_global", "graph_two")


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
    assert same.mean() > 0.5 and (passes["object"].ravel() != fine["object"]).mean() < 0.03  # silhouettes
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
