"""The arrays a Blender mesh exports to (real bpy): vertices, triangles, corner normals, UVs and each
triangle's material, against the straightforward reading, item by item through Blender's own
properties (loop_triangles' vertices, loops and material_index, the vertices' co, corner_normals,
the active render UV map's data), on a mesh of quads, ngons and triangles with two materials: smooth
and flat faces mixed, all smooth, all flat, and with sharp edges."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")

from support import blender_helpers as bh  # noqa: E402

from thurston_addon.blender.export import surfaces  # noqa: E402

SCALE = 1.7


def mixed_mesh(shading: str):
    """A bumpy 3x3 grid of quads, a hexagon and a triangle (the last two and the middle row in
    the second material), with two UV maps, the second the render one."""
    rng = np.random.default_rng(7)
    grid = [(x * 0.1, y * 0.1, 0.02 * rng.standard_normal()) for y in range(4) for x in range(4)]
    faces = [[y * 4 + x, y * 4 + x + 1, y * 4 + x + 5, y * 4 + x + 4] for y in range(3) for x in range(3)]
    hexagon = [(0.5 + 0.08 * np.cos(a), 0.1 + 0.08 * np.sin(a), 0.01 * np.sin(3 * a)) for a in np.arange(6) * np.pi / 3]
    faces.append(list(range(16, 22)))
    faces.append([3, 22, 7])
    mesh = bpy.data.meshes.new(f"Mixed {shading}")
    mesh.from_pydata(grid + hexagon + [(0.45, 0.2, 0.05)], [], faces)
    for layer in ("First", "Render"):
        uv = mesh.uv_layers.new(name=layer)
        uv.data.foreach_set("uv", rng.uniform(-1, 2, 2 * len(mesh.loops)).astype(np.float32))
    mesh.uv_layers["Render"].active_render = True
    mesh.uv_layers.active = mesh.uv_layers["First"]
    for i, poly in enumerate(mesh.polygons):
        poly.material_index = int(i in (3, 4, 5, 9, 10))
        poly.use_smooth = {"mixed": i % 2 == 0, "smooth": True, "flat": False, "sharp": True}[shading]
    if shading == "sharp":
        for edge in list(mesh.edges)[::3]:
            edge.use_edge_sharp = True
    mesh.update()
    obj = bh.link(bpy.data.objects.new(mesh.name, mesh))
    for name, color in (("One", (0.8, 0.2, 0.1)), ("Two", (0.1, 0.3, 0.9))):
        mesh.materials.append(bh.material(f"{name} {shading}", color))
    obj.location = (0.1, 0.2, 0.3)  # (the mesh is read in its own coordinates)
    return obj


def straightforward(mesh, scale):
    """The arrays read one item at a time through Blender's properties."""
    tris = list(mesh.loop_triangles)
    loops = np.array([t.loops[:] for t in tris])
    normals = None
    if mesh.normals_domain != "FACE":
        normals = np.array([[mesh.corner_normals[l].vector[:] for l in t] for t in loops], np.float64)
    layer = next(layer for layer in mesh.uv_layers if layer.active_render)
    return dict(
        vertices=np.array([v.co[:] for v in mesh.vertices], np.float64) / scale,
        triangles=np.array([t.vertices[:] for t in tris]),
        corner_normals=normals,
        corner_uvs=np.array([[layer.data[l].uv[:] for l in t] for t in loops], np.float64),
        triangle_material=np.array([t.material_index for t in tris]),
    )


@pytest.mark.parametrize("shading", ["mixed", "smooth", "flat", "sharp"])
def test_exported_arrays_are_blenders_own(shading):
    bh.fresh_scene("torus")
    obj = mixed_mesh(shading)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    # (an instance is valid only while the iteration is at it)
    (out,) = [surfaces.mesh_object(i, i.object, SCALE) for i in depsgraph.object_instances if i.object.original == obj]
    mesh = obj.evaluated_get(depsgraph).data
    assert mesh.normals_domain == {"mixed": "CORNER", "smooth": "POINT", "flat": "FACE", "sharp": "CORNER"}[shading]
    mesh.calc_loop_triangles()
    want = straightforward(mesh, SCALE)
    assert len(want["triangles"]) == 9 * 2 + 4 + 1
    assert set(want["triangle_material"]) == {0, 1}
    for name, expected in want.items():
        got = getattr(out, name)
        if expected is None:
            assert got is None, name
        else:
            assert got.dtype == expected.dtype or got.dtype.kind == expected.dtype.kind, name
            np.testing.assert_array_equal(got, expected, err_msg=name)
    assert [m.name for m in out.materials] == [f"One {shading}", f"Two {shading}"]
