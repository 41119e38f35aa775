"""Operators on the domain guide, the scale and the camera: Add Domain Guide, Fit Scale, Bring
Camera Inside."""

import bpy
import mathutils
import numpy as np

from .. import checks, render
from ..blender import domain_guide, export


class THURSTON_OT_domain_guide(bpy.types.Operator):
    """Add (or update) a wireframe of the fundamental domain to model inside"""

    bl_idname = "thurston.domain_guide"
    bl_label = "Add Domain Guide"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        try:
            obj = domain_guide.build(context.scene)
        except export.ExportError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Domain guide: {len(obj.data.vertices)} vertices, {len(obj.data.edges)} edges")
        return {"FINISHED"}


class THURSTON_OT_camera_inside(bpy.types.Operator):
    """Move the scene camera into the fundamental domain through the face pairings: the same point
    of the space, the same view (a constrained camera's constraints are muted to keep it)"""

    bl_idname = "thurston.camera_inside"
    bl_label = "Bring Camera Inside"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        scene = context.scene
        cam = scene.camera
        if cam is None:
            self.report({"ERROR"}, "The scene has no camera")
            return {"CANCELLED"}
        if export.camera_animated(cam):
            self.report(
                {"ERROR"},
                f"camera {cam.name!r} is animated: its keyframes or drivers set where it is, so it cannot "
                "be moved (renders are the same with the camera outside the domain)",
            )
            return {"CANCELLED"}
        # the view the render sees: the evaluated matrix, after constraints and parents
        seen = np.array(cam.evaluated_get(context.evaluated_depsgraph_get()).matrix_world, float)
        try:
            space = export.load_space(scene.thurston)
            moved = domain_guide.inside_matrix(space, seen, scene.thurston.scale)
        except (export.ExportError, ValueError) as exc:
            self.report({"ERROR"}, f"camera {cam.name!r}: {exc}")
            return {"CANCELLED"}
        if moved is seen:
            return {"FINISHED"}  # inside already
        muted = export.camera_constraints(cam)
        for c in muted:  # they would turn or move it away from the view it had
            c.enabled = False
        cam.matrix_world = mathutils.Matrix(moved.tolist())
        if muted:
            names = ", ".join(repr(c.name) for c in muted)
            self.report({"INFO"}, f"Camera brought inside; its constraints {names} muted to keep the view")
        return {"FINISHED"}


def _scene_box(world, lights, light_names=frozenset()) -> tuple[np.ndarray, np.ndarray]:
    """The box (lo, hi) of the scene's objects (every placement) but the lights' own (`light_names`:
    a light's sphere) and its lights' positions."""
    V = np.vstack(
        [
            o.vertices if o.instances is None else np.vstack([o.vertices @ A[:3, :3].T + A[:3, 3] for A in o.instances])
            for o in world.objects
            if o.name not in light_names
        ]
        + [np.array(lights, float).reshape(-1, 3)]
    )
    return V.min(axis=0), V.max(axis=0)


def _move_scene(scene, offset):
    """Move the scene's top-level objects (those without a parent: meshes, lights, the camera, ...)
    but the domain guide by `offset` (Blender units), so its composition stays as modelled."""
    for obj in scene.objects:
        if obj.parent is None and not export.is_guide(obj):
            obj.location = mathutils.Vector(obj.location) + mathutils.Vector(offset.tolist())


class THURSTON_OT_fit_scale(bpy.types.Operator):
    """Set the scale so that the scene's objects fit the fundamental domain (their copies do not
    overlap); in a shell, also move the scene to the domain's centre; and set the exposure that shows
    the lit surfaces neither black nor white, measured by a small render"""

    bl_idname = "thurston.fit_scale"
    bl_label = "Fit Scale"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        scene = context.scene
        settings = scene.thurston
        try:
            space = export.load_space(settings)
            world = export.export_scene(context.evaluated_depsgraph_get(), 1.0, [])  # Blender units
        except export.ExportError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if not world.objects:
            self.report({"ERROR"}, "The scene has no visible mesh objects to fit")
            return {"CANCELLED"}
        lamps = [o for o in scene.objects if o.type == "LIGHT" and o.visible_get()]
        lights = [o.matrix_world.translation for o in lamps]
        # a light with a radius is exported as an emitting sphere: fitted as the point it is about
        named = {o.name for o in lamps} | {o.data.name for o in lamps}
        lo, hi = _scene_box(world, lights, named)
        size = float(np.linalg.norm(hi - lo))
        if size == 0:
            self.report({"ERROR"}, "The scene has no extent to fit")
            return {"CANCELLED"}
        points = lights + ([scene.camera.matrix_world.translation] if scene.camera else [])
        settings.scale, offset = checks.fit(space, (lo, hi), points)
        done = [f"Scale set to {settings.scale:.4g} Blender units per chart unit"]
        if np.any(np.abs(offset) > 1e-9 * (1 + size)):
            _move_scene(scene, offset)
            done.append("the scene moved by (" + ", ".join(f"{v:.3g}" for v in offset) + ") to the domain's centre")
        context.view_layer.update()
        if scene.camera is not None:
            try:
                stops = export.measure_exposure(scene, context.evaluated_depsgraph_get())
            except (ValueError, render.RenderError) as exc:  # ExportError, a camera no point of the space
                stops = None
                done.append(f"the light not measured ({exc})")
            if stops is not None:
                scene.view_settings.exposure = stops
                done.append(f"exposure set to {stops:+.2f} stops (the lights' power unchanged)")
        self.report({"INFO"}, "; ".join(done))
        return {"FINISHED"}


class THURSTON_OT_set_exposure(bpy.types.Operator):
    """Set Color Management's exposure to the one the last render proposed: the lit surfaces at mid
    grey, the lights' power unchanged"""

    bl_idname = "thurston.set_exposure"
    bl_label = "Set Exposure"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        scene = context.scene
        notes = [n for n in scene.thurston.stats.notes if n.kind == checks.EXPOSURE]
        if not notes:
            self.report({"ERROR"}, "The last render proposed no exposure")
            return {"CANCELLED"}
        scene.view_settings.exposure = notes[0].value
        self.report({"INFO"}, f"Exposure set to {notes[0].value:+.2f} stops")
        return {"FINISHED"}


CLASSES = (THURSTON_OT_domain_guide, THURSTON_OT_fit_scale, THURSTON_OT_camera_inside, THURSTON_OT_set_exposure)
