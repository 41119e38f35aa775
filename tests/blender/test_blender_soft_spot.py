"""A spot light's radius in real bpy against Cycles: in the torus, a spot pointing down at a floor
over which a small box hangs; with a radius its shadow's edge is soft. Thurston shows the spot as
point spots spread through its sphere (lamps.spot_points); the reference is Cycles rendering the
3x3x3 tiled scene (direct light only), each light copy lighting its own cell's objects."""

from __future__ import annotations

import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")


from support import blender_helpers as bh  # noqa: E402

SIZE = (64, 48)
RADIUS = 0.04


def build():
    sc = bh.fresh_scene("torus", size=SIZE)
    sc.thurston.quality = "standard"
    sc.thurston.light_reach = 0.5  # the floor lies within 0.45 of the spot, its other copies farther
    sc.view_settings.view_transform = "Standard"
    floor = bh.box("Floor", (1.0, 1.0, 0.02), (0.0, 0.0, -0.26), color=(0.7, 0.7, 0.7))
    floor.pass_index = 1
    bh.lambert(floor.active_material)
    bh.lambert(bh.box("Blocker", 0.08, (0.02, 0.0, -0.12)).active_material)
    bh.light_object(
        "SPOT",
        "Spot",
        (0.0, 0.0, 0.05),
        energy=2.0,
        spot_size=math.radians(100),
        spot_blend=0.2,
        shadow_soft_size=RADIUS,
    )
    bh.camera((0.0, -0.12, 0.3), rotation=(math.radians(20), 0, 0), lens=22)
    return sc


def test_a_spot_with_a_radius_casts_the_soft_shadow_cycles_does(tmp_path):
    sc = build()
    sc.view_layers[0].use_pass_z = sc.view_layers[0].use_pass_object_index = True
    from thurston_addon.blender import export

    notes = export.RenderJob(sc, bpy.context.evaluated_depsgraph_get()).messages()
    assert any("spot lights with a radius" in m and "Spot" in m and "soft" in m for m in notes), notes
    L = "ViewLayer."
    spot = bpy.data.lights["Spot"]
    ch = bh.f12(sc, tmp_path / "soft.exr")
    soft = bh.rgb(ch, L + "Combined.")
    floor = bh.interior((ch[L + "Depth.Z"] < 1.0) & (np.abs(ch[L + "IndexOB.X"] - 1) < 0.01))
    spot.shadow_soft_size = 0.0
    hard = bh.rgb(bh.f12(sc, tmp_path / "hard.exr"), L + "Combined.")
    bh.tile_torus_for_cycles(sc, 3, own_cell_light=True)
    cycles_hard = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles_hard.exr", samples=16), L + "Combined.")
    spot.shadow_soft_size = RADIUS
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=128), L + "Combined.")
    lum = [image.mean(axis=-1) for image in (soft, hard, cycles, cycles_hard)]
    # the shadow's edge: where Cycles' soft and hard shadows differ
    edge = floor & (np.abs(lum[2] - lum[3]) > 0.15 * np.percentile(lum[2][floor], 95))
    assert floor.sum() > 500 and edge.sum() > 60, (floor.sum(), edge.sum())

    def error(k):  # the mean per-pixel difference from Cycles over the edge, relative to its brightness
        return float(np.abs(lum[k][edge] - lum[2][edge]).mean() / lum[2][edge].mean())

    report = {"soft": error(0), "hard": error(1), "Cycles' hard": error(3)}
    print("mean relative per-pixel difference from Cycles' soft shadow over its edge:", report)
    np.testing.assert_allclose(soft[floor].mean(axis=0), cycles[floor].mean(axis=0), rtol=0.05)
    np.testing.assert_allclose(lum[0][edge].mean(), lum[2][edge].mean(), rtol=0.05)
    assert report["soft"] < 0.1 and report["hard"] > 3 * report["soft"], report  # hard shadows fail
