"""Visibility maps (docs/lighting.md, "Visibility maps"): a point light's geodesics answered from a
cube map of its first-occluder distances, against the closed-form sums over copies and against
the exact sum of shadow walks."""

import math

import numpy as np
import pytest
from support.lit_ball import GLOW, RHO, ball_scene

from thurston_addon import render, spaces
from thurston_addon.scenes import default_scene


def test_an_unshadowed_point_gets_the_closed_form_sum_over_the_120_copies():
    """S3, the Poincare sphere: with nothing between the light's copies and the point, every texel
    about each geodesic reaches the point, so the map's answers give the closed form of test_light
    (sum over the 120 copies of |N . u| p / sin^2 d), whatever the texels per face. The ball glows
    (it is not opaque: no geodesic loop), so the long arcs, beyond the maps' walks (pi), are walked;
    the short ones are looked up."""
    space = spaces.load("poincare")
    g = space.geometry
    light, power = np.array([0.08, -0.05, 0.12]), 0.3
    scene = ball_scene([0.0, 0.15, 0.0], light, power)
    tracer = render.make_tracer(space, scene, threads=1, light_reach=None)
    o, d = np.array([[0.0, -0.1, 0.0]]), np.array([[0.0, 0.25, 0.0]])
    P = g.to_model(o)
    D = g.normalize_tangent(P, g.tangent_to_model(o, d))
    L = g.normalize_point(g.to_model(light[None]))[0]
    for texels in (16, 256):
        out = tracer.trace(P, D, 2.0, 20, shade=True, visibility_map=texels)
        x, n = out["position"][0], out["normal"][0].astype(float)
        H = g.normalize_point(g.to_model(x[None]))[0]
        N = g.normalize_tangent(H[None], g.tangent_to_model(x[None], n[None]))[0]
        total, short = 0.0, 0
        for M in space.elements_within(math.pi + 1e-6):
            Y = M @ L
            u = Y - (H @ Y) * H
            total += abs(N @ u / np.linalg.norm(u)) * power / (1 - (H @ Y) ** 2)
            short += N @ u > 0
        np.testing.assert_allclose(out["color"][0], GLOW + RHO * total, rtol=1e-4)
        assert out["light_paths"] == 120 and out["map_lookups"] == short > 30
        assert 0 < out["map_texels"] <= 4 * short


@pytest.mark.parametrize("space_id", ["torus", "poincare", "seifert_weber", "flat(amphidicosm1)"])
def test_a_maps_image_is_the_exact_sums_within_its_stated_error(space_id):
    """The default scene at standard quality with the automatic map, against the exact sum (a shadow
    walk for every geodesic) at the same sample positions: they differ only near shadow edges, by
    at most the map's error as the render states it (the share of the checked geodesics' light that
    their walks found otherwise); the light summed over the image agrees to that share too. A
    non-orientable flat space (amphidicosm1's glide reflection) checks the light's frame carried by
    orientation-reversing copies."""
    space = spaces.load(space_id)
    scene = default_scene(space)
    common = dict(width=96, height=54, quality="standard", threads=2)
    exact = render.render(space, scene, render.Settings(**common, light_map=0))
    mapped = render.render(space, scene, render.Settings(**common))
    a, b = (r.passes["color"].astype(float).mean(axis=2) for r in (exact, mapped))
    lit = a > 0
    stated = mapped.stats["map_error"]
    assert mapped.stats["light_map"] > 0 and mapped.stats["map_checks"] > 100
    assert exact.stats["light_map"] == 0 and exact.stats["shadow_walks_per_point"] > 1
    assert mapped.stats["shadow_walks_per_point"] < 0.05 * exact.stats["shadow_walks_per_point"]
    relative = np.abs(b - a)[lit].sum() / a[lit].sum()
    print(f"{space_id}: stated {stated:.4f}, image {relative:.4f}, mean {b.sum() / a.sum() - 1:+.4f}")
    assert 0 < stated < 0.1
    assert relative < stated
    assert abs(b.sum() / a.sum() - 1) < stated
    assert "visibility maps" in mapped.summary()


def test_a_region_with_a_map_is_the_whole_images_pixels():
    """The texels are the same whoever traces them first: a render region (a farm's tile) is pixel
    for pixel the whole image's, as without the map."""
    space = spaces.load("poincare")
    scene = default_scene(space)
    common = dict(width=64, height=36, quality="draft", threads=2)
    whole = render.render(space, scene, render.Settings(**common)).passes["color"]
    part = render.render(space, scene, render.Settings(**common, region=(16, 8, 24, 12))).passes["color"]
    np.testing.assert_array_equal(part, whole[8:20, 16:40])


def test_light_map_settings():
    space = spaces.load("poincare")
    assert render.Settings(quality="draft").map_texels(space, math.radians(90) / 640) == 407
    assert render.Settings().map_texels(space, math.radians(90) / 640) == 815
    assert render.Settings().map_texels(space, math.radians(90) / 640, lights=1000) == 150  # 512 MiB
    assert render.Settings(light_map=0).map_texels(space, 1e-3) == 0
    assert render.Settings().map_texels(spaces.load("nil"), 1e-3) == 0  # the flow to the light per lookup
    assert render.Settings(shading="normal").map_texels(space, 1e-3) == 0
    for bad in (-1, 1.5, render.MAX_MAP_TEXELS + 1):
        with pytest.raises(render.RenderError, match="light map must be a whole number"):
            render.Settings(light_map=bad).check()


def test_a_second_render_with_the_same_tracer_reuses_the_texels():
    """The texels are kept across renders with the same tolerances and crossing limit (the viewport's
    one-sample renders, animations): the unshaded re-trace that measures a render's error must not
    start them afresh. The second render traces none and is the first's image."""
    space = spaces.load("poincare")
    scene = default_scene(space)
    tracer = render.make_tracer(space, scene, threads=2)
    settings = render.Settings(width=32, height=18, quality="draft", threads=2)
    first, second = (render.render(space, scene, settings, tracer=tracer) for _ in range(2))
    assert first.stats["map_texels"] > 0 and second.stats["map_texels"] == 0
    np.testing.assert_array_equal(first.passes["color"], second.passes["color"])
