"""The domain guide: a wireframe of the fundamental domain, in its own collection, excluded from
export and from Blender's own renders; and the camera moved into the domain by the pairings."""

import bpy
import numpy as np

from . import export

COLLECTION = "Thurston Guide"
OBJECT = "Thurston Domain"
# Blender keeps matrices in float32: a camera that Bring Camera Inside put on a face may lie this far
# (relative) outside it once stored, and still counts as inside.
FLOAT32_SLACK = 1e-6


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
    V, edges, faces = space.guide_mesh()
    V = V * scene.thurston.scale
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


def inside_matrix(space, M, scale):
    """A camera matrix moved into the domain by the pairing isometry, with the same view. The tracer
    builds its frame by Gram-Schmidt in the metric from forward, right = forward x up and up (chart
    vectors): the moved camera looks along the image of forward under the differential D, and its up
    is the normal of the image of the forward-right plane (D^-T of that plane's normal), so that the
    tracer's frame there is D applied to the frame here, also where D is not a rotation (Nil, Sol)."""
    g = space.geometry
    p = M[:3, 3] / scale
    if not g.in_chart(p):
        raise ValueError(f"camera position {p.tolist()} is not a point of {g.name}")
    X = g.to_model(p)
    if space.domain.contains(X):
        return M
    X2, _, A = space.bring_inside(X)
    D = np.stack([g.tangent_to_chart(X2, A @ g.tangent_to_model(p, e)) for e in np.eye(3)], axis=1)
    forward, up = -M[:3, 2], M[:3, 1]
    normal = up - (up @ forward) / (forward @ forward) * forward  # of the forward-right plane
    z = -(D @ forward)
    y = np.linalg.solve(D.T, normal)
    z, y = z / np.linalg.norm(z), y / np.linalg.norm(y)
    moved = M.copy()
    moved[:3, :3] = np.stack([np.cross(y, z), y, z], axis=1) * np.linalg.norm(M[:3, :3], axis=0)
    moved[:3, 3] = g.to_chart(X2) * scale
    return moved


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
    return not (g.in_chart(p) and space.domain.contains(g.to_model(p), tol=FLOAT32_SLACK))
