"""The domain guide: a wireframe of the fundamental domain, in its own collection, excluded from
export and from Blender's own renders."""
import bpy
import mathutils
import numpy as np

from . import export

COLLECTION = "Thurston Guide"
OBJECT = "Thurston Domain"


def _guide_collection(scene, create):
    coll = bpy.data.collections.get(COLLECTION)
    if coll is None and create:
        coll = bpy.data.collections.new(COLLECTION)
        coll[export.GUIDE_TAG] = True
        coll.hide_render = True
    if coll is not None and create and coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    return coll


def build(scene):
    """Create or update the guide object for the scene's current space and scale."""
    space = export.load_space(scene.thurston)
    V = space.domain.vertices * scene.thurston.scale
    edges = [(a, b) for a, b, _, _ in space.domain.edges]
    faces = [f.vertices for f in space.domain.faces]
    coll = _guide_collection(scene, create=True)
    obj = bpy.data.objects.get(OBJECT)
    mesh = bpy.data.meshes.new(OBJECT)
    mesh.from_pydata(V.tolist(), edges, faces)
    mesh.update()
    if obj is None:
        obj = bpy.data.objects.new(OBJECT, mesh)
        obj[export.GUIDE_TAG] = True
    else:
        old = obj.data
        obj.data = mesh
        if old.users == 0:
            bpy.data.meshes.remove(old)
    if obj.name not in coll.objects:
        coll.objects.link(obj)
    obj.display_type = "WIRE"
    obj.show_in_front = True
    obj.hide_render = True
    obj.hide_select = False
    obj["thurston_space"] = space.id
    return obj


def refresh(scene):
    """Update the guide after a space or scale change, if the scene has one."""
    if bpy.data.objects.get(OBJECT) is None:
        return
    try:
        build(scene)
    except export.ExportError:
        pass  # the panel shows the space error; the old guide stays until the space is valid


class THURSTON_OT_domain_guide(bpy.types.Operator):
    """Add (or update) a wireframe of the fundamental domain to model inside"""

    bl_idname = "thurston.domain_guide"
    bl_label = "Add Domain Guide"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        try:
            obj = build(context.scene)
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
            moved = inside_matrix(space, np.array(cam.matrix_world, float), scene.thurston.scale)
        except (export.ExportError, ValueError) as exc:
            self.report({"ERROR"}, f"camera {cam.name!r}: {exc}")
            return {"CANCELLED"}
        cam.matrix_world = mathutils.Matrix(moved.tolist())
        return {"FINISHED"}


def inside_matrix(space, M, scale):
    """A camera matrix moved into the domain: position by the pairing isometry, axes by its
    differential (re-orthonormalised in the chart, where Blender shows the camera)."""
    g = space.geometry
    p = M[:3, 3] / scale
    if not g.in_chart(p):
        raise ValueError(f"camera position {p.tolist()} is not a point of {g.name}")
    X = g.to_model(p)
    if not space.domain.contains(X):
        X2, _, A = space.bring_inside(X)
        p2 = g.to_chart(X2)
        axes = []
        for k in range(3):
            V = A @ g.tangent_to_model(p, M[:3, k])
            axes.append(g.tangent_to_chart(X2, V))
        R = np.stack(axes, axis=1)
        U, _, Vt = np.linalg.svd(R)
        M = M.copy()
        M[:3, :3] = (U @ Vt) * np.linalg.norm(M[:3, :3], axis=0)
        M[:3, 3] = p2 * scale
    return M


def camera_outside(scene) -> bool:
    cam = scene.camera
    if cam is None:
        return False
    try:
        space = export.load_space(scene.thurston)
    except export.ExportError:
        return False
    g = space.geometry
    p = np.array(cam.matrix_world.translation, float) / scene.thurston.scale
    return not (g.in_chart(p) and space.domain.contains(g.to_model(p)))


CLASSES = (THURSTON_OT_domain_guide, THURSTON_OT_camera_inside)
