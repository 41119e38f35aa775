"""Graphs of Gaussians in Blender (real bpy 5.0.1, background): a graph space is a space like any
other. Picked with Blender's default Lambert shading and a point light in the scene, F12 and
render-blend render it in the pseudo-colour normal shading without the light (light paths are not
found in this metric), say so in one note of the render report, and show what the core renders from
the same scene written as files with --shading normal; the domain guide draws each graph preset's
cube."""

import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")

from support import blender_helpers as bh  # noqa: E402

from thurston_addon import cli  # noqa: E402
from thurston_addon.blender import domain_guide, export  # noqa: E402

SIZE = (64, 36)
GRAPHS = ("graph_flat", "graph_local", "graph_global", "graph_two")
NOTE = "graph spaces render in pseudo-colour only: light paths are not found in this metric"


def graph_scene(space="graph_local"):
    """Two boxes and a floor beyond the bump of graph_local (centre (0, 0.9, 0), width 0.3), seen
    from the preset camera's place looking along +y, the shading left at Blender's Lambert."""
    sc = bh.fresh_scene(space, size=SIZE)
    assert sc.thurston.shading == "lambert"
    bh.box("Near", 0.3, (0.25, 0.6, 0.05), rotation=(0.3, 0.2, 0.1))
    bh.box("Far", 0.4, (-0.3, 0.85, 0.3))
    bh.box("Floor", (1.6, 1.6, 0.05), (0.0, 0.3, -0.5))
    bh.camera((0.2, -0.4, 0.1), rotation=(math.radians(95), 0, math.radians(-15)), lens=20.0)
    return sc


def core_normal_render(tmp_path, sc, space):
    """`thurston render --shading normal` of the scene as files (the lights are none yet)."""
    toml = bh.write_scene_files(sc, tmp_path, 1.0)
    out = tmp_path / "truth.exr"
    argv = ["render", "--space", space, "--scene", str(toml), "--size", f"{SIZE[0]}x{SIZE[1]}"]
    argv += ["--quality", "draft", "--shading", "normal", "--threads", "2", "--out", str(out)]
    assert cli.main(argv) == 0
    return bh.rgb(bh.read_exr(out))


def graph_notes(sc):
    return [n.message for n in sc.thurston.stats.notes if NOTE in n.message]


@pytest.mark.slow
def test_f12_and_render_blend_render_a_graph_space_in_pseudo_colour(tmp_path):
    sc = graph_scene()
    truth = core_normal_render(tmp_path, sc, "graph_local")
    hit = np.any(truth != 0, axis=-1)
    assert hit.mean() > 0.5 and np.ptp(truth[hit]) > 0.3  # the boxes and the floor, several normals
    bh.point_light((0.0, 0.2, 0.4), energy=5.0)  # Blender's lamp: left out, said so

    chans = bh.f12(sc, tmp_path / "f12.exr")
    np.testing.assert_allclose(bh.rgb(chans, "ViewLayer.Combined."), truth, atol=1e-5)
    (note,) = graph_notes(sc)
    assert "normal shading in place of Lambert" in note and "1 light(s)" in note
    assert sc.thurston.stats.valid and "pixel footprint" in sc.thurston.stats.bound

    blend = tmp_path / "graph.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    out = tmp_path / "out"
    out.mkdir()
    run = bh.render_blend(blend, out)
    assert run.returncode == 0, run.stderr
    assert NOTE in run.stdout + run.stderr
    np.testing.assert_allclose(bh.rgb(bh.read_exr(out / "graph_0001.exr"), "ViewLayer.Combined."), truth, atol=1e-5)


def test_f12_renders_r3(tmp_path):
    """graph_r3 (R^3, no group) picked like any space: F12 shows what the core renders of the same
    scene as files, rays running to the distance limit (nothing crossed)."""
    sc = graph_scene("graph_r3")
    truth = core_normal_render(tmp_path, sc, "graph_r3")
    sc.view_layers[0].thurston.use_pass_crossings = True
    chans = bh.f12(sc, tmp_path / "r3.exr")
    np.testing.assert_allclose(bh.rgb(chans, "ViewLayer.Combined."), truth, atol=1e-5)
    assert np.any(truth != 0) and graph_notes(sc)  # (the Lambert default, said in the note)
    assert np.all(chans["ViewLayer.Crossings.X"] == 0)


def test_a_chosen_pseudo_colour_shading_is_kept_and_the_lights_noted():
    sc = graph_scene("graph_flat")
    sc.thurston.shading = "depth"
    job = export.RenderJob(sc, bpy.context.evaluated_depsgraph_get())
    assert job.settings.shading == "depth" and not graph_notes(sc)  # nothing to say: no light
    bh.point_light((0.0, 0.2, 0.4))
    job = export.RenderJob(sc, bpy.context.evaluated_depsgraph_get())
    assert job.settings.shading == "depth" and job.scene.lights == []
    (note,) = [m for m in job.messages() if NOTE in m]
    assert "the depth shading, without the scene's 1 light(s)" in note
    sc.thurston.space_id = "torus"  # a space whose light paths are found: all as given
    job = export.RenderJob(sc, bpy.context.evaluated_depsgraph_get())
    assert len(job.scene.lights) == 1 and not [m for m in job.messages() if NOTE in m]


@pytest.mark.parametrize("space,half", [(sid, 1.0) for sid in GRAPHS] + [("graph_r3", 3.0)])
def test_domain_guide_of_the_graph_presets(space, half):
    """The flat 3-torus of period 2: the guide is the cube |x_i| <= 1 (times the scale), its 12 edges
    and 6 faces; R^3 (graph_r3, no group): its region of interest, the cube |x_i| <= 3."""
    scale = 1.5
    bh.fresh_scene(space, scale)
    assert bpy.ops.thurston.domain_guide() == {"FINISHED"}
    obj = bpy.data.objects[domain_guide.OBJECT]
    assert obj["thurston_space"] == space
    V = np.array([v.co for v in obj.data.vertices], float) / scale
    cube = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)], float)
    assert sorted(map(tuple, np.round(V, 6))) == sorted(map(tuple, cube))
    assert len(obj.data.edges) == 12 and len(obj.data.polygons) == 6


def test_the_rendered_viewport_shows_a_graph_space_in_pseudo_colour():
    """view_update builds the tracer without the lamp, and the viewport's frames (engine._viewport_job,
    a view like the scene camera's) are the normal shading's render of that view."""
    from types import SimpleNamespace

    from mathutils import Matrix

    from thurston_addon import render, scenes
    from thurston_addon.blender import engine

    sc = graph_scene("graph_flat")
    bh.point_light((0.0, 0.2, 0.4))
    host = SimpleNamespace(_viewport_world=None, _meshes={}, _meshes_scale=None, _scene_version=0)
    host.tag_redraw = lambda: None
    engine.ThurstonRenderEngine.view_update(host, bpy.context, bpy.context.evaluated_depsgraph_get())
    space, tracer = host._viewport_world  # not an error
    fov = sc.camera.data.angle_x
    window = Matrix.Identity(4)
    window[0][0] = 1 / math.tan(fov / 2)
    view = SimpleNamespace(is_perspective=True, view_matrix=sc.camera.matrix_world.inverted(), window_matrix=window)
    job, settings = engine.ThurstonRenderEngine._viewport_job(host, sc, view, 16, 10)
    assert settings.shading == "normal"
    M = np.array(sc.camera.matrix_world, float)
    camera = scenes.Camera(M[:3, 3], -M[:3, 2], M[:3, 1], math.degrees(fov))
    want = render.render(
        space,
        None,
        render.Settings(width=16, height=10, quality="draft", shading="normal", samples=1),
        camera=camera,
        tracer=tracer,
    ).passes["color"]
    np.testing.assert_allclose(job(1, 0, lambda: False)[::-1, :, :3], want, atol=1e-5)
