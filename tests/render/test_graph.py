"""Rendering graphs of Gaussians (geometries/graph.py, src/core/graph.hpp): with f = 0 the image and
hits equal E3's (the same torus traced by the projective kernel); with bumps the measured error
(hits re-traced at 1/100 of the tolerance) stays within the stated bound; the shading is the
pseudo-colour modes only, and a lit render is refused with one clear error."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from thurston_addon import render, scenes, spaces

SETTINGS = dict(width=48, height=32, quality="draft", shading="normal")


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


@pytest.mark.slow
def test_a_bump_bends_the_rays_within_the_measured_bound():
    """graph_local: the image differs from the flat one where the bump lies, and the hits, re-traced
    at 1/100 of the tolerance, lie within a pixel footprint."""
    space = spaces.load("graph_local")
    settings = render.Settings(**SETTINGS)
    result = render.render(space, scenes.default_scene(space), settings)
    flat = render.render(spaces.load("graph_flat"), scenes.default_scene(space), settings)
    changed = np.any(result.passes["position"] != flat.passes["position"], axis=-1)
    assert 0.05 < changed.mean()
    assert result.stats["measured_error_pixels"] <= 1.0


def test_lit_renders_are_refused():
    space = spaces.load("graph_local")
    with pytest.raises(render.RenderError, match="pseudo-colour"):
        render.render(space, scenes.default_scene(space), render.Settings(width=8, height=8, quality="draft"))
    lit = scenes.default_scene(spaces.load("torus"))
    with pytest.raises(scenes.SceneError, match="no point lights"):
        render.render(space, lit, render.Settings(width=8, height=8, quality="draft", shading="normal"))
