"""Blender -> Thurston: the space, the scene (from the evaluated depsgraph), the camera and the
render settings. Only translation happens here; everything else lives in the Blender-free layers."""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import replace

import bpy
import numpy as np

from ... import checks, render, scenes, spaces
from ...passes import BLENDER_PASSES, LENGTHS, BlenderPass
from . import bake, hair, ignored, lamps, surfaces

GUIDE_TAG = "thurston_guide"
FILE = "FILE"  # space_id of a user's space file (space_file)
NAMED = "NAMED"  # space_id of a space by its name (space_name): a family's member or snappy:NAME
_space_cache: dict = {}


class ExportError(ValueError):
    """Something in the Blender scene that cannot be rendered; the message says what to fix."""


def load_space(settings) -> spaces.Space:
    """The space chosen in the settings (by id), cached by file path and modification time."""
    if settings.space_id == FILE:
        if not settings.space_file:
            raise ExportError("Space is set to a space file, but no file is chosen")
        path = bpy.path.abspath(settings.space_file)
    elif settings.space_id == NAMED:
        name = settings.space_name.strip()
        if not name:
            raise ExportError("Space is set to a named space, but no name is given (e.g. lens(7,2), snappy:m003(-3,1))")
        try:
            path = spaces.named_file(name)
        except spaces.SpaceError as exc:
            raise ExportError(str(exc)) from None
        if path is None:
            raise ExportError(
                f"{name!r} names no space: give a family's member such as lens(7,2) (`thurston spaces` "
                "lists the families) or snappy:NAME"
            )
    else:
        path = spaces.preset_path(settings.space_id)
        if path is None:
            dirs = ", ".join(str(d) for d in spaces.preset_dirs())
            raise ExportError(
                f"space preset {settings.space_id!r} not found (searched {dirs}): "
                f"restore its file, or choose another space"
            )
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


def render_settings(
    settings,
    width: int,
    height: int,
    projection: str = render.Settings.projection,
    region=None,
    transparent=False,
    viewport=False,
    quality=None,
    stereo=None,
) -> render.Settings:
    """The Blender settings as render.Settings: the render's sampling, or with `viewport` the
    rendered viewport's (Cycles' preview_* settings; it has no time limit); `quality` in place of
    the settings' (the Preview operator's)."""
    quality = quality or settings.quality
    prefix = "preview_" if viewport else ""
    # Samples (Cycles' Max Samples): 0 the quality's; the viewport's 0: the render's
    samples = (settings.preview_samples if viewport else 0) or settings.samples or None
    adaptive = getattr(settings, f"use_{prefix}adaptive_sampling")
    threshold = getattr(settings, f"{prefix}adaptive_threshold") if adaptive else 0.0
    # Min Samples above the samples per pixel: every pixel takes them all, as in Cycles
    most = samples or render.QUALITY[quality].samples
    min_samples = min(getattr(settings, f"{prefix}adaptive_min_samples"), most) if threshold else 0
    return render.Settings(
        width=width,
        height=height,
        projection=projection,
        quality=quality,
        shading=settings.shading,
        samples=samples,
        noise_threshold=threshold,
        min_samples=min_samples,
        time_limit=None if viewport else settings.time_limit or None,
        region=region,
        transparent=transparent,
        # the panel's distances are in Blender units; the tracer's in chart units
        max_distance=settings.max_distance / settings.scale or None,
        max_crossings=None if settings.max_crossings < 0 else settings.max_crossings,
        fog=settings.fog / settings.scale or None,
        light_reach=settings.light_reach / settings.scale or None,
        light_samples=settings.light_samples,
        light_paths=None if settings.light_paths < 0 else settings.light_paths,
        light_map=None if settings.light_map < 0 else settings.light_map,
        bounces=settings.bounces,
        threads=settings.threads,
        tolerance=settings.tolerance / settings.scale or None,
        denoise=settings.use_denoising,
        denoiser=blender_denoiser() if settings.use_denoising else None,
        stereo=stereo,
    )


# Blender's stereo convergence modes by the camera's names
CONVERGENCE_MODES = {"OFFAXIS": "off-axis", "PARALLEL": "parallel", "TOE": "toe-in"}


def export_stereo(bscene, camera_object) -> render.Stereo | None:
    """Output > Stereoscopy (Stereo 3D) with the camera's Stereoscopy settings; None where it is off."""
    r = bscene.render
    if not r.use_multiview:
        return None
    if r.views_format != "STEREO_3D":
        raise ExportError(
            "Output > Stereoscopy: Multi-View (a camera per view) is not supported; choose Stereo 3D, "
            "whose left and right eyes Thurston places along geodesics from the camera"
        )
    return camera_stereo(camera_object or bscene.camera, bscene.thurston.scale)


def camera_stereo(camera_object, scale: float) -> render.Stereo:
    """A camera's Stereoscopy settings (interocular and convergence distances, mode, pivot, pole
    merging) as render.Stereo, in chart units. Panoramic cameras take omni-directional stereo (as
    Cycles' spherical stereo), always."""
    st = camera_object.data.stereo
    return render.Stereo(
        interocular=st.interocular_distance / scale,
        convergence=st.convergence_distance / scale,
        mode=CONVERGENCE_MODES[st.convergence_mode],
        pivot=st.pivot.lower(),
        pole_merge=(math.degrees(st.pole_merge_angle_from), math.degrees(st.pole_merge_angle_to))
        if st.use_pole_merge
        else None,
    )


def views_of(bscene, stereo) -> list[str | None]:
    """The views a render makes: Stereoscopy's eyes that are in use, or the one view (None)."""
    if stereo is None:
        return [None]
    return [v.name for v in bscene.render.views if v.use and v.name in render.EYES]


def blender_denoiser() -> str | None:
    """The Open Image Denoise library Blender ships (lib/ beside Blender's version folder: the
    binary's; the bpy module's bpy/lib), which Blender has loaded already; None where there is none (the pyoidn
    binding is used then, where installed)."""
    import glob
    import os

    import bpy

    # Blender's version folder (resource_path LOCAL: 5.0/) lies beside its lib/ (the bpy module's too)
    local = os.path.normpath(bpy.utils.resource_path("LOCAL"))
    where = [os.path.dirname(local), os.path.dirname(bpy.app.binary_path or "")]
    for folder in where:
        if not folder:
            continue
        for pattern in ("libOpenImageDenoise.so*", "libOpenImageDenoise*.dylib", "OpenImageDenoise.dll"):
            found = sorted(glob.glob(os.path.join(folder, "lib", pattern)) + glob.glob(os.path.join(folder, pattern)))
            if found:
                return min(found, key=len)  # libOpenImageDenoise.so.2 before its versioned file
    return None


def is_guide(obj) -> bool:
    return bool(obj.get(GUIDE_TAG)) or any(c.get(GUIDE_TAG) for c in obj.users_collection)


def _render_disabled(inst, hidden_collections) -> bool:
    """Disabled in renders: the object, or every collection it is in (directly or by a parent). An
    instance is as visible as its instancer: a collection instance shows also when its source
    collection is excluded from the view layer (as in Cycles)."""
    obj = (inst.parent if inst.is_instance else inst.object).original
    return obj.hide_render or (
        bool(obj.users_collection) and all(c in hidden_collections for c in obj.users_collection)
    )


def _hidden_collections(view_layer):
    """Collections whose contents Blender does not render in this view layer: hide_render on them
    or on a parent, or excluded from the view layer."""
    hidden = set()

    def walk(layer_coll, parent_hidden):
        coll = layer_coll.collection
        h = parent_hidden or coll.hide_render or layer_coll.exclude
        if h:
            hidden.add(coll)
        for child in layer_coll.children:
            walk(child, h)

    walk(view_layer.layer_collection, False)
    return hidden


def export_scene(depsgraph, scale: float, notes: list[checks.Note], meshes: dict | None = None) -> scenes.Scene:
    """Mesh objects and instances (modifiers applied, world matrices), materials and point lights,
    in chart coordinates (world / scale). Skipped things are described in `notes`. `meshes`: the
    meshes read by an earlier export at the same scale, by surfaces.mesh_key, reused where the key
    comes again (the viewport keeps them while only transforms change); updated to this export's."""
    scene = scenes.Scene()
    skipped: dict[str, list[str]] = {}
    flat: list[str] = []  # objects and area lights scaled to 0 (on some axis)
    hidden_collections = _hidden_collections(depsgraph.view_layer)
    bake_size = bake.bake_size(depsgraph.scene)
    # Instances of one mesh share one scene object (surfaces.mesh_key): the mesh, read at the first
    # of them, and the chart maps of all.
    placements: dict[tuple, tuple[scenes.SceneObject | None, list[np.ndarray]]] = {}
    for inst in depsgraph.object_instances:
        obj = inst.object
        original = obj.original
        if is_guide(original) or _render_disabled(inst, hidden_collections):
            continue
        if inst.is_instance and inst.parent.original.type not in ("MESH", "EMPTY"):
            continue  # geometry of a curve, text, ... object: skipped (and noted) as that object
        if obj.type == "MESH" and inst.show_self:  # (a hair emitter may show its hair alone)
            key = surfaces.mesh_key(inst, obj)
            if key not in placements:
                if meshes is not None and key in meshes:
                    mesh = meshes[key]
                else:
                    try:
                        mesh = surfaces.mesh_object(inst, obj, scale, bake_size)
                    except scenes.SceneError as exc:
                        raise ExportError(str(exc)) from None
                placements[key] = (mesh, [])
                if mesh is None:
                    skipped.setdefault("no faces", []).append(original.name)
            chart = surfaces.chart_map(inst, scale)
            if scenes.singular(chart):  # as in Cycles, nothing of it shows
                flat.append(_instance_name(inst))
                continue
            placements[key][1].append(chart)
        elif obj.type == "LIGHT":
            light = obj.data
            if light.type == "SUN":
                skipped.setdefault(SUN_NOTE, []).append(original.name)
                continue
            if light.type == "AREA" and scenes.singular(np.array(inst.matrix_world, float)):
                flat.append(_instance_name(inst))  # no area: it emits nothing
                continue
            tint, not_constant = lamps.node_tint(light)
            if not_constant:
                skipped.setdefault(NODES_NOTE, []).append(f"{original.name} ({not_constant})")
            if light.type == "SPOT" and light.shadow_soft_size > 0:
                skipped.setdefault(SPOT_RADIUS_NOTE, []).append(original.name)
            try:
                light_objects = export_light(light, np.array(inst.matrix_world, float), scale, tint)
            except scenes.SceneError as exc:
                raise ExportError(f"light {original.name!r}: {exc}") from None
            for light_object in light_objects:
                if isinstance(light_object, scenes.SceneObject):
                    scene.objects.append(light_object)
                else:
                    scene.lights.append(light_object)
        if obj.type == "MESH" and not inst.is_instance and inst.show_particles:
            strands, thinned = hair.hair_objects(
                obj, scale, depsgraph.mode == "RENDER", lambda mat: surfaces.material(mat, original.name)
            )
            scene.objects.extend(strands)
            if thinned:
                skipped.setdefault(HAIR_THINNED_NOTE, []).extend(thinned)
        if obj.type == "CURVES":
            strands = hair.curves_object(inst, obj, scale, lambda mat: surfaces.material(mat, original.name))
            if strands is not None:
                scene.objects.append(strands)
        elif obj.type not in ("MESH", "LIGHT", "CAMERA", "EMPTY"):
            skipped.setdefault(f"{obj.type.lower()} objects (only meshes)", []).append(original.name)
    if meshes is not None:
        meshes.clear()
        meshes.update((key, mesh) for key, (mesh, _) in placements.items())
    for mesh, maps in placements.values():
        if mesh is None or not maps:  # no faces, or scaled to 0 wherever it is
            continue
        try:
            mesh.instances = scenes.checked_instances(np.array(maps), mesh.name)
        except scenes.SceneError as exc:
            raise ExportError(f"{exc}: give it a non-zero scale") from None
        if len(maps) == 1:  # used once: its vertices in the chart, as before instancing
            mesh = mesh.placed()
        scene.objects.append(mesh)
    for what, names in skipped.items():
        said = what if what in _NOT_SKIPPED else f"skipped {what}"
        notes.append(checks.Note(checks.DROPPED, f"{said}: {_shown(names)}"))
    if flat:
        frame = depsgraph.scene.frame_current
        notes.append(
            checks.Note(
                checks.SCALED_TO_ZERO,
                f"left out at frame {frame}, scaled to 0 (Cycles shows nothing of them either): {_shown(flat, repr)}",
            )
        )
    return scene


def _shown(names, form=str) -> str:
    names = sorted(set(names))
    return ", ".join(map(form, names[:5])) + (" ..." if len(names) > 5 else "")


def _instance_name(inst) -> str:
    name = inst.object.original.name
    return f"{name} ({inst.parent.original.name})" if inst.is_instance else name


def check_scale(space: spaces.Space, scene: scenes.Scene, scale: float, camera: scenes.Camera | None = None):
    """Refuse a Scale at which the scene spans more than checks.MAX_SPAN domains (a Scale of 0, which
    Blender keeps at its least, 1e-06, or one far too small), naming the setting and the Scale that
    fits the scene."""
    span, size = checks.scene_span(scene, camera), checks.domain_span(space)
    if span <= checks.MAX_SPAN * size:
        return
    fit = checks.fit_scale(space, checks.scene_span(scene) * scale)  # the objects and lights, as Blender units
    given = "0 (Blender keeps it at its least, 1e-06)" if scale < 2e-6 else f"{scale:.3g}"
    raise ExportError(
        f"Scale is {given}: at it the scene spans {span:.3g} chart units, {span / size:.3g} times the "
        f"domain, too far to bring into it; set Scale (Blender units per chart unit, in the Thurston "
        f"panel) to about {fit:.3g}, as Fit Scale does"
    )


# A sun is light from infinitely far away; a closed space has no such distance (every far light is
# a copy of a near one), so it is left out, and said so.
SUN_NOTE = (
    "sun lights (a closed space has no infinity for parallel light to come from: use a point, spot or area light)"
)


# Parts of lights rendered otherwise than Cycles renders them (named with their lights)
NODES_NOTE = (
    "light node trees that are not constant (textures, Light Falloff, ...) are ignored, those lights "
    "shine with the power and colour set on them"
)
SPOT_RADIUS_NOTE = (
    f"spot lights with a radius are {lamps.SPOT_POINTS} point spots spread through their sphere here: "
    f"their shadows soft in {lamps.SPOT_POINTS} steps"
)
HAIR_THINNED_NOTE = (
    f"hair systems of more than {hair.HAIR_STRANDS_MOST} strands show every k-th of them (as tubes, their "
    "radius unchanged)"
)
_NOT_SKIPPED = (NODES_NOTE, SPOT_RADIUS_NOTE, HAIR_THINNED_NOTE)


def export_light(light, world: np.ndarray, scale: float, tint=None) -> list:
    """A point or spot light (scenes.PointLight; with a radius: an emitting sphere, or point spots
    spread through it) or an area light (an emissive mesh, scenes.flat_light) as Cycles lights
    them, in chart units (world / scale), as a list. Point and spot: Blender's power (W) radiates
    over 4 pi sr, and a Lambert surface of albedo rho sends rho / pi of its irradiance back; a spot
    is that point light within Cycles' cone (spot size and blend; its axis the light's -Z).
    Area: a Lambertian emitter of power `strength` from one side, radiance strength / (pi area) as
    Cycles renders it (tests/blender/test_blender_lights.py; strength / pi where not normalized), area =
    size x size_y (times pi / 4 for a disk or ellipse) scaled by the object, emitted towards -Z."""
    tint = lamps.node_tint(light)[0] if tint is None else tint
    color = np.array(light.color[:3], float) * lamps.temperature_tint(light) * tint
    strength = light.energy * 2.0 ** getattr(light, "exposure", 0.0)
    position = world[:3, 3] / scale
    # (Cycles takes the radius as it is, whatever the object's scale)
    radius = light.shadow_soft_size / scale if light.type in ("POINT", "SPOT") else 0.0
    if light.type == "POINT" and radius > 0:
        return [lamps.sphere_light(light.name, position, radius, color, strength / scale**2)]
    if light.type in ("POINT", "SPOT"):
        spot = (
            {}
            if light.type == "POINT"
            else dict(spot_direction=-world[:3, 2], spot_size=light.spot_size, spot_blend=light.spot_blend)
        )
        power = strength / (4 * math.pi**2) / scale**2
        if radius > 0:
            return lamps.spot_points(position, radius, color, power, **spot)
        return [scenes.PointLight(position, color, power, **spot)]
    width = light.size
    height = light.size_y if light.shape in ("RECTANGLE", "ELLIPSE") else light.size
    disc = light.shape in ("DISK", "ELLIPSE")
    u, v = world[:3, 0] * width / 2, -world[:3, 1] * height / 2  # u x v along -Z: the side it lights
    area = 4 * np.linalg.norm(np.cross(u, v)) * (math.pi / 4 if disc else 1.0)
    normalized = getattr(light, "normalize", True)
    radiance = color * strength / math.pi / (area if normalized else 1.0)
    return [scenes.flat_light(light.name, position, u / scale, v / scale, radiance, disc=disc)]


def export_camera(bscene, depsgraph, scale: float, width: int, height: int, camera_object=None) -> scenes.Camera:
    """The scene camera as evaluated in this depsgraph (animated cameras move with the frame): its
    field of view by Blender's sensor fit, its lens shift and its clip distances."""
    cam = camera_object or bscene.camera
    if cam is None:
        raise ExportError("the scene has no camera: add one (Add > Camera) and make it the scene camera")
    cam = cam.evaluated_get(depsgraph)
    M = np.array(cam.matrix_world, float)
    position = M[:3, 3] / scale
    forward, up = -M[:3, 2], M[:3, 1]
    data = cam.data
    camera_projection(cam)  # refuses what cannot be rendered
    # Blender's angle spans the sensor-fit side (AUTO: the larger side); its lens shift is in units of
    # that side; the tracer's angle and shift are the width's
    fit = data.sensor_fit
    vertical = fit == "VERTICAL" or (fit == "AUTO" and height > width)
    fov = 2 * math.atan(math.tan(data.angle / 2) * width / height) if vertical else data.angle
    per_width = height / width if vertical else 1.0
    return scenes.Camera(
        position,
        forward,
        up,
        math.degrees(fov),
        shift=(data.shift_x * per_width, data.shift_y * per_width),
        clip_start=data.clip_start / scale,
        clip_end=data.clip_end / scale,
    )


def camera_projection(cam) -> str:
    """The projection of a Blender camera: perspective, or a whole-sphere equirectangular panorama."""
    data = cam.data
    if data.type == "PERSP":
        return "perspective"
    whole = (data.longitude_min, data.longitude_max, data.latitude_min, data.latitude_max)
    if data.type == "PANO" and data.panorama_type == "EQUIRECTANGULAR":
        if np.allclose(whole, (-math.pi, math.pi, -math.pi / 2, math.pi / 2), atol=1e-6):
            return "equirect"
        raise ExportError(
            f"camera {cam.name!r}: only the whole sphere of an equirectangular panorama is supported; set its "
            "longitude to -180..180 and latitude to -90..90 degrees"
        )
    kind = data.panorama_type.lower().replace("_", " ") + " panorama" if data.type == "PANO" else data.type.lower()
    raise ExportError(
        f"camera {cam.name!r} is {kind}; only perspective cameras and equirectangular panoramas are supported"
    )


def resolution(bscene) -> tuple[int, int]:
    r = bscene.render
    return max(1, r.resolution_x * r.resolution_percentage // 100), max(
        1, r.resolution_y * r.resolution_percentage // 100
    )


def border_region(bscene, width: int, height: int) -> tuple[int, int, int, int] | None:
    """The render border as a window (x, y, w, h) of the image, y from the top, by Blender's rule
    (the border's fractions times the size, truncated); None without a border."""
    r = bscene.render
    if not r.use_border:
        return None
    x0, x1 = int(r.border_min_x * width), int(r.border_max_x * width)
    y0, y1 = int(r.border_min_y * height), int(r.border_max_y * height)  # from the bottom
    if x1 <= x0 or y1 <= y0:
        raise ExportError("the render region is empty: draw a larger region (Ctrl+B) or clear it (Ctrl+Alt+B)")
    return x0, height - y1, x1 - x0, y1 - y0


# A camera outside the domain whose keyframes or drivers set where it is: Bring Camera Inside cannot
# move it (the animation puts it back), so its note offers no fix.
CAMERA_OUTSIDE_ANIMATED = "camera_outside_animated"

# Blender's fix for each kind of note: (operator, what to click).
FIXES = {
    checks.CAMERA_OUTSIDE: ("thurston.camera_inside", "Bring Camera Inside"),
    checks.SCENE_TOO_LARGE: ("thurston.fit_scale", "Fit Scale"),
    checks.SCENE_TOO_SMALL: ("thurston.fit_scale", "Fit Scale"),
    checks.EXPOSURE: ("thurston.set_exposure", "Set Exposure"),
}

_TRANSFORMS = ("location", "rotation_euler", "rotation_quaternion", "rotation_axis_angle", "scale", "delta_")


def _animated_paths(obj) -> list[str]:
    """The data paths of the object's keyframed or driven channels (its action's channel bag for
    its slot in Blender 4.4+, else the action's legacy F-curves; its drivers)."""
    anim = obj.animation_data
    if anim is None:
        return []
    curves = list(anim.drivers)
    action = anim.action
    if action is not None:
        try:
            from bpy_extras import anim_utils

            bag = anim_utils.action_get_channelbag_for_slot(action, anim.action_slot)
            curves += list(bag.fcurves) if bag is not None else []
        except (ImportError, AttributeError):
            curves += list(getattr(action, "fcurves", []))
    return [c.data_path for c in curves]


def camera_animated(cam) -> bool:
    """Whether keyframes or drivers set where the camera is or where it looks (its own transform)."""
    return any(path.startswith(_TRANSFORMS) for path in _animated_paths(cam))


def camera_constraints(cam) -> list:
    """The camera's constraints that take part in its transform (enabled, with influence)."""
    return [c for c in cam.constraints if c.enabled and c.influence > 0]


def _with_fix(note: checks.Note) -> checks.Note:
    fix = FIXES.get(note.kind)
    if fix is None:
        return note
    return checks.Note(note.kind, f"{note.message} ({fix[1]} in the Thurston panel does it)", note.value)


def _camera_note(note: checks.Note, cam) -> checks.Note:
    """The camera-outside note as Blender's camera allows its fix: none for an animated camera
    (its keyframes would put it back), and what the fix does to a constrained one."""
    if note.kind != checks.CAMERA_OUTSIDE or cam is None:
        return note
    if camera_animated(cam):
        return checks.Note(
            CAMERA_OUTSIDE_ANIMATED,
            f"{note.message}; camera {cam.name!r} is animated, so it stays where its keyframes put it "
            "(nothing to fix: the render is the same)",
        )
    constraints = camera_constraints(cam)
    if constraints:
        names = ", ".join(repr(c.name) for c in constraints)
        return checks.Note(
            note.kind, f"{note.message}; Bring Camera Inside keeps that view by muting its constraints ({names})"
        )
    return note


def _superseded(notes: list[checks.Note], caught: list[checks.Note]) -> list[checks.Note]:
    """The notes worth showing. A scene far larger than the domain (or, in a shell, around the
    chart's origin) explains the rest: its objects cut, the light hidden by their overlapping
    copies, the camera outside a domain of that scale. Its note alone is kept then (with what was
    skipped), so that its one fix, Fit Scale, comes first."""
    if not any(n.kind == checks.SCENE_TOO_LARGE for n in notes):
        return notes + caught
    return [n for n in notes if n.kind not in (checks.CAMERA_OUTSIDE, CAMERA_OUTSIDE_ANIMATED)]


# What a Lambert render shows in a space whose geometry finds no light paths: the normals (as the
# images of docs/graph.md)
PSEUDO_COLOUR = "normal"


def pseudo_colour(space: spaces.Space, scene: scenes.Scene, settings: render.Settings):
    """(scene, settings, notes) as the space renders them. A geometry whose point_lights is false
    (the graphs of Gaussians: the geodesics from a surface to a light have no closed form, and
    shooting for them per shaded point is far too slow) renders in the pseudo-colour shadings only:
    Lambert becomes PSEUDO_COLOUR and the lights are left out, said in one note. Elsewhere, or
    where nothing changes, all as given."""
    g = space.geometry
    lambert = settings.shading == "lambert"
    if g.point_lights or not (lambert or scene.lights):
        return scene, settings, []
    shown = f"the {PSEUDO_COLOUR} shading in place of Lambert" if lambert else f"the {settings.shading} shading"
    left_out = f", without the scene's {len(scene.lights)} light(s)" if scene.lights else ""
    others = ", ".join(s for s in render.SHADING if s != "lambert")
    note = checks.Note(
        ignored.IGNORED,
        f"{g.name} spaces render in pseudo-colour only: light paths are not found in this metric (its "
        f"geodesics to a light have no closed form), so the image shows {shown}{left_out} (Shading in "
        f"the Thurston panel picks another: {others})",
    )
    unlit = scenes.Scene(scene.objects, [], scene.camera)
    return unlit, replace(settings, shading=PSEUDO_COLOUR if lambert else settings.shading), [note]


class RenderJob:
    """A render of the Blender scene: exported, checked and compiled on the calling thread (Blender
    data is read there), traced by run() on any thread. `notes` gathers everything the user should
    hear about: what was skipped or cut, and the checks before and after the render."""

    def __init__(
        self,
        bscene,
        depsgraph,
        width=None,
        height=None,
        projection=None,
        camera_object=None,
        region=None,
        quality=None,
        stereo="scene",
    ):
        settings = bscene.thurston
        self.notes: list[checks.Note] = []
        self.space = load_space(settings)
        self.scale = settings.scale
        w, h = (width, height) if width else resolution(bscene)
        cam = camera_object or bscene.camera
        with warnings.catch_warnings(record=True) as caught:  # the scene's and the compiler's warnings
            warnings.simplefilter("always")
            self.scene = export_scene(depsgraph, settings.scale, self.notes)
            self.notes += ignored.settings_notes(bscene)
            # (a frame whose objects are all scaled to 0 renders empty, as in Cycles)
            if not self.scene.objects and not any(n.kind == checks.SCALED_TO_ZERO for n in self.notes):
                raise ExportError(
                    "nothing to render: the scene has no visible mesh objects (the domain guide does not count)"
                )
            self.camera = export_camera(bscene, depsgraph, settings.scale, w, h, camera_object)
            self.settings = render_settings(
                settings,
                w,
                h,
                projection or camera_projection(cam),
                region,
                bscene.render.film_transparent,
                quality=quality,
                # "scene": Output > Stereoscopy's; else the stereo given (None: one view)
                stereo=export_stereo(bscene, cam) if stereo == "scene" else stereo,
            )
            self.views = views_of(bscene, self.settings.stereo)
            self.scene, self.settings, unlit = pseudo_colour(self.space, self.scene, self.settings)
            self.notes += unlit
            check_scale(self.space, self.scene, self.scale, self.camera)
            try:  # here, so that the error names the camera object (an animated one, at this frame)
                render.camera_frame(self.space, self.camera)
            except render.RenderError as exc:
                raise ExportError(f"camera {(camera_object or bscene.camera).name!r}: {exc}") from None
            lambert = self.settings.shading == "lambert"
            self.notes += [
                _camera_note(n, cam) for n in checks.before_render(self.space, self.scene, self.camera, lambert)
            ]
            try:
                self.tracer = render.make_tracer(
                    self.space, self.scene, self.settings.threads, render.light_reach_for(self.space, self.settings)
                )
            except scenes.SceneError as exc:
                raise ExportError(str(exc)) from None
        # each warning once (an image missing in several materials is one note)
        self.notes = _superseded(
            self.notes, [checks.Note(checks.DROPPED, m) for m in dict.fromkeys(str(w.message) for w in caught)]
        )
        self.exposure = bscene.view_settings.exposure  # what Blender's colour management applies
        self.cancelled = False
        self.fraction = 0.0
        self.result: render.Result | None = None
        self.results: dict[str | None, render.Result] = {}
        self.error: Exception | None = None

    def progress(self, done, total):
        self.fraction = done / max(total, 1)
        return not self.cancelled

    def run(self, progress=None):
        """Trace every view; the results by view (and the first as `result`), or the exception
        (cancelled or failed), are kept for the main thread."""
        progress = progress or self.progress
        count = len(self.views)
        try:
            for k, view in enumerate(self.views):

                def report(done, total, k=k):
                    return progress(k * total + done, count * total)

                result = self.results[view] = render.render(
                    self.space,
                    self.scene,
                    replace(self.settings, eye=view),
                    camera=self.camera,
                    progress=report,
                    tracer=self.tracer,
                )
                if not any(n.kind == checks.SCENE_TOO_LARGE for n in self.notes):  # else the copies' overlap is why
                    lambert = self.settings.shading == "lambert"
                    self.notes += checks.after_render(self.scene, result.passes, lambert, self.exposure, result.stats)
            self.result = self.results[self.views[0]]
        except Exception as exc:
            self.error = exc

    def summary(self) -> str:
        return "; ".join((f"{view} eye: " if view else "") + result.summary() for view, result in self.results.items())

    def messages(self) -> list[str]:
        return [_with_fix(n).message for n in self.notes]


def blender_passes(passes: dict, scale: float) -> dict:
    """Passes in Blender's units: the lengths (depth, position) in world units (chart units x scale)."""
    passes = dict(passes)
    for name in LENGTHS:
        passes[name] = passes[name] * scale
    return passes


def combined(passes: dict) -> np.ndarray:
    """Blender's Combined pixels (h, w, 4) float32: the colour, premultiplied by the alpha."""
    return np.concatenate([np.nan_to_num(passes["color"]), passes["alpha"][..., None]], axis=-1).astype(np.float32)


NO_HIT_DEPTH = 1e10  # what Blender's depth passes hold where nothing is hit


def pass_enabled(view_layer, p: BlenderPass) -> bool:
    return getattr(view_layer.thurston if p.addon_flag else view_layer, p.flag)


def enable_pass(view_layer, p: BlenderPass):
    setattr(view_layer.thurston if p.addon_flag else view_layer, p.flag, True)


def pass_values(job: RenderJob, view=None) -> dict[str, np.ndarray]:
    """Each BLENDER_PASSES entry's pixels, (h, w, channels) float32, in Blender's conventions: world
    units; Depth along the camera's view axis (the geodesic distance times the cosine between the
    ray's initial direction and the optical axis), the geodesic distance as its own pass; the
    object's pass_index; NO_HIT_DEPTH where nothing is hit. `view`: the stereo eye's."""
    passes, scale = job.results[view].passes, job.scale
    hit = np.isfinite(passes["depth"])
    distance = np.where(hit, passes["depth"] * scale, NO_HIT_DEPTH)
    settings = replace(job.settings, eye=view)
    camera = job.camera if view is None else render.eye_camera(job.camera, settings)
    # Blender's Depth: along the view axis for cameras, the distance for panoramas (as Cycles)
    along_axis = (
        render.view_directions(camera, settings)[0] if render.PROJECTIONS[settings.projection].planar_clip else 1.0
    )
    pass_index = np.array([o.pass_index for o in job.scene.objects] + [0])  # object -1 (none): the 0 at the end
    values = {
        "Depth": np.where(hit, distance * along_axis, NO_HIT_DEPTH),
        "Geodesic Distance": distance,
        "Normal": np.nan_to_num(passes["normal"]),
        "Position": np.nan_to_num(passes["position"] * scale),
        "IndexOB": pass_index[passes["object"]],
        "Crossings": passes["crossings"],
        "Denoising Albedo": passes["albedo"],
        "Denoising Normal": passes["guide_normal"],
        "Noisy Image": np.nan_to_num(passes.get("noisy", passes["color"])),
    }
    return {
        p.name: np.asarray(values[p.name], np.float32).reshape(*values[p.name].shape[:2], -1) for p in BLENDER_PASSES
    }


def store_stats(settings, job: RenderJob):
    """The last render's statistics and notes, for the panel (and render-blend's output)."""
    s = settings.stats
    st = job.result.stats
    s.valid = True
    s.seconds, s.rays, s.crossings_per_ray = st["seconds"], st["rays"], st["crossings_per_ray"]
    s.footprint, s.geodesic_error = st["footprint"], st["geodesic_error"]
    s.chords_per_ray, s.bound, s.measured_error = st["chords_per_ray"], st["bound"], st["measured_error"]
    s.noise = -1.0 if st["noise"] is None else st["noise"]
    s.samples_mean, s.samples_max = st["samples_mean"], st["samples_max"]
    s.time_limit_reached = st["time_limit_reached"]
    s.denoised = bool(st.get("denoised"))
    s.summary = job.summary()
    store_notes(settings, job.notes)


def store_notes(settings, notes: list[checks.Note]):
    stored = settings.stats.notes
    stored.clear()
    for note in notes:
        item = stored.add()
        item.kind, item.message = note.kind, _with_fix(note).message
        item.value = 0.0 if note.value is None else note.value


MEASURE_SIZE = (64, 36)  # the measuring render of measure_exposure


def measure_exposure(bscene, depsgraph) -> float | None:
    """The exposure (stops) that shows the lit surfaces the scene camera sees at mid grey, measured
    by a small draft render (MEASURE_SIZE, one sample per pixel); None where the exposure already
    set shows them neither black nor white (checks.proposed_exposure), or where nothing lit shows."""
    job = RenderJob(bscene, depsgraph, *MEASURE_SIZE, quality="draft")
    job.settings = replace(job.settings, samples=1, noise_threshold=0.0, min_samples=0, denoise=False, denoiser=None)
    job.run()
    if job.error is not None:
        raise ExportError(f"measuring the light: {job.error}")
    return checks.proposed_exposure(job.scene, job.result.passes, bscene.view_settings.exposure)
