"""Blender meshes and materials -> scene objects: vertices in chart coordinates, Blender's corner
normals (shade smooth/flat, sharp edges, custom normals), the active render UV map, and one
material per material slot (Principled BSDF or Emission node; an Image Texture node feeding the
base or emission colour gives a texture; the Principled BSDF's Roughness, Metallic, Specular IOR
Level and IOR where they are constants)."""

from __future__ import annotations

import warnings

import bpy
import numpy as np

from ... import scenes
from ...images import srgb_to_linear


def mesh_key(inst, obj) -> tuple:
    """What depsgraph instances must share to share one mesh: the evaluated mesh data (a
    collection's or geometry nodes' instances of one geometry point to the same mesh; modifiers
    give each object its own), its materials and the pass index."""
    slots = tuple(s.material.as_pointer() if s.material else 0 for s in obj.material_slots)
    return obj.data.as_pointer(), slots, obj.original.pass_index


def chart_map(inst, scale: float) -> np.ndarray:
    """The instance's world matrix as a map of chart coordinates (world / scale) of its mesh's
    vertices (in the mesh's coordinates / scale): the translation over the scale."""
    M = np.array(inst.matrix_world, float)
    M[:3, 3] /= scale
    return M


def mesh_object(inst, obj, scale: float) -> scenes.SceneObject | None:
    """The evaluated mesh of a depsgraph instance in its own coordinates over the scale (place it
    with chart_map); None where it has no faces. Raises SceneError for what cannot be used
    (named)."""
    original = obj.original
    mesh = obj.data  # evaluated: modifiers applied
    mesh.calc_loop_triangles()
    nv, nt = len(mesh.vertices), len(mesh.loop_triangles)
    if nt == 0:
        return None
    # Blender's attribute arrays (positions, corner vertices, UV maps, face materials) are copied
    # by foreach_get at once; the triangles' corners come from loop_triangles, and every other
    # per-triangle value is gathered through them (what loop_triangles' own properties compute
    # one by one).
    loops = _get(mesh.loop_triangles, "loops", nt * 3, np.int32).reshape(-1, 3)
    co = _attribute(mesh, "position", "POINT", "vector", nv * 3, np.float32)
    if co is None:
        co = _get(mesh.vertices, "co", nv * 3, np.float32)
    corner_vert = _attribute(mesh, ".corner_vert", "CORNER", "value", len(mesh.loops), np.int32)
    if corner_vert is None:
        corner_vert = _get(mesh.loops, "vertex_index", len(mesh.loops), np.int32)
    tri = corner_vert[loops]
    normals = None
    # as Cycles uses them: smooth everywhere (POINT), the vertex normals (what corner_normals
    # holds then); all faces flat (FACE), none (the triangles' own normals)
    if mesh.normals_domain == "POINT":
        normals = _get(mesh.vertex_normals, "vector", nv * 3, np.float32).reshape(-1, 3)[tri]
    elif mesh.normals_domain == "CORNER":
        corner = _get(mesh.corner_normals, "vector", len(mesh.corner_normals) * 3, np.float32).reshape(-1, 3)
        normals = corner[loops]
    uvs = None
    layer = next((layer for layer in mesh.uv_layers if layer.active_render), None)
    if layer is not None:
        uv = _attribute(mesh, layer.name, "CORNER", "vector", len(mesh.loops) * 2, np.float32)
        if uv is None:
            uv = _get(layer.data, "uv", len(layer.data) * 2, np.float32)
        uvs = uv.reshape(-1, 2)[loops]
    slots = [slot.material for slot in obj.material_slots]
    materials = [material(m, original.name) for m in slots] or [material(None, original.name)]
    face_material = _attribute(mesh, "material_index", "FACE", "value", len(mesh.polygons), np.int32)
    if face_material is None:  # (no attribute: every face has the first slot)
        index = np.zeros(nt, np.int32)
    else:
        index = np.clip(face_material[_get(mesh.loop_triangle_polygons, "value", nt, np.int32)], 0, len(materials) - 1)
    name = original.name if not inst.is_instance else f"{original.name} ({inst.parent.original.name})"
    first = materials[index[0]]
    return scenes.clean(
        scenes.SceneObject(
            name,
            np.divide(co.reshape(-1, 3), scale, dtype=np.float64),
            tri,
            first.color,
            first.emission,
            pass_index=original.pass_index,
            corner_normals=normals,
            corner_uvs=uvs,
            triangle_material=index,
            materials=materials,
        ),
        "Blender",
    )


def _attribute(mesh, name, domain, value, count, dtype):
    """A mesh attribute's values (foreach_get of `value`: count numbers) in a new array; None where
    the mesh has no such attribute on that domain."""
    attribute = mesh.attributes.get(name)
    if attribute is None or attribute.domain != domain:
        return None
    return _get(attribute.data, value, count, dtype)


def _get(collection, attribute, count, dtype):
    """collection.foreach_get into a new array (attribute None: a property array such as pixels)."""
    values = np.empty(count, dtype)
    if attribute is None:
        collection.foreach_get(values)
    else:
        collection.foreach_get(attribute, values)
    return values


# The Principled BSDF's inputs that become the material's scattering (scenes.Material's names).
SCATTERING_INPUTS = {"roughness": "Roughness", "metallic": "Metallic", "specular": "Specular IOR Level", "ior": "IOR"}


def material(mat, object_name: str) -> scenes.Material:
    """Base colour and emission of a material: Principled BSDF or Emission node inputs; an Image
    Texture node linked to a colour gives its image (times the strength for emission); other links
    fall back to the material's viewport colour. The Principled BSDF's scattering inputs are taken
    as their constants (a link to them is not followed: its socket's own value counts); an Emission
    shader reflects nothing."""
    if mat is None:
        return scenes.Material(name="")
    where = f"object {object_name!r}, material {mat.name!r}"
    color, emission = np.array(mat.diffuse_color[:3], float), np.zeros(3)
    color_texture = emission_texture = None
    scattering = {}
    # Blender 5 always uses material nodes (use_nodes is deprecated there)
    if mat.node_tree and (bpy.app.version >= (5, 0, 0) or mat.use_nodes):
        for node in mat.node_tree.nodes:
            if node.type == "BSDF_PRINCIPLED":
                color, color_texture = _input(node.inputs["Base Color"], color)
                em = node.inputs.get("Emission Color") or node.inputs.get("Emission")
                strength = node.inputs.get("Emission Strength")
                if em is not None:
                    value, emission_texture = _input(em, np.zeros(3))
                    emission = value * (strength.default_value if strength else 1.0)
                scattering = {
                    key: _clamped(key, node.inputs[name].default_value)
                    for key, name in SCATTERING_INPUTS.items()
                    if name in node.inputs
                }
                break
            if node.type == "EMISSION":
                color = np.zeros(3)
                value, emission_texture = _input(node.inputs["Color"], np.zeros(3))
                emission = value * node.inputs["Strength"].default_value
                break
    try:
        return scenes.Material(color, emission, color_texture, emission_texture, name=mat.name, **scattering)
    except scenes.SceneError as exc:
        raise scenes.SceneError(f"{where}: {exc}") from None


def _clamped(key: str, value: float) -> float:
    """A scattering input as Cycles takes it: roughness and metallic within [0, 1], the specular
    level at least 0, the IOR at least 1e-5 (below 1 it reflects as its inverse does)."""
    ((low, high),) = [bounds for name, bounds, _ in scenes.SCATTERING if name == key]
    return float(np.clip(value, max(low, 1e-5) if key == "ior" else low, high))


def _input(socket, fallback):
    """(constant, texture) of a colour input: its value; white times the image of a linked Image
    Texture node (magenta where the image has no pixels, as in Cycles); else the fallback."""
    if not socket.is_linked:
        return np.array(socket.default_value[:3], float), None
    node = socket.links[0].from_node
    if node.type == "TEX_IMAGE" and node.image is not None:
        texture = image_texture(node.image)
        return (np.ones(3), texture) if texture is not None else (MISSING_IMAGE.copy(), None)
    return np.asarray(fallback, float), None


# What Cycles renders for an image it cannot read (its file missing or broken): magenta.
MISSING_IMAGE = np.array([1.0, 0.0, 1.0])


def image_texture(image) -> np.ndarray | None:
    """An image's pixels as a linear float RGB texture, rows top-down. Float images hold linear
    values; byte images hold their colour space's values, decoded here for sRGB. An image without
    pixels (its file missing or unreadable) is None, with a warning naming it (the colour is
    then MISSING_IMAGE, as in Cycles)."""
    w, h = image.size
    count = len(image.pixels)  # reading the pixels loads the image's file
    if w * h == 0 or count != w * h * image.channels:
        path = bpy.path.abspath(image.filepath) if image.filepath else ""
        source = f"its file {path!r} is missing or cannot be read" if path else "it has no file"
        warnings.warn(
            f"image {image.name!r} has no pixels ({source}): rendered magenta, as Cycles does; "
            "restore the file or choose another image in the Image Texture node",
            stacklevel=2,
        )
        return None
    pixels = _get(image.pixels, None, count, np.float32)
    pixels = pixels.reshape(h, w, image.channels)[::-1]  # Blender's rows are bottom-up
    rgb = pixels[..., :3] if image.channels >= 3 else np.repeat(pixels[..., :1], 3, axis=2)
    if not image.is_float and image.colorspace_settings.name == "sRGB":
        rgb = srgb_to_linear(rgb)
    return np.ascontiguousarray(rgb, np.float32)
