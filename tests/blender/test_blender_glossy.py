"""Far light on glossy surfaces (issue 20 point 6): Blender's default Principled material (its
specular layer) under an area light and an emissive panel in the torus, direct light only, against
Cycles rendering the scene tiled in the universal cover: the mean within a few percent, and the
speckles (pixels far brighter than their neighbours) as few as Cycles' from 4 samples on. Before
the glossy layer's gathering bounce was held to the light reach it walked to the distance limit
and met far copies that the emitters' samples leave out: 1.09x Cycles' mean and 19 speckles at 4
samples, 1.03x at 64."""

from __future__ import annotations

import math

import numpy as np

CELLS = 7  # Cycles' tiling: the copies within 3 cells each way


def glossy_floor():
    from support import blender_helpers as bh

    sc = bh.fresh_scene("torus", size=(64, 36))
    sc.view_settings.view_transform = "Standard"
    sc.thurston.quality = "draft"
    sc.thurston.light_reach = 0.5 * (CELLS - 1)  # what Cycles' tiling holds
    bh.box("Floor", (1.0, 1.0, 0.02), (0.0, 0.0, -0.3), color=(0.6, 0.6, 0.6))  # default Principled
    bh.box("Panel", (0.15, 0.15, 0.01), (-0.2, 0.15, 0.25), color=(0, 0, 0), emission=(1, 1, 1), strength=4.0)
    bh.light_object("AREA", "Area", (0.15, -0.1, 0.3), shape="SQUARE", size=0.15, energy=2.0)
    bh.camera((0.0, -0.35, 0.0), rotation=(math.radians(50), 0, 0), lens=18)
    return sc


def speckles(image):
    """Pixels over 3 times the median brightness of their 3x3 neighbourhood."""
    y = image.mean(axis=2)
    padded = np.pad(y, 1, mode="edge")
    windows = np.stack([padded[i : i + y.shape[0], j : j + y.shape[1]] for i in range(3) for j in range(3)])
    return int(np.sum(y > 3 * np.median(windows, axis=0) + 1e-3))


def test_default_principled_under_far_light_matches_cycles_and_clears(tmp_path, registered_addon):
    from support import blender_helpers as bh

    sc = glossy_floor()
    L = "ViewLayer."
    found = {}
    for samples in (4, 16):
        sc.thurston.samples = samples
        found[samples] = bh.rgb(bh.f12(sc, tmp_path / f"thurston{samples}.exr"), L + "Combined.")
    bh.tile_torus_for_cycles(sc, CELLS)
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=1024), L + "Combined.")
    inside = bh.interior(np.ones(cycles.shape[:2], bool))
    means = {k: float(v[inside].mean() / cycles[inside].mean()) for k, v in found.items()}
    spots = {k: speckles(v) for k, v in found.items()}
    print("mean / Cycles'", means, "speckles", spots, "Cycles'", speckles(cycles))
    for samples in found:
        assert abs(means[samples] - 1) < 0.03, means
        assert spots[samples] <= max(2 * speckles(cycles), 3), spots
