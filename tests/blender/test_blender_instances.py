"""Instancing in real bpy: a collection instanced 1000 times by an array of empties renders in F12
through one mesh in the core, and its depth straight ahead is the closed form."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")

from support import blender_helpers as bh  # noqa: E402

from thurston_addon import render  # noqa: E402
from thurston_addon.blender import export  # noqa: E402

RADIUS = 0.02
SIZE = (33, 33)  # odd: the centre pixel's ray is the optical axis


def instanced_grid():
    """Balls of RADIUS at the points of a 10 x 10 x 10 grid of the torus, each the instance of a
    collection by an empty; the camera at a grid point's x, z looking along +Y."""
    sc = bh.fresh_scene("torus", size=SIZE)
    src = bpy.data.collections.new("Ball Source")  # not in the scene: seen only through instances
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=3, radius=RADIUS, location=(0, 0, 0))
    ball = bpy.context.object
    for c in ball.users_collection:
        c.objects.unlink(ball)
    src.objects.link(ball)
    c = -0.45 + 0.1 * np.arange(10)
    for i, x in enumerate(c):
        for j, y in enumerate(c):
            for k, z in enumerate(c):
                e = bpy.data.objects.new(f"Grid {i} {j} {k}", None)
                e.instance_type, e.instance_collection = "COLLECTION", src
                e.location = (x, y, z)
                bh.link(e)
    cam = bh.camera(location=(0.05, -0.1, 0.05))
    cam.data.clip_start = 1e-4
    bh.point_light((0.0, -0.1, 0.0))
    sc.view_layers[0].use_pass_z = True
    return sc, ball


def test_thousand_collection_instances_render_through_one_mesh(tmp_path):
    sc, ball = instanced_grid()
    mesh = ball.data
    mesh.calc_loop_triangles()
    # the ball's faces lie within this of its sphere
    centres = np.array([p.center[:] for p in mesh.polygons])
    normals = np.array([p.normal[:] for p in mesh.polygons])
    sagitta = RADIUS - float(np.min(np.abs(np.einsum("ij,ij->i", centres, normals))))

    notes = []
    scene = export.export_scene(bpy.context.evaluated_depsgraph_get(), 1.0, notes)
    (shared,) = scene.objects
    assert shared.instances.shape == (1000, 4, 4)
    tracer = render.make_tracer(export.load_space(sc.thurston), scene, threads=2)
    assert tracer.num_triangles == len(mesh.loop_triangles)  # the mesh once
    assert tracer.num_instanced_triangles >= 1000 * len(mesh.loop_triangles)

    depth = bh.f12(sc, tmp_path / "grid.exr")["ViewLayer.Depth.Z"]
    # straight ahead: the ball at (0.05, -0.05, 0.05), 0.05 away
    assert 0.05 - RADIUS - 1e-6 <= depth[SIZE[1] // 2, SIZE[0] // 2] <= 0.05 - RADIUS + sagitta + 1e-6


def test_geometry_nodes_instances_share_one_mesh(tmp_path):
    """Geometry nodes' Instance on Points: the 25 instances of one ico sphere on a grid's points are
    one mesh in the core with 25 placements, and the depth along the optical axis to the sphere
    at (0, 0.15, 0) lies between the inscribed and the circumscribed sphere's."""
    sc = bh.fresh_scene("torus", size=SIZE)
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=4, y_subdivisions=4, size=0.6, location=(0, 0.45, 0))
    grid = bpy.context.active_object
    tree = bpy.data.node_groups.new("Scatter", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    points, out = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    on_points = tree.nodes.new("GeometryNodeInstanceOnPoints")
    ico = tree.nodes.new("GeometryNodeMeshIcoSphere")
    ico.inputs["Radius"].default_value, ico.inputs["Subdivisions"].default_value = 0.03, 3
    tree.links.new(points.outputs[0], on_points.inputs["Points"])
    tree.links.new(ico.outputs["Mesh"], on_points.inputs["Instance"])
    tree.links.new(on_points.outputs["Instances"], out.inputs[0])
    grid.modifiers.new("Scatter", "NODES").node_group = tree
    bh.point_light((0.1, 0, 0.1))
    bh.camera((0, 0, 0))
    scene = export.export_scene(bpy.context.evaluated_depsgraph_get(), 1.0, [])
    (balls,) = scene.objects
    assert len(balls.instances) == 25 and len(balls.triangles) == 320
    sc.view_layers[0].use_pass_z = True
    depth = bh.f12(sc, tmp_path / "gn.exr")["ViewLayer.Depth.Z"][SIZE[1] // 2, SIZE[0] // 2]
    inscribed = 0.03 * 0.98  # the subdivision-3 ico sphere's faces are within 2% of its radius
    assert 0.15 - 0.03 - 1e-6 <= depth <= 0.15 - inscribed
