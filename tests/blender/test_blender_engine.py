"""The THURSTON engine as a Blender user meets it (real bpy 5.0.1, background): the factory startup
scene, render regions, what the render report says, view layers and collection instances, the
camera's lens shift, sensor fit and clip distances (against Cycles rendering the scene tiled in the
universal cover), Blender's own panels."""

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")

from support import blender_helpers as bh  # noqa: E402
from support.outputs import PREVIOUS, error_line, fill, listing, tmpfs  # noqa: E402

import thurston_addon  # noqa: E402
from thurston_addon import checks  # noqa: E402
from thurston_addon.blender import engine  # noqa: E402


def note_kinds(sc):
    return {n.kind for n in sc.thurston.stats.notes}


def depth_pass(sc, path):
    sc.view_layers[0].use_pass_z = True
    return bh.f12(sc, path)["ViewLayer.Depth.Z"]


# --- first use ---------------------------------------------------------------------------------------
def test_first_use_of_the_factory_scene(tmp_path):
    """Blender's startup scene (a 2 m cube, a light and a camera 11 m away), engine switched to
    Thurston, F12: the report says the cube is larger than the domain, naming Fit Scale, and nothing
    else (what follows from it, and the camera's place at that scale, waits for the fix); Fit Scale
    fits the cube and the light (their box) to the domain; the image then shows the lit cube and its
    copies (tests/blender/test_blender_first_use.py: as Blender shows it)."""
    bpy.ops.wm.read_factory_settings(use_empty=False)
    sc = bpy.context.scene
    assert sc.thurston.space_id == "poincare"  # the default space, stored by id
    sc.render.engine = "THURSTON"
    sc.render.resolution_percentage = 5  # 96 x 54
    sc.thurston.threads = 2
    bh.f12(sc, tmp_path / "first.exr")
    assert note_kinds(sc) == {checks.SCENE_TOO_LARGE}
    messages = " ".join(n.message for n in sc.thurston.stats.notes)
    assert "'Cube'" in messages and "Fit Scale" in messages

    light = np.array(sc.objects["Light"].location)
    box = np.linalg.norm(np.maximum(light, 1) - np.minimum(light, -1))
    assert bpy.ops.thurston.fit_scale() == {"FINISHED"}
    assert sc.thurston.scale == pytest.approx(checks.fit_scale(bh_space("poincare"), box), rel=1e-6)
    sc.view_layers[0].use_pass_z = True
    ch = bh.f12(sc, tmp_path / "fitted.exr")
    assert not note_kinds(sc) & {checks.SCENE_TOO_LARGE, checks.EXPOSURE, checks.UNLIT}
    depth = ch["ViewLayer.Depth.Z"]
    hit = depth < 1e9
    color = bh.rgb(ch, "ViewLayer.Combined.").max(axis=-1) * 2**sc.view_settings.exposure
    assert hit.mean() > 0.2 and (color[hit] > 0.02).mean() > 0.9 and np.std(np.log(color[hit])) > 0.1
    assert np.ptp(np.log(depth[hit])) > 1  # near and far copies


def bh_space(sid):
    from thurston_addon import spaces

    return spaces.load(sid)


# --- the render region ---------------------------------------------------------------------------------
def scene_with_boxes():
    sc = bh.fresh_scene("torus", size=(40, 24))
    bh.box("Red", 0.15, (0.1, 0.3, 0.05), color=(0.9, 0.2, 0.1))
    bh.box("Floor", (0.8, 0.8, 0.02), (0, 0.2, -0.12), color=(0.5, 0.5, 0.7))
    bh.point_light((0.05, 0.05, 0.1), energy=3.0)
    bh.camera((0, -0.1, 0), lens=30.0)
    return sc


@pytest.mark.parametrize("crop", [False, True])
def test_render_region_is_rendered(tmp_path, crop):
    """F12 with a render region: the region's pixels equal those of the full frame (Blender's border
    rule: fractions times the size, truncated); without crop the rest is empty (alpha 0, as Cycles
    leaves it), with crop the image is the region."""
    sc = scene_with_boxes()
    full = bh.f12(sc, tmp_path / "full.exr")
    r = sc.render
    r.use_border, r.use_crop_to_border = True, crop
    r.border_min_x, r.border_max_x, r.border_min_y, r.border_max_y = 0.3, 0.83, 0.1, 0.65
    x0, x1, y0, y1 = int(0.3 * 40), int(0.83 * 40), int(0.1 * 24), int(0.65 * 24)
    part = bh.f12(sc, tmp_path / "part.exr")
    rows = slice(24 - y1, 24 - y0)  # top-down
    cols = slice(x0, x1)
    L = "ViewLayer.Combined."
    window = bh.rgb(part, L) if crop else bh.rgb(part, L)[rows, cols]
    assert window.shape == (y1 - y0, x1 - x0, 3)
    np.testing.assert_allclose(window, bh.rgb(full, L)[rows, cols], rtol=1e-5, atol=1e-7)
    assert window.max() > 0.05
    if not crop:
        alpha = part[L + "A"]
        outside = np.ones_like(alpha, bool)
        outside[rows, cols] = False
        assert np.all(alpha[outside] == 0) and np.all(alpha[~outside] == 1)


def test_region_in_render_blend(tmp_path):
    """render-blend honours the region saved in the file and exits 0 with a non-empty image."""
    sc = scene_with_boxes()
    r = sc.render
    r.use_border, r.use_crop_to_border = True, True
    r.border_min_x, r.border_max_x, r.border_min_y, r.border_max_y = 0.25, 0.75, 0.25, 0.75
    blend = tmp_path / "region.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    run = bh.render_blend(blend, tmp_path, "--format", "exr")
    assert run.returncode == 0, run.stderr
    image = bh.read_exr(tmp_path / "region_0001.exr")
    color = bh.rgb(image, "ViewLayer.Combined.")
    assert color.shape == (12, 20, 3) and color.max() > 0.05


# --- the render report ------------------------------------------------------------------------------------
def test_notes_reach_the_report(tmp_path):
    sc = bh.fresh_scene("torus", size=(16, 10))
    bh.box("Floor", (0.8, 0.8, 0.02), (0, 0.2, -0.12))
    bh.camera((0, -0.1, 0), lens=30.0)
    bh.f12(sc, tmp_path / "a.exr")
    assert checks.NO_LIGHTS in note_kinds(sc)

    # a light shut inside a closed box: nothing the camera sees is lit
    bh.box("Shell", 0.1, (0.3, 0.3, 0.3))
    bh.point_light((0.3, 0.3, 0.3), energy=5.0)
    bh.f12(sc, tmp_path / "b.exr")
    assert checks.UNLIT in note_kinds(sc) and checks.NO_LIGHTS not in note_kinds(sc)


def test_camera_inside_an_object():
    """Inside a closed box with no light in it the camera sees an unlit inside: noted; with a light
    inside it, not (a room)."""
    sc = bh.fresh_scene("torus", size=(8, 6))
    bh.box("Room", 0.4, (0, 0.02, 0))
    light = bh.point_light((0.6, 0.6, 0.6), energy=5.0)  # outside the room (inside the next copies' gaps)
    light.location = (0.45, 0.45, 0.45)
    bh.camera((0, 0, 0))
    sc.render.engine = "THURSTON"
    bpy.ops.render.render()
    assert checks.CAMERA_IN_OBJECT in note_kinds(sc)
    messages = " ".join(n.message for n in sc.thurston.stats.notes)
    assert "'Room'" in messages
    light.location = (0.1, 0.1, 0.1)
    bpy.ops.render.render()
    assert checks.CAMERA_IN_OBJECT not in note_kinds(sc)


def test_scene_far_smaller_than_the_domain_is_noted():
    sc = bh.fresh_scene("torus", size=(8, 6))
    bh.box("Speck", 1e-3, (0, 0.2, 0))
    bh.point_light((0, 0.2, 2e-3))  # the scene: the speck and its light
    bh.camera((0, 0, 0))
    sc.render.engine = "THURSTON"
    bpy.ops.render.render()
    assert checks.SCENE_TOO_SMALL in note_kinds(sc)
    assert bpy.ops.thurston.fit_scale() == {"FINISHED"}
    diagonal = math.hypot(1e-3, 1e-3, 2.5e-3)  # the box of the speck and the light
    assert sc.thurston.scale == pytest.approx(checks.fit_scale(bh_space("torus"), diagonal), rel=1e-3)


def test_a_small_object_lit_from_afar_is_no_small_scene():
    sc = bh.fresh_scene("torus", size=(8, 6))
    bh.box("Speck", 1e-3, (0, 0.2, 0))
    bh.point_light((0, 0, 0.1))
    bh.camera((0, 0, 0))
    sc.render.engine = "THURSTON"
    bpy.ops.render.render()
    assert checks.SCENE_TOO_SMALL not in note_kinds(sc)


def test_render_blend_prints_notes_and_fails_on_a_failed_frame(tmp_path):
    bh.fresh_scene("torus", size=(8, 6))
    bh.box("Floor", (0.8, 0.8, 0.02), (0, 0.2, -0.12))
    bh.camera((0, -0.1, 0), lens=30.0)
    blend = tmp_path / "dark.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    run = bh.render_blend(blend, tmp_path)
    assert run.returncode == 0, run.stderr
    assert "warning: the scene has no lights" in run.stdout + run.stderr

    bh.fresh_scene("seifert_weber", size=(8, 6))
    bh.box("B", 0.1, (0, 0.3, 0))
    bh.camera((3, 0, 0))  # not a point of H3's chart
    blend = tmp_path / "broken.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    run = bh.render_blend(blend, tmp_path)
    assert run.returncode != 0
    assert "frame 1" in run.stderr and "camera" in run.stderr and "Traceback" not in run.stderr
    assert not (tmp_path / "broken_0001.exr").exists()


@pytest.mark.parametrize("suffix", ("exr", "png"))
def test_render_blend_on_a_full_disk_keeps_the_previous_frame(tmp_path, suffix):
    """Blender writes render-blend's frames (save_render) into a temporary file that is read back
    before it replaces the frame: on a full disk (where Blender's writer fails silently) the run
    fails with one error naming the frame's file, whose previous bytes stay, and no temporary file
    is left."""
    bh.fresh_scene("torus", size=(64, 48))
    bh.box("B", 0.1, (0, 0.3, 0))
    bh.camera((0, 0, 0))
    blend = tmp_path / "full.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    with tmpfs(tmp_path / "disk", "256k") as disk:
        frame = disk / f"full_0001.{suffix}"
        frame.write_bytes(PREVIOUS)
        fill(disk)
        run = bh.render_blend(blend, disk, "--format", suffix, "--overwrite")
        assert run.returncode == 2, run.stderr
        assert error_line(run.stderr).startswith(
            f"thurston: error: cannot write {str(frame)!r}: No space left on "
            "device: the written file does not read back whole"
        )
        assert frame.read_bytes() == PREVIOUS and listing(disk) == ["filler", frame.name]


@pytest.mark.parametrize("suffix", ("exr", "png"))
def test_save_to_on_a_full_disk_keeps_the_previous_file(tmp_path, suffix):
    """The panel's Save To goes through the command line's checked writer: on a full disk Render
    View fails with one error naming the file, whose previous bytes stay, and no temporary file is
    left."""
    sc = bh.fresh_scene("torus", size=(64, 48))
    bh.box("B", 0.1, (0, 0.3, 0))
    bh.camera((0, 0, 0))
    with tmpfs(tmp_path / "disk", "256k") as disk:
        out = disk / f"view.{suffix}"
        out.write_bytes(PREVIOUS)
        fill(disk)
        sc.thurston.save_path, sc.thurston.overwrite = str(out), True
        with pytest.raises(RuntimeError) as info:
            bpy.ops.thurston.render_view()
        errors = [ln for ln in str(info.value).splitlines() if ln.startswith("Error:")]
        assert len(errors) == 1 and errors[0].startswith(f"Error: cannot write {str(out)!r}: No space left on device")
        assert out.read_bytes() == PREVIOUS and listing(disk) == ["filler", out.name]


# --- view layers and instances -------------------------------------------------------------------------------
def box_in_collection(sc, name, location):
    """A 0.1 box in a new collection of that name, under the scene's collection."""
    coll = bpy.data.collections.new(name)
    sc.collection.children.link(coll)
    box = bh.box("Box", 0.1, location)
    sc.collection.objects.unlink(box)
    coll.objects.link(box)
    return coll


def test_each_view_layer_renders_with_its_own_visibility(tmp_path):
    """Two view layers; a collection excluded from the second: F12 renders both layers, the box in
    that collection is straight ahead at distance 0.25 in the first and absent in the second."""
    sc = bh.fresh_scene("torus", size=(9, 9))
    box_in_collection(sc, "OnlyFirst", (0, 0.3, 0))
    bh.box("Far", (0.9, 0.02, 0.9), (0, 0.45, 0))
    bh.point_light((0, 0, 0.1))
    bh.camera((0, 0, 0))
    first = sc.view_layers[0]
    second = sc.view_layers.new("Second")
    second.layer_collection.children["OnlyFirst"].exclude = True
    for layer in (first, second):
        layer.use_pass_z = True
    ch = bh.f12(sc, tmp_path / "layers.exr")
    assert ch[f"{first.name}.Depth.Z"][4, 4] == pytest.approx(0.25, abs=1e-6)
    assert ch["Second.Depth.Z"][4, 4] == pytest.approx(0.44, abs=1e-6)  # the far wall


def test_instances_of_an_excluded_collection_render(tmp_path):
    """As in Cycles: a collection excluded from the view layer still renders through an instancer."""
    sc = bh.fresh_scene("torus", size=(9, 9))
    source = box_in_collection(sc, "Source", (0, 0, 0))
    sc.view_layers[0].layer_collection.children["Source"].exclude = True
    empty = bpy.data.objects.new("Instancer", None)
    empty.instance_type = "COLLECTION"
    empty.instance_collection = source
    empty.location = (0, 0.3, 0)
    sc.collection.objects.link(empty)
    bh.point_light((0, 0, 0.1))
    bh.camera((0, 0, 0))
    assert depth_pass(sc, tmp_path / "inst.exr")[4, 4] == pytest.approx(0.25, abs=1e-6)


# --- the camera against Cycles -----------------------------------------------------------------------------
def test_lens_shift_sensor_fit_and_clipping_match_cycles(tmp_path):
    """Emissive boxes in the torus, a camera with lens shift, vertical sensor fit, and clip start
    and end: Thurston's image equals Cycles' image of the scene tiled 3 x 3 x 3 in the universal
    cover (the clip end keeps every ray inside the tiling). A box nearer than the clip start and
    the copies beyond the clip end are cut in both."""
    sc = bh.fresh_scene("torus", size=(40, 30))
    black = (0, 0, 0)
    bh.box("Red", 0.18, (0.22, 0.35, 0.1), color=black, emission=(1, 0.1, 0.1))
    bh.box("Green", (0.3, 0.12, 0.2), (-0.2, 0.4, -0.15), color=black, emission=(0.1, 1, 0.2))
    bh.box("Near", 0.08, (0.0, 0.18, 0.0), color=black, emission=(0.2, 0.2, 1))
    cam = bh.camera((0, 0, 0), rotation=(math.pi / 2 - 0.1, 0, 0.15), lens=28.0)
    cam.data.sensor_fit = "VERTICAL"
    cam.data.shift_x, cam.data.shift_y = 0.12, -0.08
    cam.data.clip_start, cam.data.clip_end = 0.25, 0.9
    sc.thurston.shading = "lambert"
    thurston = bh.rgb(bh.f12(sc, tmp_path / "thurston.exr"), "ViewLayer.Combined.")

    bh.tile_torus_for_cycles(sc, 3)
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=16), "ViewLayer.Combined.")

    def seen(image):  # which box each pixel mostly shows: 0 red, 1 green, 2 blue, 3 none
        return np.where(image.max(axis=-1) > 0.5, np.argmax(image, axis=-1), 3)

    differs = seen(thurston) != seen(cycles)
    assert differs.mean() < 0.01, f"{differs.mean():.1%} of pixels show another box"
    for box in (0, 1):  # the colours, over each box's pixels (Cycles' are noisy by a few per cent)
        mask = (seen(cycles) == box) & ~differs
        np.testing.assert_allclose(thurston[mask].mean(axis=0), cycles[mask].mean(axis=0), rtol=0.03, atol=0.005)
    counts = np.bincount(seen(cycles).ravel(), minlength=4)
    assert counts[0] > 20 and counts[1] > 20 and counts[2] == 0  # the near box is clipped


# --- Blender's panels ------------------------------------------------------------------------------------
NEEDED_PANELS = (
    "EEVEE_MATERIAL_PT_context_material",
    "EEVEE_MATERIAL_PT_surface",
    "DATA_PT_uv_texture",
    "DATA_PT_vertex_groups",
    "OBJECT_PT_visibility",
    "RENDER_PT_color_management",
    "RENDER_PT_output",
    "RENDER_PT_format",
    "RENDER_PT_stamp",
    "VIEWLAYER_PT_layer_passes",
    "EEVEE_WORLD_PT_surface",
    "DATA_PT_lens",
    "DATA_PT_camera",
    "DATA_PT_light",
    "RENDER_PT_frame_range",
)


def test_blender_panels_show_under_the_engine():
    for name in NEEDED_PANELS:
        assert "THURSTON" in getattr(bpy.types, name).COMPAT_ENGINES, name
    assert not any(
        "THURSTON" in p.COMPAT_ENGINES for p in engine.compatible_panels() if "freestyle" in p.__name__.lower()
    )


def test_the_settings_panel_only_under_thurston_and_the_tools_always():
    sc = bh.fresh_scene()
    panel = bpy.types.THURSTON_PT_render
    sc.render.engine = "CYCLES"
    assert not panel.poll(bpy.context)
    sc.render.engine = "THURSTON"
    assert panel.poll(bpy.context)
    assert bpy.types.THURSTON_PT_layer_passes.bl_parent_id == "VIEWLAYER_PT_layer_passes"
    tools = bpy.types.THURSTON_PT_tools
    assert tools.bl_space_type == "VIEW_3D" and tools.bl_category == "Thurston"


def test_film_transparent_alpha_matches_cycles(tmp_path):
    """Film > Transparent: alpha is the share of a pixel that shows an object, 0 where a ray meets
    nothing before the clip end, as in Cycles' render of the tiled scene."""
    sc = bh.fresh_scene("torus", size=(32, 24))
    sc.render.film_transparent = True
    sc.thurston.quality = "standard"  # 4 samples: partly covered pixels get partial alpha
    bh.box("A", 0.2, (0.15, 0.35, 0.05), color=(0, 0, 0), emission=(1, 1, 1))
    bh.box("B", (0.1, 0.3, 0.1), (-0.2, 0.3, -0.1), color=(0, 0, 0), emission=(1, 1, 1))
    cam = bh.camera((0, 0, 0), lens=24.0)
    cam.data.clip_end = 0.8
    alpha = bh.f12(sc, tmp_path / "thurston.exr")["ViewLayer.Combined.A"]
    bh.tile_torus_for_cycles(sc, 3)
    cycles = bh.cycles_render(sc, tmp_path / "cycles.exr", samples=16)["ViewLayer.Combined.A"]
    assert 0.1 < (cycles > 0.5).mean() < 0.9
    assert np.mean((alpha > 0.5) != (cycles > 0.5)) < 0.02
    assert np.all(alpha[cycles == 0] == 0) and np.all(alpha[cycles == 1] == 1)


def test_view_and_panorama_survive_saving(tmp_path):
    """The View image and the baked panorama are packed into the .blend when it is saved: the
    reopened file holds the same pixels, and its World's Environment Texture still shows them."""
    sc = scene_with_boxes()
    sc.thurston.panorama_width = 32
    assert bpy.ops.thurston.render_view() == {"FINISHED"}
    assert bpy.ops.thurston.bake_panorama() == {"FINISHED"}
    before = {name: bh.image_pixels(bpy.data.images[name]) for name in ("Thurston View", "Thurston Panorama")}
    assert all(p[..., :3].max() > 0.05 for p in before.values())
    blend = tmp_path / "saved.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    for name, pixels in before.items():
        np.testing.assert_array_equal(bh.image_pixels(bpy.data.images[name]), pixels)
    env = bpy.context.scene.world.node_tree.nodes["Thurston Panorama"]
    assert env.image.name == "Thurston Panorama" and env.image.has_data


# --- the viewport's exports -----------------------------------------------------------------------------------
def test_viewport_reexports_only_what_changed():
    """What the rendered viewport's view_update sees: a moved object changes the scene but not the
    meshes (they are reused, placed anew), an edited mesh changes the meshes, a moved camera
    changes neither; the reused export equals a fresh one."""
    from thurston_addon.blender import export

    sc = scene_with_boxes()
    seen = []

    def record(scene, depsgraph):
        seen.append((engine.changes_scene(depsgraph), engine.changes_meshes(depsgraph)))

    bpy.app.handlers.depsgraph_update_post.append(record)
    try:
        bpy.context.view_layer.update()
        meshes = {}
        first = export.export_scene(bpy.context.evaluated_depsgraph_get(), 1.0, [], meshes=meshes)
        read = dict(meshes)
        seen.clear()
        bpy.data.objects["Red"].location.x += 0.05
        bpy.context.view_layer.update()
        assert seen and seen[-1] == (True, False)
        moved = export.export_scene(bpy.context.evaluated_depsgraph_get(), 1.0, [], meshes=meshes)
        assert all(meshes[k] is read[k] for k in read)  # nothing read again
        fresh = export.export_scene(bpy.context.evaluated_depsgraph_get(), 1.0, [])
        for a, b in zip(moved.objects, fresh.objects):
            np.testing.assert_array_equal(a.vertices, b.vertices)
        red = [o for o in moved.objects if o.name == "Red"][0]
        before = [o for o in first.objects if o.name == "Red"][0]
        np.testing.assert_allclose(red.vertices - before.vertices, [[0.05, 0, 0]] * len(red.vertices), atol=1e-6)

        seen.clear()
        bpy.data.objects["Red"].data.vertices[0].co.x += 0.01
        bpy.data.objects["Red"].data.update()
        bpy.context.view_layer.update()
        assert seen and seen[-1][1]
        seen.clear()
        sc.camera.location.x += 0.01
        bpy.context.view_layer.update()
        assert seen and seen[-1] == (False, False)
    finally:
        bpy.app.handlers.depsgraph_update_post.remove(record)


def test_viewport_job_adds_the_panels_samples_with_its_bounces():
    """The job view_draw hands the progressive view (engine._viewport_job, here with a view like the
    scene camera's): the panel's Samples and Bounces, one-sample frames whose mean is the render of
    that view with those samples (draft accuracy), and the header's words for each frame."""
    from types import SimpleNamespace

    from mathutils import Matrix

    from thurston_addon import progressive, render, scenes
    from thurston_addon.blender import export

    sc = scene_with_boxes()
    sc.thurston.quality, sc.thurston.samples, sc.thurston.bounces = "standard", 3, 1
    space = export.load_space(sc.thurston)
    scene = export.export_scene(bpy.context.evaluated_depsgraph_get(), sc.thurston.scale, [])
    tracer = render.make_tracer(space, scene, 2)
    fov = sc.camera.data.angle_x
    window = Matrix.Identity(4)
    window[0][0] = 1 / math.tan(fov / 2)
    view = SimpleNamespace(is_perspective=True, view_matrix=sc.camera.matrix_world.inverted(), window_matrix=window)
    host = SimpleNamespace(_viewport_world=(space, tracer))
    job, viewport_settings = engine.ThurstonRenderEngine._viewport_job(host, sc, view, 24, 16)
    samples = viewport_settings.samples_per_pixel
    assert samples == 3 and viewport_settings.noise_threshold == 0
    mean = np.mean([job(1, k, lambda: False)[::-1, :, :3] for k in range(samples)], axis=0)  # rows top-down
    M = np.array(sc.camera.matrix_world, float)
    camera = scenes.Camera(M[:3, 3], -M[:3, 2], M[:3, 1], math.degrees(fov))
    settings = render.Settings(width=24, height=16, quality="draft", samples=3, bounces=1, threads=2)
    direct = render.render(space, None, settings, camera=camera, tracer=tracer).passes["color"]
    assert np.mean(np.isclose(mean, direct, rtol=1e-4, atol=1e-5).all(axis=2)) > 0.99
    assert (
        render.render(
            space,
            None,
            replace(settings, bounces=0),
            camera=camera,  # the bounces count
            tracer=tracer,
        )
        .passes["color"]
        .mean()
        < 0.9 * direct.mean()
    )
    frames = [
        progressive.Frame("k", 4, None),
        progressive.Frame("k", 1, None, 2, 0.0123),
        progressive.Frame("k", 1, None, 3, 0.01),
    ]
    assert [engine.viewport_status(f, 3) for f in frames] == [
        "viewport: 1/4 resolution",
        "viewport: sample 2/3, noise 1.2e-02",
        "viewport: sample 3/3, noise 1.0e-02 (done)",
    ]


# --- settings, operators' notes, layout --------------------------------------------------------------------
def test_samples_setting_and_distinct_draft_and_preview():
    """The panel's Samples overrides the quality's; draft and preview differ in samples per pixel."""
    from thurston_addon import render

    assert render.QUALITY["draft"].samples < render.QUALITY["preview"].samples
    sc = scene_with_boxes()
    sc.render.engine = "THURSTON"
    for quality, samples, want in (("draft", 0, 1), ("preview", 0, 2), ("draft", 3, 3)):
        sc.thurston.quality, sc.thurston.samples = quality, samples
        bpy.ops.render.render()
        assert sc.thurston.stats.rays == want * 40 * 24, (quality, samples)


def test_operators_report_the_notes():
    """Render View says what the engine says: a scene without lights is noted in its stats."""
    bh.fresh_scene("torus", size=(8, 6))
    bh.box("Floor", (0.8, 0.8, 0.02), (0, 0.2, -0.12))
    bh.camera((0, -0.1, 0), lens=30.0)
    assert bpy.ops.thurston.render_view() == {"FINISHED"}
    assert checks.NO_LIGHTS in note_kinds(bpy.context.scene)


def test_only_registration_imports_the_ui_packages():
    """The layout: nothing but the Blender layer's registration imports operators/ or panels/."""
    import re

    root = Path(thurston_addon.__file__).parent
    for path in root.rglob("*.py"):
        rel = path.relative_to(root)
        if rel.parts[0] in ("operators", "panels") or rel == Path("blender", "registration.py"):
            continue
        text = path.read_text()
        assert not re.search(
            r"from \.+\s*(operators|panels)\b|from \.+ import .*\b(operators|panels)\b|"
            r"thurston_addon\.(operators|panels)",
            text,
        ), rel
