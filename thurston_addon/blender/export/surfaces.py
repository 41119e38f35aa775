"""Blender meshes and materials -> scene objects: vertices in chart coordinates, Blender's corner
normals (shade smooth/flat, sharp edges, custom normals), the active render UV map (or the
coordinates and Mapping a material's Image Texture reads), and one material per material slot
(shading.py reads its node tree from the Material Output)."""

from __future__ import annotations

import functools
import warnings

import bpy
import numpy as np

from ... import scenes
from ...images import srgb_to_linear
from . import bake, shading


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


def mesh_object(inst, obj, scale: float, bake_size: int | None = None) -> scenes.SceneObject | None:
    """The evaluated mesh of a depsgraph instance in its own coordinates over the scale (place it
    with chart_map); None where it has no faces. Colours from procedural nodes are baked by Cycles
    to images of side `bake_size` (None: not baked, noted). Raises SceneError for what cannot be
    used (named)."""
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
    baker = None if bake_size is None else bake.Baker(obj, inst.matrix_world.copy(), bake_size)
    surfaces = [
        material_surface(m, original.name, baker and functools.partial(baker, m, k)) for k, m in enumerate(slots)
    ] or [material_surface(None, original.name)]
    materials = [m for m, _ in surfaces]
    face_material = _attribute(mesh, "material_index", "FACE", "value", len(mesh.polygons), np.int32)
    if face_material is None:  # (no attribute: every face has the first slot)
        index = np.zeros(nt, np.int32)
    else:
        index = np.clip(face_material[_get(mesh.loop_triangle_polygons, "value", nt, np.int32)], 0, len(materials) - 1)
    for k, (_, texture) in enumerate(surfaces):  # textures read through other coordinates or a Mapping
        mine = index == k
        if texture is None or not mine.any():
            continue
        mapped = texture_uvs(texture, mesh, co.reshape(-1, 3), loops[mine])
        if mapped is not None:
            uvs = np.zeros((nt, 3, 2)) if uvs is None else uvs
            uvs[mine] = mapped
    name = original.name if not inst.is_instance else f"{original.name} ({inst.parent.original.name})"
    if uvs is None and any(m.color_texture is not None or m.emission_texture is not None for m in materials):
        warnings.warn(
            f"object {name!r} has an image texture but no UV map: it shows the texture's colour at UV (0, 0), "
            "as Cycles does; add a UV map (UV > Unwrap) to map the image"
        )
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


def material(mat, object_name: str) -> scenes.Material:
    """The scene material of a Blender material (see shading.py: what reaches its Material Output's
    Surface); what cannot be shown is one warning (a note of the render report) naming it."""
    return material_surface(mat, object_name)[0]


def material_surface(mat, object_name: str, bake=None) -> tuple[scenes.Material, shading.Texture | None]:
    """The scene material and the texture whose coordinates its triangles get (None: the active
    render UV map as it is); `bake`: see shading.surface."""
    if mat is None:
        return scenes.Material(name=""), None
    where = f"object {object_name!r}, material {mat.name!r}"
    if mat.node_tree is not None and (bpy.app.version >= (5, 0, 0) or mat.use_nodes):
        surface = shading.surface(mat, mat.diffuse_color, bake)
    else:  # (before Blender 5, a material without nodes: its viewport colour, as Cycles)
        surface = shading.Surface(np.array(mat.diffuse_color[:3], float), np.zeros(3))
    color, emission = surface.color, surface.emission
    textures = []
    for texture, value in ((surface.color_texture, color), (surface.emission_texture, emission)):
        pixels = None if texture is None else texture.pixels if texture.image is None else image_texture(texture.image)
        if texture is not None and pixels is None:  # magenta where the image has no pixels, as in Cycles
            value *= MISSING_IMAGE
        textures.append(pixels)
    shading.warn_notes(mat, surface.notes)
    try:
        result = scenes.Material(color, emission, *textures, name=mat.name, **surface.scattering)
    except scenes.SceneError as exc:
        raise scenes.SceneError(f"{where}: {exc}") from None
    texture = surface.texture
    plain = texture is not None and texture.source is None and texture.loop_uvs is None
    if plain and np.array_equal(texture.affine, np.eye(2, 4)):
        texture = None
    return result, texture


def texture_uvs(texture: shading.Texture, mesh, co, loops) -> np.ndarray | None:
    """(m, 3, 2) corner UVs of the triangles for a texture's coordinates and Mapping."""
    if texture.source == "GENERATED":  # the mesh's texture space: its box as [0, 1]^3
        loc, size = np.array(mesh.texspace_location, float), np.array(mesh.texspace_size, float)
        size = np.where(size != 0, size, 1.0)
        points = ((co - loc) / (2 * size) + 0.5)[np.asarray(tri_vertices(mesh, loops))]
    elif texture.source == "OBJECT":
        points = co[np.asarray(tri_vertices(mesh, loops))]
    else:
        if texture.loop_uvs is not None:  # baked on a Smart UV Project of the object
            uv = texture.loop_uvs.astype(np.float64)[loops]
        else:
            layer = mesh.uv_layers.get(texture.source) if texture.source else None
            layer = layer or next((layer for layer in mesh.uv_layers if layer.active_render), None)
            if layer is None:
                return None
            uv = _get(layer.data, "uv", len(layer.data) * 2, np.float64).reshape(-1, 2)[loops]
        points = np.concatenate([uv, np.zeros(uv.shape[:-1] + (1,))], axis=-1)
    homogeneous = np.concatenate([points, np.ones(points.shape[:-1] + (1,))], axis=-1)
    return homogeneous @ texture.affine.T


def tri_vertices(mesh, loops) -> np.ndarray:
    """The vertex of each triangle corner (loops: the corners' loop indices)."""
    loop_vertex = _get(mesh.loops, "vertex_index", len(mesh.loops), np.int32)
    return loop_vertex[loops]


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
