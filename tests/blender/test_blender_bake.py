"""Procedural colours baked by Cycles, in real bpy against Cycles: in the torus, seen from inside, a
plane whose Base Color is a Noise Texture through a ColorRamp, one whose Base Color and Emission
Color are a Checker Texture on Object coordinates, and a cube whose Base Color is an Image Texture
in Box projection, lit by a point light within a light reach that holds only its copy in the
point's own cell. The reference is Cycles rendering the 3x3x3 tiled scene (direct
light only), each light copy linked to its own cell's objects."""

from __future__ import annotations

import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")


from support import blender_helpers as bh  # noqa: E402

SIZE = (64, 36)
LIGHT_REACH = 0.5  # the objects lie within 0.45 of the light, its other copies a cell away


def procedural(name, kind):
    """A diffuse material whose Base Color comes from nodes: "noise" (Noise Texture -> ColorRamp,
    red to blue), "checker" (Checker Texture, yellow and red, on Object coordinates, also into the
    Emission Color) or "box" (the 2x2 checker image in Box projection)."""
    mat = bh.lambert(bh.material(name))
    tree, nodes = mat.node_tree, mat.node_tree.nodes
    if kind == "noise":
        noise = nodes.new("ShaderNodeTexNoise")
        noise.inputs["Scale"].default_value = 4.0
        ramp = nodes.new("ShaderNodeValToRGB")
        ramp.color_ramp.elements[0].color = (0.8, 0.05, 0.05, 1)
        ramp.color_ramp.elements[1].color = (0.05, 0.1, 0.8, 1)
        ramp.color_ramp.elements[0].position, ramp.color_ramp.elements[1].position = 0.35, 0.65
        tree.links.new(noise.outputs["Fac"], ramp.inputs["Fac"])
        colour = ramp.outputs["Color"]
    elif kind == "box":
        image = bpy.data.images.new("Checker", 2, 2, float_buffer=True)
        image.pixels.foreach_set(np.ascontiguousarray(bh.CHECKER[::-1]).ravel())
        texture = nodes.new("ShaderNodeTexImage")
        texture.image, texture.projection, texture.interpolation = image, "BOX", "Closest"
        colour = texture.outputs["Color"]
    else:
        checker = nodes.new("ShaderNodeTexChecker")
        checker.inputs["Color1"].default_value = (0.8, 0.7, 0.1, 1)
        checker.inputs["Color2"].default_value = (0.8, 0.1, 0.1, 1)
        checker.inputs["Scale"].default_value = 12.0
        coordinates = nodes.new("ShaderNodeTexCoord")
        tree.links.new(coordinates.outputs["Object"], checker.inputs["Vector"])
        colour = checker.outputs["Color"]
        principled = nodes["Principled BSDF"]
        tree.links.new(colour, principled.inputs["Emission Color"])
        principled.inputs["Emission Strength"].default_value = 0.05
    tree.links.new(colour, nodes["Principled BSDF"].inputs["Base Color"])
    return mat


def build():
    sc = bh.fresh_scene("torus", size=SIZE)
    sc.thurston.quality = "standard"
    sc.thurston.light_reach = LIGHT_REACH
    sc.view_settings.view_transform = "Standard"
    for k, (name, x) in enumerate((("noise", -0.15), ("checker", 0.15)), start=1):
        bpy.ops.mesh.primitive_plane_add(size=0.26, location=(x, 0.3, 0.0), rotation=(math.pi / 2, 0, 0))
        plane = bpy.context.object
        plane.name, plane.pass_index = name, k
        plane.data.materials.append(procedural(name, name))
    bpy.ops.mesh.primitive_cube_add(size=0.07, location=(0.0, 0.2, -0.02), rotation=(0.3, 0.2, 0.5))
    cube = bpy.context.object
    cube.name, cube.pass_index = "box", 3
    cube.data.materials.append(procedural("box", "box"))
    light = bh.point_light((0.0, 0.08, 0.15), energy=2.0)
    light.data.shadow_soft_size = 0.0
    bh.camera((0, -0.05, 0))
    return sc


@pytest.mark.slow
def test_procedural_base_colours_are_baked_and_match_cycles_tiled(tmp_path):
    sc = build()
    from thurston_addon.blender import export

    notes = export.RenderJob(sc, bpy.context.evaluated_depsgraph_get()).messages()
    for name, node in (("noise", "Color Ramp"), ("checker", "Checker Texture"), ("box", "Image Texture")):
        said = [m for m in notes if f"material {name!r}" in m]
        assert len(said) == 1 and node in said[0] and "baked by Cycles to a 128x128 image" in said[0], notes
    assert "Emission Color" in next(m for m in notes if "material 'checker'" in m)
    sc.view_layers[0].use_pass_z = sc.view_layers[0].use_pass_object_index = True
    L = "ViewLayer."
    ch = bh.f12(sc, tmp_path / "thurston.exr")
    thurston = bh.rgb(ch, L + "Combined.")
    index, depth = ch[L + "IndexOB.X"], ch[L + "Depth.Z"]
    bh.tile_torus_for_cycles(sc, 3, own_cell_light=True)
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=32), L + "Combined.")
    masks = {
        name: bh.interior((depth < 1.0) & (np.abs(index - k) < 0.01))
        for k, name in ((1, "noise"), (2, "checker"), (3, "box"))
    }
    report = {}
    for name, mask in masks.items():
        assert mask.sum() > 40, name
        mean = cycles[mask].mean(axis=0)
        assert mean.max() > 1.5 * mean.min(), (name, mean)  # coloured: the unbaked grey would fail
        report[name] = float(np.abs(thurston[mask] - cycles[mask]).sum() / cycles[mask].sum())
        np.testing.assert_allclose(thurston[mask].mean(axis=0), mean, rtol=0.05, atol=0.003, err_msg=name)
    print("mean relative per-pixel difference from Cycles:", report)
    # (the box's faces get a share of the image: its checker's edges blur over a texel)
    assert report["noise"] < 0.03 and report["checker"] < 0.03 and report["box"] < 0.06, report


def test_an_object_without_uvs_is_baked_on_a_smart_uv_project_and_matches_cycles(tmp_path):
    """No UV map: the colour (a Noise Texture, on Generated coordinates, which need none) is baked on
    a Smart UV Project of a temporary copy, whose UVs the cube gets; against Cycles as above."""
    sc = bh.fresh_scene("torus", size=SIZE)
    sc.thurston.quality = "standard"
    sc.thurston.light_reach = LIGHT_REACH
    sc.view_settings.view_transform = "Standard"
    bpy.ops.mesh.primitive_cube_add(size=0.2, location=(0, 0.3, 0), rotation=(0.4, 0.3, 0.6))
    cube = bpy.context.object
    cube.pass_index = 1
    cube.data.uv_layers.remove(cube.data.uv_layers[0])
    cube.data.materials.append(procedural("noise", "noise"))
    bh.point_light((0.05, 0.08, 0.15), energy=2.0).data.shadow_soft_size = 0.0
    bh.camera((0, -0.05, 0))
    from thurston_addon.blender import export

    job = export.RenderJob(sc, bpy.context.evaluated_depsgraph_get())
    (said,) = [m for m in job.messages() if "material 'noise'" in m]
    assert "baked by Cycles to a 128x128 image on a Smart UV Project" in said, said
    assert len(cube.data.uv_layers) == 0 and "Thurston Bake" not in bpy.data.scenes  # (temporary)
    sc.view_layers[0].use_pass_z = sc.view_layers[0].use_pass_object_index = True
    L = "ViewLayer."
    ch = bh.f12(sc, tmp_path / "thurston.exr")
    thurston = bh.rgb(ch, L + "Combined.")
    mask = bh.interior((ch[L + "Depth.Z"] < 1.0) & (np.abs(ch[L + "IndexOB.X"] - 1) < 0.01))
    bh.tile_torus_for_cycles(sc, 3, own_cell_light=True)
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=32), L + "Combined.")
    assert mask.sum() > 100
    error = float(np.abs(thurston[mask] - cycles[mask]).sum() / cycles[mask].sum())
    print("mean relative per-pixel difference from Cycles:", error)
    np.testing.assert_allclose(thurston[mask].mean(axis=0), cycles[mask].mean(axis=0), rtol=0.05, atol=0.003)
    assert error < 0.05


def not_baked_before(roughness):
    """Materials whose trees no earlier test baked (bakes are kept by what they depend on)."""
    for mat in bpy.data.materials:
        mat.node_tree.nodes["Principled BSDF"].inputs["Roughness"].default_value = roughness


def test_off_blenders_main_thread_only_kept_bakes_are_used():
    """An interactive F12 renders on a thread of its own, where Blender cannot bake: the note says
    so, and the input's own colour is shown; where the main thread baked the same input before
    (the rendered viewport), that bake is used."""
    import threading

    sc = build()
    not_baked_before(0.987)
    from thurston_addon.blender import export

    def notes_on_a_thread():
        depsgraph, said = bpy.context.evaluated_depsgraph_get(), []
        thread = threading.Thread(target=lambda: said.extend(export.RenderJob(sc, depsgraph).messages()))
        thread.start()
        thread.join()
        return {name: [m for m in said if f"material {name!r}" in m] for name in ("noise", "checker", "box")}

    for (note,) in notes_on_a_thread().values():
        assert "not baked: Blender bakes only on its main thread" in note, note
    export.RenderJob(sc, bpy.context.evaluated_depsgraph_get())  # on the main thread: bakes
    for (note,) in notes_on_a_thread().values():
        assert "baked by Cycles" in note and "not baked" not in note, note


def test_bakes_are_kept_until_what_they_depend_on_changes():
    """The rendered viewport exports again after every change, and a bake's temporary datablocks are
    changes: a second export bakes nothing and leaves nothing changed (the loop ends); an edited
    node bakes its material again, and only it."""
    build()
    not_baked_before(0.876)
    from thurston_addon.blender import engine, export

    bakes = []

    def record(scene, depsgraph):  # a bake evaluates its temporary scene
        if scene.name.startswith("Thurston Bake"):
            bakes.append(scene.name)

    def changed():
        updates = []
        bpy.app.handlers.depsgraph_update_post.append(lambda s, d: updates.append(engine.changes_scene(d)))
        try:
            bpy.context.view_layer.update()
        finally:
            bpy.app.handlers.depsgraph_update_post.pop()
        return any(updates)

    def export_scene():
        bakes.clear()
        export.export_scene(bpy.context.evaluated_depsgraph_get(), 1.0, [], meshes={})
        return len(bakes)

    bpy.app.handlers.depsgraph_update_post.append(record)
    try:
        bpy.context.view_layer.update()
        first = export_scene()  # four bakes (the checker's two inputs)
        changed()
        assert export_scene() == 0 and not changed()
        bpy.data.materials["noise"].node_tree.nodes["Noise Texture"].inputs["Scale"].default_value = 9.0
        assert changed()
        assert 0 < export_scene() <= first / 4  # the noise's alone
        changed()
        assert export_scene() == 0 and not changed()
    finally:
        bpy.app.handlers.depsgraph_update_post.remove(record)
