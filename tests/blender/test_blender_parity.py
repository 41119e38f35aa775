"""Where the add-on behaves as Blender and Cycles do (real bpy 5.0.1, background): its images stay
in a file saved any number of times, animations go on past objects scaled to 0, render-blend
creates its output folder, presets keep every render setting, a missing texture renders magenta,
and a Scale of 0 is one clear error."""

from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")

from support import blender_helpers as bh  # noqa: E402


def small_scene(size=(16, 9)):
    """A lit box ahead of a camera at the origin of the torus (draft quality)."""
    sc = bh.fresh_scene("torus", size=size)
    bh.box("Box", 0.12, (0.02, 0.25, 0.0), color=(0.9, 0.3, 0.1), rotation=(0.3, 0.2, 0.1))
    bh.box("Lamp", 0.05, (-0.1, 0.2, -0.05), color=(0, 0, 0), emission=(0.2, 0.9, 0.4), strength=2.0)
    bh.point_light((0.05, 0.05, 0.1), energy=3.0)
    bh.camera((0, 0, 0))
    return sc


# --- images stay in the file over any number of saves ---------------------------------------------------
def world_seen_by_cycles(sc, tmp_path, name):
    """Cycles' render of the World alone (the boxes hidden) looking along +Y: the panorama."""
    hidden = [o for o in sc.objects if o.type == "MESH"]
    for o in hidden:
        o.hide_render = True
    engine = sc.render.engine
    sc.render.engine = "CYCLES"
    sc.cycles.samples = 4
    sc.cycles.device = "CPU"
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.filepath = str(tmp_path / f"{name}.exr")
    bpy.ops.render.render(write_still=True)
    for o in hidden:
        o.hide_render = False
    sc.render.engine = engine
    return bh.rgb(bh.read_exr(tmp_path / f"{name}.exr"))


def test_images_stay_in_a_file_saved_three_times(tmp_path):
    """Each save packs the add-on's images only where the file lacks their pixels (packing a packed
    image unpacks it in Blender 5): after three saves the reopened file holds every image as rendered,
    and Cycles sees the same panorama in the World (not Blender's magenta for a missing image)."""
    sc = small_scene()
    sc.thurston.panorama_width = 64
    for op in (bpy.ops.thurston.render_view, bpy.ops.thurston.preview, bpy.ops.thurston.bake_panorama):
        assert op() == {"FINISHED"}
    names = ("Thurston View", "Thurston Preview", "Thurston Panorama")
    rendered = {name: bh.image_pixels(bpy.data.images[name]) for name in names}
    world = world_seen_by_cycles(sc, tmp_path, "before")
    assert world.max() > 0.05 and not np.allclose(world, [1, 0, 1], atol=0.05)
    blend = tmp_path / "saved.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.thurston.render_view()  # a new render between the saves is saved too
    rendered["Thurston View"] = bh.image_pixels(bpy.data.images["Thurston View"])
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    bpy.ops.wm.save_mainfile()  # and once more after reopening it
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    for name in names:
        image = bpy.data.images[name]
        assert image.packed_file is not None, name
        assert tuple(image.size) == rendered[name].shape[1::-1], name
        np.testing.assert_allclose(bh.image_pixels(image), rendered[name], rtol=1e-6, atol=1e-7, err_msg=name)
    sc = bpy.context.scene
    np.testing.assert_allclose(world_seen_by_cycles(sc, tmp_path, "after"), world, rtol=1e-5, atol=1e-6)


# --- render-blend creates its output folder ---------------------------------------------------------------
def test_render_blend_creates_its_output_folder(tmp_path):
    """As Blender creates a render's output folder (with its parents), so does render-blend; a
    file where the folder should be is one error naming it."""
    small_scene(size=(8, 6))
    blend = tmp_path / "made.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    out = tmp_path / "new" / "frames"
    run = bh.render_blend(blend, out)
    assert run.returncode == 0, run.stderr
    assert sorted(p.name for p in out.iterdir()) == ["made_0001.exr"]
    (tmp_path / "a_file").write_text("")
    run = bh.render_blend(blend, tmp_path / "a_file")
    assert run.returncode == 2
    assert "a_file' is a file" in run.stderr and "Traceback" not in run.stderr


# --- presets keep every render setting -------------------------------------------------------------------
def test_presets_keep_the_light_settings(tmp_path, monkeypatch):
    """A preset restores the light settings (bounces, light samples, light reach, light paths) and
    denoising, and names every setting of the panel but the file's own (Save To, Overwrite)."""
    monkeypatch.setenv("BLENDER_USER_SCRIPTS", str(tmp_path))
    bh.fresh_scene()
    s = bpy.context.scene.thurston
    chosen = dict(bounces=3, light_samples=7, light_reach=2.5, light_paths=16, use_denoising=True)
    for name, value in chosen.items():
        setattr(s, name, value)
    assert bpy.ops.thurston.add_preset(name="Lit") == {"FINISHED"}
    preset = next(tmp_path.glob("**/presets/thurston/Lit.py"), None) or next(
        Path(bpy.utils.resource_path("USER")).glob("**/presets/thurston/Lit.py")
    )
    try:
        text = preset.read_text()
        named = {p.identifier for p in s.bl_rna.properties if p.identifier not in ("rna_type", "name")}
        named -= {"space", "stats", "save_path", "overwrite"}  # space_id holds the space
        assert [n for n in sorted(named) if f"settings.{n} = " not in text] == []
        for name in chosen:
            s.property_unset(name)
        assert (s.bounces, s.light_samples, s.light_reach, s.light_paths) != (3, 7, 2.5, 16)
        assert bpy.ops.script.execute_preset(filepath=str(preset), menu_idname="THURSTON_MT_presets") == {"FINISHED"}
        assert {name: getattr(s, name) for name in chosen} == chosen
    finally:
        preset.unlink()


# --- a missing texture file renders magenta ------------------------------------------------------------
def missing_image_material(name, image):
    """An Emission shader whose colour is an Image Texture of `image`."""
    mat = bh.material(name, kind="emission")
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    emission = next(n for n in mat.node_tree.nodes if n.type == "EMISSION")
    mat.node_tree.links.new(tex.outputs["Color"], emission.inputs["Color"])
    return mat


def test_a_missing_texture_file_renders_magenta_as_in_cycles(tmp_path):
    """An image whose file is gone: Cycles renders it magenta (1, 0, 1) and goes on; so does the
    engine, with one note naming the image and its file (two materials use it)."""
    sc = bh.fresh_scene("torus", size=(8, 8))
    gone = tmp_path / "gone.png"
    image = bpy.data.images.new("Gone", 4, 4)
    image.source, image.filepath = "FILE", str(gone)
    for name, x in (("Left", -0.06), ("Right", 0.06)):
        wall = bh.box(name, (0.12, 0.02, 0.4), (x, 0.3, 0))
        wall.data.materials[0] = missing_image_material(name, image)
    bh.camera((0, 0, 0))
    sc.view_settings.view_transform = "Standard"
    thurston = bh.rgb(bh.f12(sc, tmp_path / "thurston.exr"), "ViewLayer.Combined.")
    notes = [n.message for n in sc.thurston.stats.notes if "'Gone'" in n.message]
    assert len(notes) == 1 and str(gone) in notes[0] and "magenta" in notes[0], notes
    cycles = bh.cycles_render(sc, tmp_path / "cycles.exr", samples=1)
    cycles = bh.rgb(cycles, "ViewLayer.Combined.")
    for image in (thurston, cycles):
        np.testing.assert_allclose(image[2:6, 2:6], np.broadcast_to([1.0, 0.0, 1.0], (4, 4, 3)), atol=1e-6)


# --- a Scale of 0 --------------------------------------------------------------------------------------
@pytest.mark.parametrize("space", ("torus", "poincare", "seifert_weber", "nil"))
def test_a_scale_of_0_is_one_error_naming_the_setting(space):
    """Blender keeps a Scale of 0 at its least, 1e-06, where the scene lies hundreds of thousands of
    domains away: F12 and Render View fail with one error naming Scale and the value that fits
    (not the tracer's complaint about face crossings, a point outside H3 or the clip start)."""
    sc = small_scene(size=(8, 6))
    sc.thurston.space = space
    sc.thurston.scale = 0.0
    sc.render.engine = "THURSTON"
    for op in (bpy.ops.render.render, bpy.ops.thurston.render_view):
        with pytest.raises(RuntimeError) as info:
            op()
        errors = [line for line in str(info.value).splitlines() if line.startswith("Error:")]
        assert len(errors) == 1, errors
        assert "Scale is 0" in errors[0] and "set Scale" in errors[0] and "Fit Scale" in errors[0], errors
        assert "crossings" not in errors[0] and "clip" not in errors[0]
    assert bpy.ops.thurston.fit_scale() == {"FINISHED"}
    assert bpy.ops.thurston.render_view() == {"FINISHED"}


# --- animations go on past objects scaled to 0 -----------------------------------------------------------
def pop_in(obj, frames=(1, 3)):
    """Scale keyed from 0 at the first frame to 1 at the last (linear)."""
    for frame, scale in zip(frames, (0.0, 1.0)):
        obj.scale = (scale,) * 3
        obj.keyframe_insert("scale", frame=frame)
    action = obj.animation_data.action
    for fc in action.fcurves if hasattr(action, "fcurves") else []:
        for k in fc.keyframe_points:
            k.interpolation = "LINEAR"


def exr_settings(sc):
    s = sc.render.image_settings
    s.media_type = "MULTI_LAYER_IMAGE"
    s.file_format = "OPEN_EXR_MULTILAYER"
    s.color_depth = "32"


def test_render_blend_goes_on_past_an_object_scaled_to_0(tmp_path):
    """A pop-in (scale keyed from 0): render-blend renders every frame, the first without the object
    and one warning naming it and the frame, the last with it."""
    sc = small_scene(size=(16, 9))
    pop = bh.box("Pop", 0.1, (-0.12, 0.25, 0.05), color=(0.2, 0.3, 0.9))
    pop_in(pop)
    sc.frame_start, sc.frame_end = 1, 3
    blend = tmp_path / "pop.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    run = bh.render_blend(blend, tmp_path / "out", frames="1..3")
    assert run.returncode == 0, run.stderr
    warnings = [line for line in run.stdout.splitlines() if ": warning: " in line and "scaled to 0" in line]
    assert len(warnings) == 1 and "pop_0001.exr" in warnings[0], warnings
    assert "'Pop'" in warnings[0] and "frame 1" in warnings[0] and "'Box'" not in warnings[0]
    first, last = (bh.read_exr(tmp_path / "out" / f"pop_{f:04d}.exr") for f in (1, 3))
    assert not np.allclose(bh.rgb(first, "ViewLayer.Combined."), bh.rgb(last, "ViewLayer.Combined."))


def test_f12_animation_of_a_lone_pop_in_and_a_failing_frame(tmp_path):
    """F12 animation of a scene whose only object pops in: the first frame renders empty (as in
    Cycles) with a note naming the object and frame; the frames after show it. A frame that fails
    names the frame."""
    sc = bh.fresh_scene("torus", size=(8, 6))
    pop = bh.box("Pop", 0.2, (0, 0.3, 0), color=(0, 0, 0), emission=(1, 1, 1))
    pop_in(pop, (1, 2))
    bh.camera((0, 0, 0))
    sc.frame_start, sc.frame_end = 1, 2
    sc.render.engine = "THURSTON"
    exr_settings(sc)
    sc.render.filepath = str(tmp_path / "frame_###")
    bpy.ops.render.render(animation=True)
    first, second = (bh.rgb(bh.read_exr(tmp_path / f"frame_{f:03d}.exr"), "ViewLayer.Combined.") for f in (1, 2))
    assert first.max() == 0 and second[3, 4].min() > 0.5
    sc.frame_set(1)
    bpy.ops.render.render()  # a still of the first frame: the same note
    notes = [n.message for n in sc.thurston.stats.notes if "scaled to 0" in n.message]
    assert len(notes) == 1 and "'Pop'" in notes[0] and "frame 1" in notes[0], notes

    sc.thurston.space = "seifert_weber"
    cam = sc.camera
    cam.keyframe_insert("location", frame=1)
    cam.location = (3, 0, 0)  # not a point of H3's chart
    cam.keyframe_insert("location", frame=2)
    with pytest.raises(RuntimeError) as info:
        bpy.ops.render.render(animation=True)
    assert "frame 2" in str(info.value) and "Camera" in str(info.value), str(info.value)
