"""Blender -> Thurston: the space, the scene (from the evaluated depsgraph), the camera and the
render settings. Only translation happens here; everything else lives in the Blender-free layers."""
from __future__ import annotations

import math
import os

import bpy
import numpy as np

from .. import properties, render, scene as scenes, spaces
from . import surfaces

GUIDE_TAG = "thurston_guide"
_space_cache: dict = {}


class ExportError(ValueError):
    """Something in the Blender scene that cannot be rendered; the message says what to fix."""


def load_space(settings) -> spaces.Space:
    """The space chosen in the settings (by id), cached by file path and modification time."""
    if settings.space_id == properties.FILE:
        if not settings.space_file:
            raise ExportError("Space is set to a space file, but no file is chosen")
        path = bpy.path.abspath(settings.space_file)
    else:
        path = spaces.preset_path(settings.space_id)
        if path is None:
            dirs = ", ".join(str(d) for d in spaces.preset_dirs())
            raise ExportError(f"space preset {settings.space_id!r} not found (searched {dirs}): "
                              f"restore its file, or choose another space")
    try:
        key = (str(path), os.path.getmtime(path))
    except OSError:
        raise ExportError(f"space file {str(path)!r} cannot be read") from None
    if key not in _space_cache:
        try:
            _space_cache[key] = spaces.load(key[0])
        except spaces.SpaceError as exc:
            raise ExportError(str(exc)) from None
    return _space_cache[key]


def render_settings(settings, width: int, height: int, projection: str = "perspective") -> render.Settings:
    return render.Settings(
        width=width, height=height, projection=projection, quality=settings.quality, shading=settings.shading,
        # the panel's distances are in Blender units; the tracer's in chart units
        max_distance=settings.max_distance / settings.scale or None,
        max_crossings=None if settings.max_crossings < 0 else settings.max_crossings,
        fog=settings.fog / settings.scale or None, threads=settings.threads,
        tolerance=settings.tolerance / settings.scale or None)


def _is_guide(obj) -> bool:
    return bool(obj.get(GUIDE_TAG)) or any(c.get(GUIDE_TAG) for c in obj.users_collection)


def _render_disabled(obj, hidden_collections) -> bool:
    """Disabled in renders: the object, or every collection it is in (directly or by a parent)."""
    return obj.hide_render or (bool(obj.users_collection) and all(c in hidden_collections for c in obj.users_collection))


def _hidden_collections(bscene):
    """Collections whose contents Blender does not render: hide_render on them or on a parent,
    or excluded from the view layer."""
    hidden = set()

    def walk(coll, parent_hidden):
        h = parent_hidden or coll.hide_render
        if h:
            hidden.add(coll)
        for child in coll.children:
            walk(child, h)

    walk(bscene.collection, False)

    def excluded(layer_coll):
        if layer_coll.exclude:
            hidden.add(layer_coll.collection)
            hidden.update(layer_coll.collection.children_recursive)
        for child in layer_coll.children:
            excluded(child)

    for view_layer in bscene.view_layers[:1]:
        excluded(view_layer.layer_collection)
    return hidden


def export_scene(depsgraph, scale: float, notes: list[str]) -> scenes.Scene:
    """Mesh objects and instances (modifiers applied, world matrices), materials and point lights,
    in chart coordinates (world / scale). Skipped things are described in `notes`."""
    scene = scenes.Scene()
    skipped: dict[str, list[str]] = {}
    hidden_collections = _hidden_collections(depsgraph.scene.original)
    for inst in depsgraph.object_instances:
        obj = inst.object
        original = obj.original
        if _is_guide(original) or _render_disabled(original, hidden_collections):
            continue
        if inst.is_instance and inst.parent.original.type not in ("MESH", "EMPTY"):
            continue  # geometry of a curve, text, ... object: skipped (and noted) as that object
        if obj.type == "MESH":
            try:
                mesh = surfaces.mesh_object(inst, obj, scale)
            except scenes.SceneError as exc:
                raise ExportError(str(exc)) from None
            if mesh is None:
                skipped.setdefault("no faces", []).append(original.name)
                continue
            scene.objects.append(mesh)
        elif obj.type == "LIGHT":
            light = obj.data
            if light.type != "POINT":
                skipped.setdefault(f"{light.type.lower()} lights (only point lights)", []).append(original.name)
                continue
            pos = np.array(inst.matrix_world.translation, float) / scale
            # Blender's power (W) radiates over 4 pi sr, and a Lambert surface of albedo rho sends
            # rho / pi of its irradiance back (as Cycles does); chart distances are world / scale
            intensity = light.energy * 2.0 ** getattr(light, "exposure", 0.0) / (4 * math.pi**2) / scale**2
            scene.lights.append(scenes.PointLight(pos, np.array(light.color[:3], float), intensity))
        elif obj.type not in ("CAMERA", "EMPTY"):
            skipped.setdefault(f"{obj.type.lower()} objects (only meshes)", []).append(original.name)
    for what, names in skipped.items():
        shown = ", ".join(sorted(set(names))[:5]) + (" ..." if len(set(names)) > 5 else "")
        notes.append(f"skipped {what}: {shown}")
    return scene


def export_camera(bscene, depsgraph, scale: float, width: int, height: int, camera_object=None) -> scenes.Camera:
    """The scene camera as evaluated in this depsgraph (animated cameras move with the frame)."""
    cam = camera_object or bscene.camera
    if cam is None:
        raise ExportError("the scene has no camera: add one (Add > Camera) and make it the scene camera")
    cam = cam.evaluated_get(depsgraph)
    M = np.array(cam.matrix_world, float)
    position = M[:3, 3] / scale
    forward, up = -M[:3, 2], M[:3, 1]
    data = cam.data
    if data.type != "PERSP":
        raise ExportError(f"camera {cam.name!r} is {data.type.lower()}; only perspective cameras are supported")
    # Blender's angle spans the larger image side under AUTO sensor fit
    fit = data.sensor_fit
    if fit == "VERTICAL" or (fit == "AUTO" and height > width):
        fov = 2 * math.atan(math.tan(data.angle / 2) * width / height)
    else:
        fov = data.angle
    return scenes.Camera(position, forward, up, math.degrees(fov))


def resolution(bscene) -> tuple[int, int]:
    r = bscene.render
    return max(1, r.resolution_x * r.resolution_percentage // 100), max(1, r.resolution_y * r.resolution_percentage // 100)


def collect(context_scene, depsgraph, width=None, height=None, projection="perspective", camera_object=None):
    """Everything a render needs: (space, scene, camera, settings, notes)."""
    settings = context_scene.thurston
    space = load_space(settings)
    w, h = (width, height) if width else resolution(context_scene)
    notes: list[str] = []
    scene = export_scene(depsgraph, settings.scale, notes)
    if not scene.objects:
        raise ExportError("nothing to render: the scene has no visible mesh objects (the domain guide does not count)")
    camera = export_camera(context_scene, depsgraph, settings.scale, w, h, camera_object)
    rs = render_settings(settings, w, h, projection)
    return space, scene, camera, rs, notes


def blender_passes(result: render.Result, scale: float) -> dict:
    """Passes in Blender's units: depth and position in world units (chart units x scale)."""
    passes = dict(result.passes)
    passes["depth"] = passes["depth"] * scale
    passes["position"] = passes["position"] * scale
    return passes


def index_pass(result: render.Result, scene) -> np.ndarray:
    """Blender's IndexOB: each object's pass_index where it is seen, 0 where nothing is hit."""
    lookup = np.array([o.pass_index for o in scene.objects] + [0], np.float32)  # object -1 -> the 0 at the end
    return lookup[result.passes["object"]]


def store_stats(settings, result: render.Result):
    s = settings.stats
    st = result.stats
    s.valid = True
    s.seconds, s.rays, s.crossings_per_ray = st["seconds"], st["rays"], st["crossings_per_ray"]
    s.footprint, s.geodesic_error = st["footprint"], st["geodesic_error"]
    s.chords_per_ray, s.bound, s.measured_error = st["chords_per_ray"], st["bound"], st["measured_error"]
    s.summary = result.summary()
