"""Helpers for the Blender-layer tests (real bpy): scene building, pixel read-back, and an
independent export of a Blender scene to OBJ+MTL and a TOML scene file for `thurston render`."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np

W, H = 48, 27


def bpy():
    import bpy as _bpy

    return _bpy


def fresh_scene(space="torus", scale=1.0, size=(W, H)):
    """An empty factory scene with tiny, draft-quality Thurston settings."""
    b = bpy()
    b.ops.wm.read_factory_settings(use_empty=True)
    sc = b.context.scene
    sc.render.resolution_x, sc.render.resolution_y = size
    sc.render.resolution_percentage = 100
    sc.thurston.space = space
    sc.thurston.scale = scale
    sc.thurston.quality = "draft"
    sc.thurston.threads = 2
    return sc


def link(obj):
    bpy().context.scene.collection.objects.link(obj)
    return obj


def material(name, color=(0.8, 0.8, 0.8), emission=(0, 0, 0), strength=1.0, kind="principled"):
    b = bpy()
    mat = b.data.materials.new(name)
    if mat.node_tree is None:  # Blender 5 gives new materials a node tree
        mat.use_nodes = True
    nodes = mat.node_tree.nodes
    if kind == "principled":
        p = nodes["Principled BSDF"]
        p.inputs["Base Color"].default_value = (*color, 1.0)
        p.inputs["Emission Color"].default_value = (*emission, 1.0)
        p.inputs["Emission Strength"].default_value = strength
    else:  # an Emission shader feeding the output
        for n in list(nodes):
            if n.type != "OUTPUT_MATERIAL":
                nodes.remove(n)
        e = nodes.new("ShaderNodeEmission")
        e.inputs["Color"].default_value = (*emission, 1.0)
        e.inputs["Strength"].default_value = strength
        mat.node_tree.links.new(e.outputs["Emission"], nodes["Material Output"].inputs["Surface"])
    return mat


def box(name, size, location, color=(0.8, 0.8, 0.8), emission=(0, 0, 0), strength=1.0, rotation=(0, 0, 0)):
    """A box mesh built from data (no operator): size (x, y, z) or a number."""
    b = bpy()
    sx, sy, sz = (size,) * 3 if np.isscalar(size) else size
    V = [(x * sx / 2, y * sy / 2, z * sz / 2) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    F = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh = b.data.meshes.new(name)
    mesh.from_pydata(V, [], F)
    mesh.update()
    obj = b.data.objects.new(name, mesh)
    obj.location = location
    obj.rotation_euler = rotation
    obj.data.materials.append(material(name, color, emission, strength))
    return link(obj)


def light_object(kind, name, location, rotation=(0.0, 0.0, 0.0), **props):
    """A light of `kind` (POINT, SPOT, AREA, SUN) with the given light data properties."""
    data = bpy().data.lights.new(name, kind)
    for key, value in props.items():
        setattr(data, key, value)
    obj = bpy().data.objects.new(name, data)
    obj.location, obj.rotation_euler = location, rotation
    return link(obj)


def point_light(location, energy=10.0, color=(1, 1, 1), name="Light"):
    b = bpy()
    data = b.data.lights.new(name, "POINT")
    data.energy = energy
    data.color = color
    obj = b.data.objects.new(name, data)
    obj.location = location
    return link(obj)


def camera(location=(0, 0, 0), rotation=(math.pi / 2, 0, 0), lens=50.0, name="Camera"):
    """Default rotation: looking along +Y with +Z up."""
    b = bpy()
    data = b.data.cameras.new(name)
    data.lens = lens
    obj = b.data.objects.new(name, data)
    obj.location = location
    obj.rotation_euler = rotation
    link(obj)
    b.context.scene.camera = obj
    b.context.view_layer.update()
    return obj


def image_pixels(image):
    """RGBA float pixels of an image datablock, rows top-down."""
    w, h = image.size
    p = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(p)
    return p.reshape(h, w, 4)[::-1]


def read_exr(path):
    """{channel name: (H, W) array} over all parts of an EXR (Blender's multilayer EXRs are multi-part)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    out = {}
    try:
        k = 0
        while inp.seek_subimage(k, 0):
            spec = inp.spec()
            px = np.asarray(inp.read_image(oiio.FLOAT)).reshape(spec.height, spec.width, spec.nchannels)
            for c, name in enumerate(spec.channelnames):
                out[name] = px[..., c]
            k += 1
    finally:
        inp.close()
    return out


def rgb(channels, prefix=""):
    return np.stack([channels[prefix + c] for c in "RGB"], axis=-1)


def f12(scene, path):
    """Render with the THURSTON engine (F12) and write the result with all passes to a multilayer EXR."""
    b = bpy()
    scene.render.engine = "THURSTON"
    s = scene.render.image_settings
    s.media_type = "MULTI_LAYER_IMAGE"
    s.file_format = "OPEN_EXR_MULTILAYER"
    s.color_depth = "32"
    scene.render.filepath = str(path)
    b.ops.render.render(write_still=True)
    return read_exr(path)


# --- an independent export of the Blender scene to files the CLI reads --------------------------------
def _fmt(v):
    return " ".join(repr(float(x)) for x in v)


def material_values(obj):
    """Kd and Ke read straight from the node inputs the test set (independent of blender/export)."""
    mat = obj.active_material
    nodes = mat.node_tree.nodes
    p = nodes.get("Principled BSDF")
    if p is not None:
        kd = np.array(p.inputs["Base Color"].default_value[:3])
        ke = np.array(p.inputs["Emission Color"].default_value[:3]) * p.inputs["Emission Strength"].default_value
    else:
        e = next(n for n in nodes if n.type == "EMISSION")
        kd = np.zeros(3)
        ke = np.array(e.inputs["Color"].default_value[:3]) * e.inputs["Strength"].default_value
    return kd, ke


def scattering_lines(obj):
    """MTL lines of the Principled BSDF's roughness (Pr), metallic (Pm), specular IOR level (Ks, as
    Blender's importer reads its mean) and IOR (Ni), read straight from the node inputs; none for
    an Emission shader (it reflects nothing)."""
    p = obj.active_material.node_tree.nodes.get("Principled BSDF")
    if p is None:
        return []
    level = p.inputs["Specular IOR Level"].default_value
    return [
        f"Pr {p.inputs['Roughness'].default_value!r}",
        f"Pm {p.inputs['Metallic'].default_value!r}",
        f"Ks {level!r} {level!r} {level!r}",
        f"Ni {p.inputs['IOR'].default_value!r}",
    ]


def exported_names(scene):
    """Names of the mesh objects write_scene_files writes, in its order (the core's object numbers)."""
    return [obj.name for obj in scene.objects if obj.type == "MESH" and not obj.hide_render]


def write_scene_files(scene, folder: Path, scale: float):
    """OBJ+MTL (world vertices / scale, Kd, Ke, the Principled BSDF's scattering) of the scene's mesh
    objects, and a TOML scene file with
    the point lights (position / scale, power = energy / 4 pi^2 / scale^2) and the camera (position /
    scale, forward = -Z column, up = +Y column, horizontal fov from lens and sensor width)."""
    b = bpy()
    depsgraph = b.context.evaluated_depsgraph_get()
    obj_lines, mtl_lines = ["mtllib scene.mtl"], []
    base = 1
    for name in exported_names(scene):
        obj = scene.objects[name]
        ev = obj.evaluated_get(depsgraph)
        mesh = ev.to_mesh()
        # in double precision, as the tracer takes them: where geodesics bend the core's hits are
        # sensitive to the last bits of the scene (see test_blender.CORE_FIND_ROOT_BUG)
        M = np.array(ev.matrix_world, float)
        co = np.array([v.co for v in mesh.vertices], float)
        Vw = co @ M[:3, :3].T + M[:3, 3]
        kd, ke = material_values(obj)
        mtl_lines += [f"newmtl m_{obj.name}", f"Kd {_fmt(kd)}", f"Ke {_fmt(ke)}", *scattering_lines(obj)]
        obj_lines += [f"o {obj.name}", f"usemtl m_{obj.name}"]
        obj_lines += [f"v {_fmt(v / scale)}" for v in Vw]
        obj_lines += ["f " + " ".join(str(base + i) for i in poly.vertices) for poly in mesh.polygons]
        base += len(Vw)
        ev.to_mesh_clear()
    (folder / "scene.obj").write_text("\n".join(obj_lines) + "\n")
    (folder / "scene.mtl").write_text("\n".join(mtl_lines) + "\n")
    toml = ["[[object]]", 'file = "scene.obj"']
    for obj in scene.objects:
        if obj.type == "LIGHT":
            pos = np.array(obj.matrix_world.translation, float) / scale
            power = obj.data.energy / (4 * math.pi**2) / scale**2  # radiant intensity x albedo / pi
            toml += [
                "[[light]]",
                f"position = [{', '.join(map(repr, map(float, pos)))}]",
                f"color = [{', '.join(map(repr, map(float, obj.data.color)))}]",
                f"power = {power!r}",
            ]
    cam = scene.camera
    M = np.array(cam.matrix_world, float)
    fov = math.degrees(cam.data.angle_x)  # Blender's own horizontal angle (float32, from lens and sensor width)
    toml += [
        "[camera]",
        f"position = [{', '.join(map(repr, map(float, M[:3, 3] / scale)))}]",
        f"forward = [{', '.join(map(repr, map(float, -M[:3, 2])))}]",
        f"up = [{', '.join(map(repr, map(float, M[:3, 1])))}]",
        f"fov = {fov!r}",
        f"shift = [{cam.data.shift_x!r}, {cam.data.shift_y!r}]",  # in widths under the default sensor fit
        f"clip_start = {cam.data.clip_start / scale!r}",
        f"clip_end = {cam.data.clip_end / scale!r}",
    ]
    (folder / "scene.toml").write_text("\n".join(toml) + "\n")
    return folder / "scene.toml"


# --- surfaces: textures, material slots, Cycles references of the tiled torus ---------------------
def lambert(mat):
    """A Principled BSDF reduced to its diffuse part (roughness 1, no specular), as the core shades."""
    p = mat.node_tree.nodes["Principled BSDF"]
    p.inputs["Roughness"].default_value = 1.0
    p.inputs["Specular IOR Level"].default_value = 0.0
    return mat


def image_texture_material(name, pixels):
    """A material whose Principled Base Color is an Image Texture of a new float (linear) image
    with the given RGBA pixels (rows top-down). Float, because Cycles interpolates a byte sRGB
    image before decoding it, and the core after."""
    b = bpy()
    h, w = pixels.shape[:2]
    image = b.data.images.new(name, w, h, float_buffer=True)
    image.pixels.foreach_set(np.ascontiguousarray(pixels[::-1], np.float32).ravel())
    mat = lambert(material(name))
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    mat.node_tree.links.new(tex.outputs["Color"], mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    return mat, image


# A 2x2 linear RGBA checker, top row first (the surface tests' texture).
CHECKER = np.array([[[0.9, 0.1, 0.1, 1], [0.1, 0.8, 0.2, 1]], [[0.2, 0.3, 0.9, 1], [0.9, 0.9, 0.2, 1]]], np.float32)


def floor_under_lamp(size=(48, 27)):
    """A floor slab and two walls spanning the torus's cross-sections (in the cover: a corridor along
    y, repeated), a lamp 0.65 above the floor in plain view, seen from above; Standard view
    transform, standard quality. What lights a point of the corridor: the lamp's copies along it,
    one per cell (nearest-copy lighting left the floor black: the lamp's nearest copy lies below it)."""
    sc = fresh_scene("torus", size=size)
    sc.view_settings.view_transform = "Standard"
    sc.thurston.quality = "standard"
    for name, box_size, location in (
        ("Floor", (1.0, 1.0, 0.02), (0.0, 0.0, -0.26)),
        ("Left", (0.02, 1.0, 1.0), (-0.4, 0.0, 0.0)),
        ("Right", (0.02, 1.0, 1.0), (0.45, 0.0, 0.0)),
    ):
        lambert(box(name, box_size, location, color=(0.7, 0.7, 0.7)).active_material)
    lamp = point_light((0.05, 0.1, 0.39), energy=3.0)
    lamp.data.shadow_soft_size = 0.0
    camera((0.0, -0.35, 0.15), rotation=(math.radians(55), 0, 0), lens=20)
    return sc


def tile_torus_for_cycles(scene, cells=7, own_cell_light=False):
    """The torus [-0.5, 0.5]^3 unrolled for Cycles: the cells^3 translated copies of every mesh and
    light (linked duplicates, cells odd), every light copy lighting everything, as in the universal
    cover: exact for points of the central cell as far as the light from beyond (cells - 1) / 2
    cells away does not count (a light reach). With own_cell_light each light copy lights only its
    own cell's objects (light linking): a light reach that holds only a point's own cell's copy."""
    b = bpy()
    originals = [o for o in scene.objects if o.type in ("MESH", "LIGHT")]
    steps = np.arange(cells) - cells // 2
    for k, offset in enumerate(np.stack(np.meshgrid(*[steps] * 3, indexing="ij"), -1).reshape(-1, 3)):
        cell = b.data.collections.new(f"cell {k}")
        scene.collection.children.link(cell)
        for o in originals:
            copy = o if not offset.any() else o.copy()
            if copy is not o:
                copy.location = np.array(o.location) + offset
            cell.objects.link(copy)
            if copy is o:
                scene.collection.objects.unlink(o)
        if own_cell_light:
            for light in [o for o in cell.objects if o.type == "LIGHT"]:
                light.light_linking.receiver_collection = cell
    b.context.view_layer.update()


def cycles_render(scene, path, samples=32):
    """Cycles, direct light only, CPU, after f12 (whose multilayer EXR settings stay)."""
    b = bpy()
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.max_bounces = 0
    scene.cycles.use_denoising = False
    scene.render.filepath = str(path)
    b.ops.render.render(write_still=True)
    return read_exr(path)


def interior(mask):
    """The mask without its border pixels (silhouettes are anti-aliased differently)."""
    m = mask.copy()
    m[1:] &= mask[:-1]
    m[:-1] &= mask[1:]
    m[:, 1:] &= mask[:, :-1]
    m[:, :-1] &= mask[:, 1:]
    return m


THURSTON = Path(sys.executable).with_name("thurston")


def render_blend(blend, out, *options: str, frames: str = "1") -> subprocess.CompletedProcess:
    """`thurston render-blend` on a saved .blend file, in a child process, as a user runs it."""
    argv = [str(THURSTON), "render-blend", str(blend), "--frames", frames, "--out", str(out), *map(str, options)]
    return subprocess.run(argv, capture_output=True, text=True, timeout=120)
