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


from support import blender_helpers as bh  # noqa: E402

SIZE = (64, 36)
# The objects lie within 0.45 of the light and its other copies a cell (at least 0.55 from them) away.
LIGHT_REACH = 0.5


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
    mat, _ = bh.image_texture_material("Checker", bh.CHECKER)
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
    masks = {
        name: bh.interior(near & (np.abs(index - k) < 0.01)) for name, k in (("ball", 1), ("plane", 2), ("box", 3))
    }

    def error(image, mask):  # the per-pixel differences from Cycles relative to its brightness
        return float(np.abs(image[mask] - cycles[mask]).sum() / cycles[mask].sum())

    report = {name: error(thurston, mask) for name, mask in masks.items()}
    report["ball shaded flat"] = error(flat, masks["ball"])
    print("mean relative per-pixel difference from Cycles:", report)
    for name, mask in masks.items():
        assert mask.sum() > 20, name
        np.testing.assert_allclose(
            thurston[mask].mean(axis=0), cycles[mask].mean(axis=0), rtol=0.05, atol=0.005, err_msg=name
        )
        assert report[name] < 0.02, (name, report)
    assert report["ball shaded flat"] > 0.05, report


def test_an_image_texture_on_a_mesh_without_uvs_reads_uv_0_as_cycles(tmp_path):
    """No UV map: Cycles reads an Image Texture at UV (0, 0), where its bilinear lookup with Repeat
    blends the four corner texels of the 2x2 checker (their mean); Thurston the same, with a note."""
    sc = bh.fresh_scene("torus", size=(48, 27))
    sc.view_settings.view_transform = "Standard"
    mat, _ = bh.image_texture_material("Checker", bh.CHECKER)
    bpy.ops.mesh.primitive_cube_add(size=0.2, location=(0, 0.4, 0))
    cube = bpy.context.active_object
    cube.data.uv_layers.remove(cube.data.uv_layers[0])
    cube.data.materials.append(mat)
    bh.point_light((0.05, 0.1, 0.15), energy=2.0)
    bh.camera()
    sc.thurston.max_distance = 0.45
    from thurston_addon.blender import export

    job = export.RenderJob(sc, bpy.context.evaluated_depsgraph_get())
    assert any("no UV map" in m and "UV (0, 0)" in m for m in job.messages())
    L = "ViewLayer."
    thurston = bh.rgb(bh.f12(sc, tmp_path / "thurston.exr"), L + "Combined.")
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=8), L + "Combined.")
    corner_mean = bh.CHECKER[..., :3].mean(axis=(0, 1))
    for image in (thurston, cycles):
        lit = bh.interior(image.sum(axis=-1) > 0.05)
        assert lit.sum() > 20
        colour = image[lit].mean(axis=0)
        np.testing.assert_allclose(colour / colour[0], corner_mean / corner_mean[0], rtol=0.02)


# --- glossy: the Principled BSDF's roughness, metallic and specular layer --------------------------
GLOSSY = {
    "Metal": dict(color=(0.9, 0.6, 0.3), roughness=0.35, metallic=1.0),
    "Varnish": dict(color=(0.15, 0.2, 0.3), roughness=0.3, metallic=0.0),
}  # specular level 0.5, IOR 1.5


def principled(name, color, roughness, metallic):
    """A Principled BSDF of single-scattering GGX (the tracer's; Blender's default, multiscatter
    GGX, adds what light the microfacets scatter more than once)."""
    mat = bh.material(name, color)
    p = mat.node_tree.nodes["Principled BSDF"]
    p.distribution = "GGX"
    p.inputs["Roughness"].default_value = roughness
    p.inputs["Metallic"].default_value = metallic
    return mat


def build_glossy():
    """A metal ball and a varnished (dielectric specular layer over a dark base) plate facing the
    camera, each showing the point light's highlight, in the torus."""
    sc = bh.fresh_scene("torus", size=SIZE)
    sc.thurston.quality = "standard"
    sc.thurston.light_reach = LIGHT_REACH
    sc.view_settings.view_transform = "Standard"
    bpy.ops.mesh.primitive_uv_sphere_add(segments=32, ring_count=16, radius=0.1, location=(-0.09, 0.3, -0.02))
    ball = bpy.context.object
    ball.name, ball.pass_index = "Metal", 1
    bpy.ops.object.shade_smooth()
    ball.data.materials.append(principled("Metal", **GLOSSY["Metal"]))
    bpy.ops.mesh.primitive_plane_add(size=0.22, location=(0.1, 0.34, 0.0), rotation=(math.pi / 2, 0, 0))
    plate = bpy.context.object
    plate.name, plate.pass_index = "Varnish", 2
    plate.data.materials.append(principled("Varnish", **GLOSSY["Varnish"]))
    light = bh.point_light((0.03, 0.12, 0.1), energy=1.5)
    light.data.shadow_soft_size = 0.0
    bh.camera((0, -0.05, 0))
    return sc


def test_principled_scattering_is_exported():
    sc = build_glossy()
    from thurston_addon.blender.export import surfaces

    for name, spec in GLOSSY.items():
        m = surfaces.material(sc.objects[name].active_material, name)
        assert (m.roughness, m.metallic, m.specular, m.ior) == pytest.approx(
            (spec["roughness"], spec["metallic"], 0.5, 1.5)
        )
    p = sc.objects["Metal"].active_material.node_tree.nodes["Principled BSDF"]
    p.inputs["Roughness"].default_value = 7.0  # Cycles clamps it to 1, as the export does
    assert surfaces.material(sc.objects["Metal"].active_material, "Metal").roughness == 1.0


def test_glossy_ball_and_plate_match_cycles_tiled(tmp_path):
    """Direct light of a point light on GGX lobes, pixel by pixel against Cycles (CPU, the 3x3x3
    tiled scene, direct light only, each light copy lighting its own cell's objects), where the
    highlights are: a roughness mapped wrongly (alpha = roughness, not its square) fails."""
    sc = build_glossy()
    sc.view_layers[0].use_pass_z = sc.view_layers[0].use_pass_object_index = True
    L = "ViewLayer."
    ch = bh.f12(sc, tmp_path / "thurston.exr")
    thurston = bh.rgb(ch, L + "Combined.")
    index, depth = ch[L + "IndexOB.X"], ch[L + "Depth.Z"]
    for name, spec in GLOSSY.items():  # alpha = roughness: a Blender roughness of its square root
        p = sc.objects[name].active_material.node_tree.nodes["Principled BSDF"]
        p.inputs["Roughness"].default_value = math.sqrt(spec["roughness"])
    wrong = bh.rgb(bh.f12(sc, tmp_path / "wrong.exr"), L + "Combined.")
    for name, spec in GLOSSY.items():
        sc.objects[name].active_material.node_tree.nodes["Principled BSDF"].inputs["Roughness"].default_value = spec[
            "roughness"
        ]
    bh.tile_torus_for_cycles(sc, 3, own_cell_light=True)
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=32), L + "Combined.")
    near = depth < 1.0
    masks = {name: bh.interior(near & (np.abs(index - k) < 0.01)) for name, k in (("Metal", 1), ("Varnish", 2))}

    def error(image, mask):  # the per-pixel differences from Cycles relative to its brightness
        return float(np.abs(image[mask] - cycles[mask]).sum() / cycles[mask].sum())

    report = {name: (error(thurston, mask), error(wrong, mask)) for name, mask in masks.items()}
    print("mean relative per-pixel difference from Cycles (roughness right, alpha = roughness):", report)
    for name, mask in masks.items():
        assert mask.sum() > 40, name
        np.testing.assert_allclose(
            thurston[mask].mean(axis=0), cycles[mask].mean(axis=0), rtol=0.04, atol=0.002, err_msg=name
        )
        right, wrong_mapping = report[name]
        assert right < 0.04 and wrong_mapping > 3 * right, (name, report)
