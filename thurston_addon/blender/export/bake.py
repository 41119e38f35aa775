"""Colours that procedural nodes give (a Noise Texture, a ColorRamp, a checker made of nodes, ... into
a Base Color or an Emission Color), baked by Cycles: what reaches the input is wired into a
temporary Emission shader and Cycles' Emit bake writes it to a float image on the object's active
render UV map (an object without one: a Smart UV Project of its copy, whose UVs the object then
gets), which the material then reads as its texture. The bake runs on a temporary copy of the
evaluated mesh (only the faces of that material) in a temporary scene, all removed after.
Bakes are kept (the last CACHE_MOST) by everything they depend on: the node tree, the evaluated
mesh, the object's place, the size. Blender bakes only on its main thread: a render on another (an
interactive F12) uses the kept bake of an unchanged input (the rendered viewport's, an earlier
render's) and otherwise keeps the note that the input's own colour is shown."""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass

import numpy as np

# The baked image's side: twice the render's longer side (an object filling the frame spreads over
# part of its UV square), rounded up to a power of two, within these
BAKE_PER_PIXEL = 2
BAKE_LEAST, BAKE_MOST = 64, 2048
BAKE_SAMPLES = 4  # per texel: enough to smooth a texel's edges, the colour itself is not noisy
BAKE_MARGIN = 2  # texels: bilinear lookups at a UV island's edge stay within the island's colours
_NAME = "Thurston Bake"  # the temporary datablocks' (and the UV map Smart UV Project makes)
UNWRAP_MARGIN = 0.02  # Smart UV Project's island margin (of the UV square)


class Unavailable(Exception):
    """Why a colour could not be baked (said in the material's note)."""


def bake_size(bscene) -> int:
    """The side of a baked image for a render of this scene (see BAKE_LEAST, BAKE_MOST)."""
    r = bscene.render
    side = BAKE_PER_PIXEL * max(r.resolution_x, r.resolution_y) * r.resolution_percentage / 100
    return int(min(max(2 ** int(np.ceil(np.log2(max(side, 1)))), BAKE_LEAST), BAKE_MOST))


@dataclass
class Baked:
    """A baked colour: its (size, size, 3) linear pixels, rows top-down, the UV map it was baked on
    (None: a Smart UV Project of the object's copy) and then that projection's UVs per corner of the
    evaluated mesh (its loops)."""

    pixels: np.ndarray
    uv_map: str | None
    loop_uvs: np.ndarray | None = None


class Baker:
    """Bakes colour inputs of one evaluated mesh object's materials: call it with the material, its
    slot and the input socket (in the material's own tree, not a node group's); it returns what was
    Baked, or raises Unavailable. An object without a UV map is baked on a Smart UV Project of its
    temporary copy (made once, for all its materials), whose UVs the export then gives the object."""

    def __init__(self, obj, matrix_world, size: int):
        self.obj, self.matrix_world, self.size = obj, matrix_world, size
        self._unwrapped: np.ndarray | None = None  # the Smart UV Project's UVs per loop

    def __call__(self, mat, slot: int, socket) -> Baked:
        """The bake of `socket`, made again only where anything it depends on changed: the
        rendered viewport exports again after each change, and a bake's temporary datablocks are
        a change (its cache ends that loop)."""
        key = (
            self.obj.original.name,
            mat.name,
            slot,
            socket.node.name,
            socket.identifier,
            self.size,
            tree_fingerprint(mat.node_tree),
            mesh_fingerprint(self.obj),
            tuple(map(tuple, self.matrix_world)),
        )
        baked = _CACHE.pop(key, None)
        if baked is None:
            baked = self._bake(mat, slot, socket)
        _CACHE[key] = baked  # (the most recent last)
        while len(_CACHE) > CACHE_MOST:
            _CACHE.pop(next(iter(_CACHE)))
        return baked

    def _bake(self, mat, slot: int, socket) -> Baked:
        import bpy

        if threading.current_thread() is not threading.main_thread():
            raise Unavailable(
                "Blender bakes only on its main thread, not in an interactive F12 render "
                "(the viewport's rendered view bakes it, and F12 then uses that bake; `thurston "
                "render-blend` bakes it)"
            )
        uv = next((layer.name for layer in self.obj.data.uv_layers if layer.active_render), None)
        made = []  # the temporary datablocks, removed whatever happens
        try:
            mesh = bpy.data.meshes.new_from_object(self.obj)
            made.append((bpy.data.meshes, mesh))
            scene = bpy.data.scenes.new(_NAME)
            made.append((bpy.data.scenes, scene))
            obj = bpy.data.objects.new(_NAME, mesh)
            made.insert(0, (bpy.data.objects, obj))
            obj.matrix_world = self.matrix_world  # (Position and World coordinates as the object's)
            scene.collection.objects.link(obj)
            layer = scene.view_layers[0]
            layer.objects.active = obj
            override = dict(scene=scene, view_layer=layer, active_object=obj, object=obj)
            override.update(selected_objects=[obj], selected_editable_objects=[obj])
            if uv is None:
                self._unwrap(mesh, override)
            mesh.uv_layers.active = mesh.uv_layers[uv or _NAME]
            _keep_slot(mesh, slot)
            copy = mat.copy()
            made.append((bpy.data.materials, copy))
            mesh.materials.clear()
            mesh.materials.append(copy)
            image = bpy.data.images.new(_NAME, self.size, self.size, float_buffer=True)
            made.append((bpy.data.images, image))
            _emit_input(copy.node_tree, socket, image)
            scene.render.engine = "CYCLES"
            scene.cycles.device = "CPU"
            scene.cycles.samples = BAKE_SAMPLES
            with bpy.context.temp_override(**override):
                result = bpy.ops.object.bake(
                    type="EMIT",
                    width=self.size,
                    height=self.size,
                    margin=BAKE_MARGIN,
                    target="IMAGE_TEXTURES",
                    use_clear=True,
                )
            if result != {"FINISHED"}:
                raise Unavailable(f"Cycles' bake did not finish ({', '.join(sorted(result))})")
            pixels = np.empty(self.size * self.size * 4, np.float32)
            image.pixels.foreach_get(pixels)
        except RuntimeError as exc:  # the bake operator's own error
            raise Unavailable(f"Cycles' bake failed: {str(exc).strip()}") from None
        finally:
            for collection, datablock in made:
                collection.remove(datablock)
        rgb = pixels.reshape(self.size, self.size, 4)[::-1, :, :3]  # Blender's rows are bottom-up
        return Baked(np.ascontiguousarray(rgb), uv, None if uv else self._unwrapped)

    def _unwrap(self, mesh, override):
        """A UV map on the temporary mesh (all its faces): the object's Smart UV Project, made once."""
        import bpy

        mesh.uv_layers.new(name=_NAME)
        if self._unwrapped is None:
            with bpy.context.temp_override(**override):
                bpy.ops.object.mode_set(mode="EDIT")
                try:
                    with bpy.context.temp_override(edit_object=override["object"]):
                        bpy.ops.mesh.select_all(action="SELECT")
                        bpy.ops.uv.smart_project(island_margin=UNWRAP_MARGIN)
                finally:
                    bpy.ops.object.mode_set(mode="OBJECT")
            uvs = np.empty(len(mesh.loops) * 2, np.float32)  # (edit mode made the mesh's layers anew)
            mesh.uv_layers[_NAME].data.foreach_get("uv", uvs)
            self._unwrapped = uvs.reshape(-1, 2)
        else:
            mesh.uv_layers[_NAME].data.foreach_set("uv", self._unwrapped.ravel())


CACHE_MOST = 64  # bakes kept between exports
_CACHE: dict[tuple, Baked] = {}  # by what they depend on (Baker.__call__), least recent first
# Node properties that do not change what a node computes
_LAYOUT = {"location", "location_absolute", "width", "height", "dimensions", "select", "hide", "label", "name"}


def tree_fingerprint(tree, seen=None) -> tuple:
    """What a node tree computes, as a tuple: its nodes' types, settings and input values (colour
    ramps, curves and node groups' trees within), and its links."""
    seen = set() if seen is None else seen
    if tree is None or tree.name in seen:
        return ()
    seen.add(tree.name)
    nodes = []
    for node in tree.nodes:
        settings = [
            (p.identifier, _plain(getattr(node, p.identifier)))
            for p in node.bl_rna.properties
            if p.type in ("BOOLEAN", "INT", "FLOAT", "STRING", "ENUM") and p.identifier not in _LAYOUT
        ]
        inputs = [(i.identifier, _plain(getattr(i, "default_value", None))) for i in node.inputs]
        extra = []
        ramp = getattr(node, "color_ramp", None)
        if ramp is not None:
            extra += [ramp.interpolation, ramp.color_mode]
            extra += [(e.position, tuple(e.color)) for e in ramp.elements]
        mapping = getattr(node, "mapping", None)
        if mapping is not None and hasattr(mapping, "curves"):
            extra += [tuple((p.location[:], p.handle_type) for p in c.points) for c in mapping.curves]
        for pointer in ("image", "object", "node_tree"):
            value = getattr(node, pointer, None)
            extra.append(getattr(value, "name", None))
        if getattr(node, "image", None) is not None:
            extra.append(node.image.is_dirty)
        extra.append(tree_fingerprint(getattr(node, "node_tree", None), seen))
        nodes.append((node.name, node.bl_idname, node.mute, tuple(settings), tuple(inputs), tuple(extra)))
    links = [
        (k.from_node.name, k.from_socket.identifier, k.to_node.name, k.to_socket.identifier, k.is_muted)
        for k in tree.links
    ]
    return tuple(nodes), tuple(links)


def _plain(value):
    """A property's value as something hashable."""
    try:
        return tuple(value)
    except TypeError:
        return value


def mesh_fingerprint(obj) -> str:
    """A digest of the evaluated mesh's positions, corners, UV maps and face materials."""
    mesh = obj.data
    digest = hashlib.blake2b(digest_size=16)
    for collection, attribute, count, dtype in (
        (mesh.vertices, "co", 3 * len(mesh.vertices), np.float32),
        (mesh.loops, "vertex_index", len(mesh.loops), np.int32),
        (mesh.polygons, "loop_start", len(mesh.polygons), np.int32),
        (mesh.polygons, "material_index", len(mesh.polygons), np.int32),
        *((layer.data, "uv", 2 * len(layer.data), np.float32) for layer in mesh.uv_layers),
    ):
        values = np.empty(count, dtype)
        collection.foreach_get(attribute, values)
        digest.update(values.tobytes())
    digest.update(repr([(layer.name, layer.active_render) for layer in mesh.uv_layers]).encode())
    return digest.hexdigest()


def _keep_slot(mesh, slot: int):
    """Leave only the faces of material slot `slot` (the others' UVs may overlap them)."""
    index = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("material_index", index)
    if len(mesh.materials) <= 1 or (np.clip(index, 0, len(mesh.materials) - 1) == slot).all():
        return
    import bmesh

    bm = bmesh.new()
    bm.from_mesh(mesh)
    last = len(mesh.materials) - 1
    bmesh.ops.delete(bm, geom=[f for f in bm.faces if min(f.material_index, last) != slot], context="FACES")
    bm.to_mesh(mesh)
    bm.free()


def _emit_input(tree, socket, image):
    """In a copy of the material's tree: what reaches `socket` (the original's input) into an
    Emission shader of strength 1 on the only active Material Output, and `image` the active
    Image Texture node (where the bake writes)."""
    node = tree.nodes[socket.node.name]
    source = next(s for s in node.inputs if s.identifier == socket.identifier).links[0].from_socket
    emission = tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 1.0
    tree.links.new(source, emission.inputs["Color"])
    output = tree.nodes.new("ShaderNodeOutputMaterial")
    output.target = "ALL"
    tree.links.new(emission.outputs["Emission"], output.inputs["Surface"])
    for other in tree.nodes:
        if other.type == "OUTPUT_MATERIAL":
            other.is_active_output = other == output
    target = tree.nodes.new("ShaderNodeTexImage")
    target.image = image
    tree.nodes.active = target
