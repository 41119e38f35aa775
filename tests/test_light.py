"""Direct light along every geodesic (E3, S3, H3) against closed forms: the sum over the copies of
a point light (and in S3 over both arcs to each) of cos * power * falloff, where nothing shadows
(the shaded object is emissive, so it casts no shadow, and there is nothing else), and the
render's light statistics."""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import trimesh

from thurston_addon import render, spaces
from thurston_addon.scene import PointLight, Scene, SceneObject, default_scene

RHO, GLOW = 0.5, 1e-3  # the ball's base colour and its faint emission (which makes it cast no shadow)


def ball_scene(centre, light, power=1.0):
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.02)
    return Scene(objects=[SceneObject("ball", ball.vertices + centre, ball.faces, (RHO,) * 3, emission=(GLOW,) * 3)],
                 lights=[PointLight(np.asarray(light, float), np.ones(3), power)])


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


@pytest.mark.parametrize("fog", [math.inf, 0.5])
def test_torus_sums_every_lattice_copy_within_the_reach(fog):
    """E3: the irradiance at a point of the ball is sum_k max(0, cos theta_k) p / r_k^2 over the
    lattice copies L + k of the light with r_k <= reach (every one visible), to float precision;
    with fog each term falls by exp(-r_k / fog). The trace counts those geodesics (facing or not)
    and sums p / r_k^2 exp(-r_k / fog) over them (the energy the stats set the part beyond against)."""
    space = spaces.load("torus")
    light, power, reach = np.array([-0.2, 0.1, 0.3]), 0.7, 2.5
    colour, H, N, out = shade_one(space, ball_scene([0.1, 0.2, -0.15], light, power), [0.1, -0.2, -0.15],
                                  [0.1, 0.2, -0.15], reach, fog)
    x = H[:3] / H[3]
    total, energy, paths, facing = 0.0, 0.0, 0, 0
    for k in itertools.product(range(-4, 5), repeat=3):
        v = light + np.array(k) - x
        r = np.linalg.norm(v)
        assert abs(r - reach) > 1e-6  # no copy on the boundary of the reach
        if r <= reach:
            paths += 1
            energy += power / r**2 * math.exp(-r / fog)
            if N[:3] @ v > 0:
                total += (N[:3] @ v / r) * power / r**2 * math.exp(-r / fog)
                facing += 1
    assert facing > 20  # many copies, not just the nearest
    np.testing.assert_allclose(colour, GLOW + RHO * total, rtol=2e-5)
    assert out["light_paths"] == paths
    assert float(out["light_energy"]) == pytest.approx(energy, rel=1e-6)  # the radiance is float32


def test_poincare_sums_120_copies_and_both_arcs():
    """S3, the Poincare sphere: sum over the 120 copies g L and the two arcs to each (the short one
    of length d, the long one of length 2 pi - d leaving the other way, falloff 1/sin^2 on both)
    of max(0, cos) p / sin^2: that is |N . u_k| p / sin^2 d_k for the unit direction u_k of the
    short arc. Computed from the group's matrices in R^4, against the traced value to 1e-4."""
    space = spaces.load("poincare")
    g = space.geometry
    group = space.elements_within(math.pi + 1e-6)
    assert len(group) == 120
    light, power = np.array([0.08, -0.05, 0.12]), 0.3
    colour, H, N, out = shade_one(space, ball_scene([0.0, 0.15, 0.0], light, power), [0.0, -0.1, 0.0],
                                  [0.0, 0.15, 0.0], None)
    L = g.normalize_point(g.to_model(light[None]))[0]
    total = 0.0
    for M in group:
        Y = M @ L
        d = math.acos(np.clip(H @ Y, -1, 1))
        u = Y - (H @ Y) * H
        u /= np.linalg.norm(u)
        total += abs(N @ u) * power / math.sin(d) ** 2
    np.testing.assert_allclose(colour, GLOW + RHO * total, rtol=1e-4)
    assert out["light_paths"] == 240  # every copy, both arcs


def test_opaque_points_in_the_poincare_sphere_see_no_long_arcs():
    """-1 is in the binary icosahedral group, so a geodesic returns to its start after length pi: a
    long arc from an opaque surface passes through that surface again. Traced (the geodesic_loop
    shortcut off) and with the shortcut, the image is the same."""
    space = spaces.load("poincare")
    scene = default_scene(space)
    assert render.geodesic_loop(space) == math.pi
    settings = render.Settings(width=24, height=16, quality="draft", threads=1)
    shortcut = render.render(space, scene, settings).passes["color"]
    data = render.compile_scene(space, scene, 2 * math.pi)
    import thurston_core

    traced = render.render(space, scene, settings, tracer=thurston_core.Tracer(**{**data, "geodesic_loop": math.inf},
                                                                                threads=1)).passes["color"]
    np.testing.assert_allclose(shortcut, traced, rtol=1e-4, atol=1e-6)


def test_light_stats_and_energy_estimate():
    """The stats count the copies and the geodesics, and estimate the energy beyond the reach:
    4 pi p (D - R) / vol against what was summed; S3 with every copy and both arcs: 0."""
    torus = spaces.load("torus")
    scene = default_scene(torus)
    near = render.render(torus, scene, render.Settings(width=32, height=18, quality="draft", light_reach=1.0))
    far = render.render(torus, scene, render.Settings(width=32, height=18, quality="draft", light_reach=2.0))
    for r in (near, far):
        assert r.stats["light_copies"] > 1 and r.stats["light_paths_per_point"] > 1
        assert "copies within reach" in r.summary()
    assert far.stats["light_copies"] > near.stats["light_copies"]
    # beyond R = 1 up to D = 30 there is far more than the summed part: (D - R) / R ~ 29, roughly
    assert 5 < near.stats["light_energy_left_out"] and far.stats["light_energy_left_out"] < near.stats["light_energy_left_out"]
    poincare = spaces.load("poincare")
    r = render.render(poincare, default_scene(poincare), render.Settings(width=16, height=9, quality="draft"))
    assert r.stats["light_copies"] == 120 and r.stats["light_energy_left_out"] == 0.0
    sw = spaces.load("seifert_weber")
    r = render.render(sw, default_scene(sw), render.Settings(width=16, height=9, quality="draft"))
    assert math.isfinite(r.stats["light_reach"]) and 0 < r.stats["light_energy_left_out"] < math.inf
    nil = spaces.load("nil")
    r = render.render(nil, default_scene(nil), render.Settings(width=16, height=9, quality="draft"))
    assert r.stats["light_reach"] is None and "nearest" in r.summary()


@pytest.mark.parametrize("reach", [-1.0, float("nan")])
def test_bad_light_reach_is_one_clear_error(reach):
    with pytest.raises(render.RenderError, match="light reach"):
        render.render(spaces.load("torus"), Scene(), render.Settings(width=4, height=4, light_reach=reach))


# --- the floor under the lamp (issue 9) against Cycles in the tiled universal cover -------------------
CYCLES_CELLS, CYCLES_REACH = 7, 3.5


def floor_under_lamp():
    """A floor slab and two walls spanning the domain's cross-sections (in the cover: a corridor
    along y, repeated), a lamp 0.65 above the floor in plain view, seen from above. Nearest-copy
    lighting left the floor black: the lamp's nearest copy to it lies below it. What lights a point
    of the corridor: the lamp's copies along it, one per cell, 0.65 / r^3 falling off."""
    import blender_helpers as bh

    sc = bh.fresh_scene("torus", size=(48, 27))
    sc.view_settings.view_transform = "Standard"
    sc.thurston.quality = "standard"
    for name, size, location in (("Floor", (1.0, 1.0, 0.02), (0.0, 0.0, -0.26)),
                                 ("Left", (0.02, 1.0, 1.0), (-0.4, 0.0, 0.0)),
                                 ("Right", (0.02, 1.0, 1.0), (0.45, 0.0, 0.0))):
        bh.lambert(bh.box(name, size, location, color=(0.7, 0.7, 0.7)).active_material)
    lamp = bh.point_light((0.05, 0.1, 0.39), energy=3.0)
    lamp.data.shadow_soft_size = 0.0
    bh.camera((0.0, -0.35, 0.15), rotation=(math.radians(55), 0, 0), lens=20)
    return sc


def test_floor_under_the_lamp_matches_cycles_in_the_tiled_cover(tmp_path, registered_addon):
    """The floor is lit, and pixel by pixel as Cycles renders the scene tiled 7x7x7 in the universal
    cover (direct light only, all 343 lamps lighting everything): the points of the central cell
    (no face crossed), lit by every copy within reach 3.5 (Cycles' tiling holds the corridor's
    lamps three cells each way; the ones one cell further, at reach 3.5 to 4, send under 1%). A
    missing copy fails it: the reach that keeps only the lamp's own copy."""
    import blender_helpers as bh
    from test_blender_surfaces import interior

    sc = floor_under_lamp()
    sc.view_layers[0].thurston.use_pass_crossings = True
    L = "ViewLayer."
    sc.thurston.light_reach = CYCLES_REACH
    ch = bh.f12(sc, tmp_path / "thurston.exr")
    thurston = bh.rgb(ch, L + "Combined.")
    central = interior(next(v for k, v in ch.items() if "Crossings" in k) < 0.5)
    sc.thurston.light_reach = 0.9  # the lamp's own copy only (the ones a cell away are farther)
    own_only = bh.rgb(bh.f12(sc, tmp_path / "own.exr"), L + "Combined.")
    bh.tile_torus_for_cycles(sc, CYCLES_CELLS)
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=1024), L + "Combined.")
    assert central.sum() > 300
    assert thurston[central].mean() > 0.05  # lit

    def error(image):  # the per-pixel differences from Cycles relative to its brightness
        return float(np.abs(image[central] - cycles[central]).sum() / cycles[central].sum())

    report = {"all copies": error(thurston), "own copy only": error(own_only)}
    print("mean relative per-pixel difference from Cycles:", report)
    np.testing.assert_allclose(thurston[central].mean(axis=0), cycles[central].mean(axis=0), rtol=0.02)
    assert report["all copies"] < 0.05, report  # Cycles' noise at 1024 samples: about 0.03
    assert report["own copy only"] > 3 * report["all copies"], report
