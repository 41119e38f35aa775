"""Operators on the domain guide, the scale and the camera: Add Domain Guide, Fit Scale, Bring
Camera Inside."""

import bpy
import mathutils
import numpy as np

from .. import checks
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
    """Move the scene camera into the fundamental domain through the face pairings (the view is the same)"""

    bl_idname = "thurston.camera_inside"
    bl_label = "Bring Camera Inside"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        scene = context.scene
        cam = scene.camera
        if cam is None:
            self.report({"ERROR"}, "The scene has no camera")
            return {"CANCELLED"}
        try:
            space = export.load_space(scene.thurston)
            moved = domain_guide.inside_matrix(space, np.array(cam.matrix_world, float), scene.thurston.scale)
        except (export.ExportError, ValueError) as exc:
            self.report({"ERROR"}, f"camera {cam.name!r}: {exc}")
            return {"CANCELLED"}
        cam.matrix_world = mathutils.Matrix(moved.tolist())
        return {"FINISHED"}


class THURSTON_OT_fit_scale(bpy.types.Operator):
    """Set the scale so that the scene's objects fit the fundamental domain (their copies do not overlap)"""

    bl_idname = "thurston.fit_scale"
    bl_label = "Fit Scale"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        settings = context.scene.thurston
        try:
            space = export.load_space(settings)
            world = export.export_scene(context.evaluated_depsgraph_get(), 1.0, [])  # Blender units
        except export.ExportError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if not world.objects:
            self.report({"ERROR"}, "The scene has no visible mesh objects to fit")
            return {"CANCELLED"}
        V = np.vstack([o.vertices for o in world.objects])
        size = float(np.linalg.norm(np.ptp(V, axis=0)))
        if size == 0:
            self.report({"ERROR"}, "The scene's objects have no extent to fit")
            return {"CANCELLED"}
        settings.scale = checks.fit_scale(space, size)
        self.report({"INFO"}, f"Scale set to {settings.scale:.4g} Blender units per chart unit")
        return {"FINISHED"}


CLASSES = (THURSTON_OT_domain_guide, THURSTON_OT_fit_scale, THURSTON_OT_camera_inside)
