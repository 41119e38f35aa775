"""Shader nodes in real bpy: what reaches the Material Output's Surface is read (never an
unconnected node); Diffuse, Glossy, Metallic, Emission, Mix Shader and Add Shader as a blend of the
Principled parameters; Image Textures through a Mapping node and other coordinates; one note per
material for what Thurston cannot show. Against Cycles: planes in the torus seen from inside, lit
by a point light within a light reach that holds only its copy in the point's own cell, the
reference Cycles rendering the 3x3x3 tiled scene (direct light only)."""

from __future__ import annotations

import math
import types
import warnings

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")

from support import blender_helpers as bh  # noqa: E402

SIZE = (96, 54)
LIGHT_REACH = 0.5


def shader_material(name):
    """A new material whose tree keeps its (now unconnected) Principled BSDF, painted red, and its
    output: what a user leaves behind when wiring another shader to the output."""
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (0.8, 0.8, 0.8, 1)
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (1, 0, 0, 1)
    for link in list(mat.node_tree.links):
        mat.node_tree.links.remove(link)
    return mat, mat.node_tree.nodes, mat.node_tree


def to_output(mat, socket):
    mat.node_tree.links.new(socket, mat.node_tree.nodes["Material Output"].inputs["Surface"])
    return mat


def diffuse(nodes, color):
    d = nodes.new("ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = (*color, 1)
    return d


def glossy(nodes, color, roughness):
    g = nodes.new("ShaderNodeBsdfGlossy")
    g.distribution = "GGX"  # single scattering, the tracer's
    g.inputs["Color"].default_value = (*color, 1)
    g.inputs["Roughness"].default_value = roughness
    return g


def mix(tree, factor, a, b):
    m = tree.nodes.new("ShaderNodeMixShader")
    m.inputs[0].default_value = factor
    tree.links.new(a.outputs[0], m.inputs[1])
    tree.links.new(b.outputs[0], m.inputs[2])
    return m


def emission(nodes, color, strength):
    e = nodes.new("ShaderNodeEmission")
    e.inputs["Color"].default_value = (*color, 1)
    e.inputs["Strength"].default_value = strength
    return e


def build_materials():
    """The supported shaders, each in a material of its own; (name -> material, exact)."""
    out = {}
    mat, nodes, tree = shader_material("Diffuse")
    out["Diffuse"] = to_output(mat, diffuse(nodes, (0.2, 0.6, 0.3)).outputs[0]), True
    mat, nodes, tree = shader_material("Glossy")
    out["Glossy"] = to_output(mat, glossy(nodes, (0.9, 0.7, 0.4), 0.35).outputs[0]), False
    mat, nodes, tree = shader_material("MixDiffuse")
    m = mix(tree, 0.3, diffuse(nodes, (0.9, 0.2, 0.1)), diffuse(nodes, (0.1, 0.3, 0.9)))
    out["MixDiffuse"] = to_output(mat, m.outputs[0]), True
    mat, nodes, tree = shader_material("AddEmission")
    a = tree.nodes.new("ShaderNodeAddShader")
    tree.links.new(diffuse(nodes, (0.5, 0.5, 0.5)).outputs[0], a.inputs[0])
    tree.links.new(emission(nodes, (0.3, 0.2, 0.1), 0.5).outputs[0], a.inputs[1])
    out["AddEmission"] = to_output(mat, a.outputs[0]), True
    mat, nodes, tree = shader_material("MixGlossy")
    m = mix(tree, 0.3, diffuse(nodes, (0.6, 0.5, 0.3)), glossy(nodes, (0.6, 0.5, 0.3), 0.4))
    out["MixGlossy"] = to_output(mat, m.outputs[0]), False
    mat, nodes, tree = shader_material("Tiled")
    image = bpy.data.images.new("Checker", 2, 2, float_buffer=True)
    image.pixels.foreach_set(np.ascontiguousarray(bh.CHECKER[::-1]).ravel())
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = (3, 2, 1)
    mapping.inputs["Location"].default_value = (0.25, 0, 0)
    coords = nodes.new("ShaderNodeTexCoord")
    tree.links.new(coords.outputs["UV"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    d = diffuse(nodes, (1, 1, 1))
    tree.links.new(tex.outputs["Color"], d.inputs["Color"])
    out["Tiled"] = to_output(mat, d.outputs[0]), True
    return out


def material_of(mat):
    """(scenes.Material, the warnings' messages) of a Blender material."""
    from thurston_addon.blender.export import surfaces

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = surfaces.material(mat, "Plane")
    return result, [str(w.message) for w in caught]


# --- the export ------------------------------------------------------------------------------------
def test_the_shader_wired_to_the_output_is_read_as_a_blend():
    bh.fresh_scene()
    mats = {name: mat for name, (mat, _) in build_materials().items()}
    m, notes = material_of(mats["Diffuse"])  # not the red Principled left in the tree
    assert notes == [] and m.color == pytest.approx([0.2, 0.6, 0.3]) and (m.metallic, m.specular) == (0, 0)
    m, notes = material_of(mats["MixDiffuse"])
    assert notes == [] and m.color == pytest.approx(0.7 * np.array([0.9, 0.2, 0.1]) + 0.3 * np.array([0.1, 0.3, 0.9]))
    m, notes = material_of(mats["AddEmission"])
    assert notes == [] and m.color == pytest.approx([0.5] * 3) and m.emission == pytest.approx([0.15, 0.1, 0.05])
    m, notes = material_of(mats["MixGlossy"])
    assert notes == [] and m.color == pytest.approx([0.6, 0.5, 0.3])
    assert (m.metallic, m.roughness, m.specular) == pytest.approx((0.3, 0.4, 0.0))
    m, notes = material_of(mats["Glossy"])
    assert notes == [] and (m.metallic, m.roughness) == pytest.approx((1.0, 0.35))
    # a Metallic BSDF: Principled metallic 1 of its colour and roughness
    mat, nodes, tree = shader_material("Metal")
    metal = nodes.new("ShaderNodeBsdfMetallic")
    metal.inputs["Base Color"].default_value = (0.7, 0.5, 0.2, 1)
    metal.inputs["Roughness"].default_value = 0.25
    metal.inputs["Edge Tint"].default_value = (1, 1, 1, 1)  # (its default tint is noted)
    m, notes = material_of(to_output(mat, metal.outputs[0]))
    assert notes == [] and (m.metallic, m.roughness) == pytest.approx((1.0, 0.25))
    assert m.color == pytest.approx([0.7, 0.5, 0.2])
    # nothing wired to the Surface: black, as Cycles renders it (not the Principled left in the tree)
    mat, _, _ = shader_material("Unwired")
    m, notes = material_of(mat)
    assert m.color == pytest.approx([0, 0, 0]) and notes == []


def test_reroutes_muted_nodes_and_groups_are_followed():
    bh.fresh_scene()
    mat, nodes, tree = shader_material("Routed")
    group = bpy.data.node_groups.new("Shade", "ShaderNodeTree")
    group.interface.new_socket("Tint", in_out="INPUT", socket_type="NodeSocketColor")
    group.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
    gin, gout = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
    inner = group.nodes.new("ShaderNodeBsdfDiffuse")
    group.links.new(gin.outputs["Tint"], inner.inputs["Color"])
    group.links.new(inner.outputs[0], gout.inputs["Shader"])
    node = nodes.new("ShaderNodeGroup")
    node.node_tree = group
    node.inputs["Tint"].default_value = (0.1, 0.2, 0.7, 1)
    muted = mix(tree, 0.9, node, diffuse(nodes, (1, 1, 0)))
    muted.mute = True  # passes its first shader through
    reroute = nodes.new("NodeReroute")
    tree.links.new(muted.outputs[0], reroute.inputs[0])
    m, notes = material_of(to_output(mat, reroute.outputs[0]))
    assert notes == [] and m.color == pytest.approx([0.1, 0.2, 0.7])


def unsupported(kind):
    """A material showing one thing Thurston cannot render."""
    mat = bpy.data.materials.new(kind)
    nodes, tree = mat.node_tree.nodes, mat.node_tree
    p = nodes["Principled BSDF"]
    if kind == "glass":
        to_output(mat, nodes.new("ShaderNodeBsdfGlass").outputs[0])
    elif kind == "transmission":
        p.inputs["Transmission Weight"].default_value = 1.0
    elif kind == "alpha":
        p.inputs["Alpha"].default_value = 0.5
    elif kind == "normal map":
        tree.links.new(nodes.new("ShaderNodeNormalMap").outputs[0], p.inputs["Normal"])
    elif kind == "volume":
        volume = nodes.new("ShaderNodeVolumePrincipled")
        tree.links.new(volume.outputs[0], nodes["Material Output"].inputs["Volume"])
    elif kind == "noise":
        tree.links.new(nodes.new("ShaderNodeTexNoise").outputs["Color"], p.inputs["Base Color"])
    elif kind == "color ramp":
        tree.links.new(nodes.new("ShaderNodeValToRGB").outputs["Color"], p.inputs["Base Color"])
    elif kind == "box":
        tex = nodes.new("ShaderNodeTexImage")
        tex.image, tex.projection = bpy.data.images.new("Box", 2, 2), "BOX"
        tree.links.new(tex.outputs["Color"], p.inputs["Base Color"])
    elif kind == "transparent":
        m = mix(tree, 0.5, p, nodes.new("ShaderNodeBsdfTransparent"))
        to_output(mat, m.outputs[0])
    return mat


NOTES = {  # what the note must say
    "glass": ("Glass BSDF", "reflection"),
    "transmission": ("transmission", "opaque"),
    "alpha": ("alpha", "opaque"),
    "normal map": ("Normal Map", "normals"),
    "volume": ("volume",),
    "noise": ("Noise Texture", "own colour"),
    "color ramp": ("Color Ramp", "own colour"),
    "box": ("Box projection",),
    "transparent": ("Transparent BSDF", "black"),
}


@pytest.mark.parametrize("kind", NOTES)
def test_what_cannot_be_rendered_is_one_note_naming_the_material(kind):
    bh.fresh_scene()
    _, notes = material_of(unsupported(kind))
    assert len(notes) == 1 and notes[0].startswith(f"material {kind!r}: "), notes
    assert all(word in notes[0] for word in NOTES[kind]), notes


def plane_object(mat, name="Plane"):
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    obj = bpy.context.object
    obj.name = name
    obj.data.materials.append(mat)
    return obj


def exported(obj):
    from thurston_addon.blender.export import surfaces

    depsgraph = bpy.context.evaluated_depsgraph_get()
    inst = types.SimpleNamespace(is_instance=False, matrix_world=obj.matrix_world)
    return surfaces.mesh_object(inst, obj.evaluated_get(depsgraph), 1.0)


def test_mapping_and_coordinates_give_the_corner_uvs():
    bh.fresh_scene()
    mat = build_materials()["Tiled"][0]
    obj = plane_object(mat)
    uv = bpy.data.meshes[obj.data.name].uv_layers.active.data
    plain = np.array([[uv[i].uv[:] for i in tri.loops] for tri in obj.data.loop_triangles])
    got = exported(obj).corner_uvs
    np.testing.assert_allclose(got, plain * [3, 2] + [0.25, 0], atol=1e-6)
    # Generated coordinates: the mesh's box as [0, 1]; rotated 90 degrees about z by the Mapping
    tree = mat.node_tree
    tex_coord, mapping = tree.nodes["Texture Coordinate"], tree.nodes["Mapping"]
    tree.links.new(tex_coord.outputs["Generated"], mapping.inputs["Vector"])
    mapping.inputs["Scale"].default_value = (1, 1, 1)
    mapping.inputs["Location"].default_value = (0, 0, 0)
    mapping.inputs["Rotation"].default_value = (0, 0, math.pi / 2)
    corners = np.array([[obj.data.vertices[v].co[:2] for v in tri.vertices] for tri in obj.data.loop_triangles])
    generated = (corners + 1) / 2
    got = exported(obj).corner_uvs
    np.testing.assert_allclose(got, np.stack([-generated[..., 1], generated[..., 0]], -1), atol=1e-6)
    tree.links.new(tex_coord.outputs["Camera"], mapping.inputs["Vector"])  # not representable: noted
    _, notes = material_of(mat)
    assert len(notes) == 1 and "Camera coordinates" in notes[0], notes


# --- against Cycles --------------------------------------------------------------------------------
def build_planes():
    """The supported shaders on planes facing the camera, in a 3x2 grid, in the torus: the glossy
    ones where they show the light's highlight (the top middle holds its mirror point)."""
    sc = bh.fresh_scene("torus", size=SIZE)
    sc.thurston.quality = "standard"
    sc.thurston.light_reach = LIGHT_REACH
    sc.view_settings.view_transform = "Standard"
    materials = build_materials()
    for k, (name, (mat, _)) in enumerate(materials.items()):
        x, z = (k % 3 - 1) * 0.15, (0.5 - k // 3) * 0.15
        bpy.ops.mesh.primitive_plane_add(size=0.12, location=(x, 0.32, z), rotation=(math.pi / 2, 0, 0))
        plane = bpy.context.object
        plane.name, plane.pass_index = name, k + 1
        plane.data.materials.append(mat)
    light = bh.point_light((0.0, 0.12, 0.05), energy=2.0)
    light.data.shadow_soft_size = 0.0
    bh.camera((0, -0.05, 0), lens=20.0)
    return sc, materials


def test_shader_nodes_match_cycles_tiled(tmp_path):
    """Each supported shader's plane against Cycles: exact blends within 5% (the texture, tiled by
    its Mapping, pixel by pixel), the approximated ones (a Glossy BSDF as a metal, its mix with a
    Diffuse as one Principled) within 15%."""
    sc, materials = build_planes()
    sc.view_layers[0].use_pass_z = sc.view_layers[0].use_pass_object_index = True
    L = "ViewLayer."
    ch = bh.f12(sc, tmp_path / "thurston.exr")
    thurston = bh.rgb(ch, L + "Combined.")
    index, depth = ch[L + "IndexOB.X"], ch[L + "Depth.Z"]
    notes = [n.message for n in sc.thurston.stats.notes if "material" in n.message]
    assert notes == [], notes
    bh.tile_torus_for_cycles(sc, 3, own_cell_light=True)
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=32), L + "Combined.")
    near = depth < 1.0
    report = {}
    for k, name in enumerate(materials):
        mask = bh.interior(near & (np.abs(index - (k + 1)) < 0.01))
        assert mask.sum() > 40, name
        mean_error = np.abs(thurston[mask].mean(axis=0) - cycles[mask].mean(axis=0)) / cycles[mask].mean()
        pixel_error = float(np.abs(thurston[mask] - cycles[mask]).sum() / cycles[mask].sum())
        report[name] = (float(mean_error.max()), pixel_error)
    print("relative difference from Cycles (mean colour, per pixel):", report)
    for name, (_, exact) in materials.items():
        mean_error, pixel_error = report[name]
        assert mean_error < (0.05 if exact else 0.15), (name, report)
        if name == "Tiled":
            assert pixel_error < 0.08, (name, report)


def test_the_note_reaches_the_render_report(tmp_path):
    """F12: one note naming the material (used by two objects) and what the image shows."""
    sc = bh.fresh_scene("torus", size=(8, 8))
    glass = unsupported("glass")
    for name, x in (("Left", -0.06), ("Right", 0.06)):
        bh.box(name, (0.1, 0.02, 0.3), (x, 0.3, 0)).data.materials[0] = glass
    bh.point_light((0, 0.1, 0.1), energy=1.0)
    bh.camera((0, 0, 0))
    bh.f12(sc, tmp_path / "thurston.exr")
    notes = [n.message for n in sc.thurston.stats.notes if "'glass'" in n.message]
    assert len(notes) == 1 and "Glass BSDF" in notes[0] and "reflection" in notes[0], notes
