"""Surfaces in real bpy against Cycles: in the torus, seen from inside, a smooth-shaded UV sphere,
a plane with an Image Texture on its Base Color and a box with two material slots, lit by a point
light within a light reach that holds only its copy in the point's own cell. The reference is
Cycles rendering the 3x3x3 tiled scene (direct light only), each light copy linked to its own
cell's objects."""
from __future__ import annotations

import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")


import blender_helpers as bh  # noqa: E402

SIZE = (64, 36)
# The objects lie within 0.45 of the light and its other copies a cell (at least 0.55 from them) away.
LIGHT_REACH = 0.5
TEXELS = np.array([[[0.9, 0.1, 0.1, 1], [0.1, 0.8, 0.2, 1]],
                   [[0.2, 0.3, 0.9, 1], [0.9, 0.9, 0.2, 1]]], np.float32)  # linear, top row first


def build():
    sc = bh.fresh_scene("torus", size=SIZE)
    sc.thurston.quality = "standard"
    sc.thurston.light_reach = LIGHT_REACH
    sc.view_settings.view_transform = "Standard"
    bpy.ops.mesh.primitive_uv_sphere_add(segments=12, ring_count=6, radius=0.12, location=(-0.16, 0.32, 0.0))
    ball = bpy.context.object
    ball.name, ball.pass_index = "Ball", 1
    bpy.ops.object.shade_smooth()
    ball.data.materials.append(bh.lambert(bh.material("Ball", (0.7, 0.7, 0.7))))
    bpy.ops.mesh.primitive_plane_add(size=0.26, location=(0.17, 0.3, 0.02), rotation=(math.pi / 2, 0, 0))
    plane = bpy.context.object
    plane.name, plane.pass_index = "Plane", 2
    mat, _ = bh.image_texture_material("Checker", TEXELS)
    plane.data.materials.append(mat)
    box = bh.box("Box", (0.5, 0.1, 0.04), (0.0, 0.3, -0.06), color=(0.8, 0.2, 0.2))
    box.pass_index = 3
    bh.lambert(box.active_material)
    box.data.materials.append(bh.lambert(bh.material("Blue", (0.1, 0.3, 0.9))))
    for poly in box.data.polygons:  # the faces on the camera's side of x = 0: the second slot
        poly.material_index = int(poly.center.x < 0)
    light = bh.point_light((0.0, 0.08, 0.15), energy=2.0)
    light.data.shadow_soft_size = 0.0
    bh.camera((0, -0.05, 0))
    return sc


def interior(mask):
    """The mask without its border pixels (silhouettes are anti-aliased differently)."""
    m = mask.copy()
    m[1:] &= mask[:-1]
    m[:-1] &= mask[1:]
    m[:, 1:] &= mask[:, :-1]
    m[:, :-1] &= mask[:, 1:]
    return m


def test_smooth_textured_per_face_materials_match_cycles_tiled(tmp_path):
    sc = build()
    sc.view_layers[0].use_pass_z = sc.view_layers[0].use_pass_object_index = True
    ch = bh.f12(sc, tmp_path / "thurston.exr")
    L = "ViewLayer."
    thurston = bh.rgb(ch, L + "Combined.")
    index, depth = ch[L + "IndexOB.X"], ch[L + "Depth.Z"]
    for poly in sc.objects["Ball"].data.polygons:  # a missing feature must fail: the ball shaded flat
        poly.use_smooth = False
    flat = bh.rgb(bh.f12(sc, tmp_path / "flat.exr"), L + "Combined.")
    for poly in sc.objects["Ball"].data.polygons:
        poly.use_smooth = True
    bh.tile_torus_for_cycles(sc, 3, own_cell_light=True)
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=32), L + "Combined.")
    near = depth < 1.0  # hits within the 27 cells Cycles has
    masks = {name: interior(near & (np.abs(index - k) < 0.01)) for name, k in (("ball", 1), ("plane", 2), ("box", 3))}

    def error(image, mask):  # the per-pixel differences from Cycles relative to its brightness
        return float(np.abs(image[mask] - cycles[mask]).sum() / cycles[mask].sum())

    report = {name: error(thurston, mask) for name, mask in masks.items()}
    report["ball shaded flat"] = error(flat, masks["ball"])
    print("mean relative per-pixel difference from Cycles:", report)
    for name, mask in masks.items():
        assert mask.sum() > 20, name
        np.testing.assert_allclose(thurston[mask].mean(axis=0), cycles[mask].mean(axis=0), rtol=0.05, atol=0.005,
                                   err_msg=name)
        assert report[name] < 0.02, (name, report)
    assert report["ball shaded flat"] > 0.05, report
