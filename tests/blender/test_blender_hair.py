"""Hair particle systems in real bpy against Cycles: in the torus, seen from inside, a tuft of
tapering strands growing from a hidden plane, lit by a point light within a light reach that holds
only its copy in the point's own cell. Thurston tessellates the strands to tubes (export/hair.py);
the reference is Cycles rendering the 3x3x3 tiled scene (direct light only), each light copy
lighting its own cell's objects."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")


from support import blender_helpers as bh  # noqa: E402

SIZE = (96, 54)


def build(strands=60):
    sc = bh.fresh_scene("torus", size=SIZE)
    sc.thurston.quality = "standard"
    sc.thurston.light_reach = 0.5  # the tuft lies within 0.45 of the light, its other copies farther
    sc.view_settings.view_transform = "Standard"
    bpy.ops.mesh.primitive_plane_add(size=0.16, location=(0.0, 0.3, -0.08))
    tuft = bpy.context.object
    tuft.name, tuft.pass_index = "Tuft", 1
    tuft.show_instancer_for_render = False  # the hair alone
    tuft.data.materials.append(bh.lambert(bh.material("Fur", (0.8, 0.45, 0.1))))
    settings = tuft.modifiers.new("Fur", "PARTICLE_SYSTEM").particle_system.settings
    settings.type, settings.count, settings.hair_length = "HAIR", strands, 0.14
    settings.radius_scale, settings.root_radius, settings.tip_radius = 0.03, 1.0, 0.2
    light = bh.point_light((0.06, 0.12, 0.12), energy=2.0)
    light.data.shadow_soft_size = 0.0
    bh.camera((0, -0.25, 0)).data.clip_end = 0.8  # the tuft of the camera's own cell alone
    sc.thurston.max_distance = 0.8
    return sc


def test_hair_strands_are_tubes_that_match_cycles_tiled(tmp_path):
    sc = build()
    from thurston_addon.blender import export

    job = export.RenderJob(sc, bpy.context.evaluated_depsgraph_get())
    assert not [m for m in job.messages() if "hair" in m], job.messages()
    L = "ViewLayer."
    thurston = bh.rgb(bh.f12(sc, tmp_path / "thurston.exr"), L + "Combined.")
    bh.tile_torus_for_cycles(sc, 3, own_cell_light=True)
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=32), L + "Combined.")
    # the image holds the hair alone (the plane hidden, no World): its pixels, and its light summed
    hair, cycles_hair = (image.mean(axis=-1) > 0.02 for image in (thurston, cycles))
    totals = thurston.sum(axis=(0, 1)), cycles.sum(axis=(0, 1))
    print("hair pixels (Thurston, Cycles):", hair.sum(), cycles_hair.sum(), "light summed:", totals)
    assert cycles_hair.sum() > 150
    assert abs(hair.sum() / cycles_hair.sum() - 1) < 0.05
    np.testing.assert_allclose(totals[0], totals[1], rtol=0.07)
    both = bh.interior(hair & cycles_hair)
    np.testing.assert_allclose(thurston[both].mean(axis=0), cycles[both].mean(axis=0), rtol=0.1)


def test_children_replace_their_parents_as_in_cycles():
    """Interpolated children: Cycles renders them and not their parents (unless asked); each
    strand a tube of 2^steps + 1 keys, closed at its tip."""
    sc = build(strands=8)
    settings = sc.objects["Tuft"].particle_systems[0].settings
    settings.child_type = "INTERPOLATED"
    from thurston_addon.blender import export
    from thurston_addon.blender.export import hair

    def tube_triangles():
        notes = []
        scene = export.export_scene(bpy.context.evaluated_depsgraph_get(), 1.0, notes)
        (tubes,) = [o for o in scene.objects if o.name.startswith("Tuft (")]
        return len(tubes.triangles)

    keys = 2**settings.display_step + 1  # (a viewport depsgraph: the display steps)
    per_strand = hair.HAIR_SIDES * (2 * (keys - 2) + 1)  # rings joined by quads, the last to the tip
    assert tube_triangles() == 8 * settings.child_percent * per_strand
    settings.use_parent_particles = True
    assert tube_triangles() == 8 * (settings.child_percent + 1) * per_strand


def test_curves_objects_are_tubes_that_match_cycles_tiled(tmp_path):
    """Blender's hair since 3.3, a Curves object: 36 slanted curves of 5 points tapering from
    radius 0.006 to 0.002 (the radius attribute), against Cycles as above."""
    sc = bh.fresh_scene("torus", size=SIZE)
    sc.thurston.quality = "standard"
    sc.thurston.light_reach = 0.5
    sc.thurston.max_distance = 0.8
    sc.view_settings.view_transform = "Standard"
    curves = bpy.data.hair_curves.new("Strands")
    curves.add_curves([5] * 36)
    t = np.linspace(0, 1, 5)
    roots = np.stack(np.meshgrid(np.linspace(-0.1, 0.1, 6), np.linspace(-0.04, 0.04, 6)), -1).reshape(-1, 2)
    points = np.array([[(x + 0.03 * s, 0.3 + y, -0.08 + 0.15 * s) for s in t] for x, y in roots], np.float32)
    curves.position_data.foreach_set("vector", points.ravel())
    radius = curves.attributes.new("radius", "FLOAT", "POINT")
    radius.data.foreach_set("value", np.tile(0.006 - 0.004 * t, 36).astype(np.float32))
    curves.materials.append(bh.lambert(bh.material("Strands", (0.3, 0.5, 0.8))))
    strands = bh.link(bpy.data.objects.new("Strands", curves))
    bh.point_light((0.06, 0.12, 0.12), energy=2.0).data.shadow_soft_size = 0.0
    bh.camera((0, -0.25, 0)).data.clip_end = 0.8
    from thurston_addon.blender import export

    job = export.RenderJob(sc, bpy.context.evaluated_depsgraph_get())
    assert not [m for m in job.messages() if "curves" in m], job.messages()
    L = "ViewLayer."
    thurston = bh.rgb(bh.f12(sc, tmp_path / "thurston.exr"), L + "Combined.")
    bh.tile_torus_for_cycles(sc, 3, own_cell_light=True)
    (own_cell,) = bpy.data.objects["Light"].users_collection  # the lights' copies light their cells
    own_cell.objects.link(strands)
    sc.collection.objects.unlink(strands)
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=32), L + "Combined.")
    hair, cycles_hair = (image.mean(axis=-1) > 0.02 for image in (thurston, cycles))
    totals = thurston.sum(axis=(0, 1)), cycles.sum(axis=(0, 1))
    print("curves' pixels (Thurston, Cycles):", hair.sum(), cycles_hair.sum(), "light summed:", totals)
    assert cycles_hair.sum() > 150
    assert abs(hair.sum() / cycles_hair.sum() - 1) < 0.1  # (strands a pixel or two wide)
    np.testing.assert_allclose(totals[0], totals[1], rtol=0.07)


def test_principled_hair_is_a_diffuse_surface_of_the_hairs_colour():
    """Hair shading is not modelled: a Principled Hair BSDF shows as a diffuse surface of the colour
    its parametrization gives, noted. Cycles turns a colour c into the absorption
    (ln c / poly(radial roughness))^2 (Chiang et al.); that absorption must give c back."""
    from thurston_addon.blender.export import surfaces

    bh.fresh_scene()
    mat = bpy.data.materials.new("Hair")
    tree = mat.node_tree
    hair = tree.nodes.new("ShaderNodeBsdfHairPrincipled")
    tree.links.new(hair.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
    colour, beta = np.array([0.6, 0.35, 0.15]), 0.4
    hair.inputs["Radial Roughness"].default_value = beta
    poly = 0.245 * beta**5 + 5.574 * beta**4 - 10.73 * beta**3 + 2.532 * beta**2 - 0.215 * beta + 5.969
    hair.parametrization = "ABSORPTION"
    hair.inputs["Absorption Coefficient"].default_value = tuple((np.log(colour) / poly) ** 2)
    with pytest.warns(UserWarning, match="diffuse surface of the hair's colour"):
        np.testing.assert_allclose(surfaces.material(mat, "Tuft").color, colour, rtol=1e-5)
    hair.parametrization = "MELANIN"
    hair.inputs["Melanin"].default_value = 0.0  # no pigment: white
    with pytest.warns(UserWarning):
        np.testing.assert_allclose(surfaces.material(mat, "Tuft").color, 1.0, rtol=1e-6)
    hair.parametrization = "COLOR"
    hair.inputs["Color"].default_value = (*colour, 1)
    with pytest.warns(UserWarning):
        np.testing.assert_allclose(surfaces.material(mat, "Tuft").color, colour, rtol=1e-6)
