"""Operators on the domain guide and the camera: Add Domain Guide, Bring Camera Inside."""
import bpy
import mathutils
import numpy as np

from .. import export, guide


class THURSTON_OT_domain_guide(bpy.types.Operator):
    """Add (or update) a wireframe of the fundamental domain to model inside"""

    bl_idname = "thurston.domain_guide"
    bl_label = "Add Domain Guide"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        try:
            obj = guide.build(context.scene)
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
            moved = guide.inside_matrix(space, np.array(cam.matrix_world, float), scene.thurston.scale)
        except (export.ExportError, ValueError) as exc:
            self.report({"ERROR"}, f"camera {cam.name!r}: {exc}")
            return {"CANCELLED"}
        cam.matrix_world = mathutils.Matrix(moved.tolist())
        return {"FINISHED"}


CLASSES = (THURSTON_OT_domain_guide, THURSTON_OT_camera_inside)
