"""render-blend's frames on the real two-node Ray cluster (tests/farm/conftest.py) against the
single-process render-blend of the same file: the same files, a rerun renders only the frames
not finished, a changed file starts afresh."""

import subprocess

import numpy as np
import pytest
from support import blender_helpers as bh

pytestmark = [pytest.mark.slow, pytest.mark.blender]


@pytest.fixture(scope="module")
def blend(tmp_path_factory):
    bpy = bh.bpy()
    import thurston_addon

    if not hasattr(bpy.types.Scene, "thurston"):
        thurston_addon.register()
    sc = bh.fresh_scene("torus", size=(16, 9))
    bh.box("Box", 0.2, (0.0, 0.3, 0.0), color=(0.8, 0.3, 0.2))
    bh.point_light((0.1, 0.1, 0.1))
    cam = bh.camera((0, 0, 0))
    sc.frame_start, sc.frame_end = 1, 3
    cam.keyframe_insert("location", frame=1)
    cam.location.x += 0.1
    cam.keyframe_insert("location", frame=3)
    path = tmp_path_factory.mktemp("blend") / "anim.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    return path


def test_frames_on_the_cluster_are_render_blends(blend, cluster, tmp_path):
    one, farmed = tmp_path / "one", tmp_path / "farm"
    one.mkdir()
    run = bh.render_blend(blend, one, frames="1..3")
    assert run.returncode == 0, run.stderr
    run = bh.render_blend(blend, farmed, "--cluster", cluster["address"], frames="1..3")
    assert run.returncode == 0, run.stderr
    names = ["anim_0001.exr", "anim_0002.exr", "anim_0003.exr"]
    assert sorted(p.name for p in farmed.iterdir()) == names  # and nothing kept once done
    for name in names:
        a, b = bh.read_exr(one / name), bh.read_exr(farmed / name)
        assert a.keys() == b.keys()
        for channel in a:
            np.testing.assert_array_equal(a[channel], b[channel], err_msg=f"{name} {channel}")


def test_a_rerun_renders_only_the_frames_not_finished(blend, cluster, tmp_path):
    from thurston_addon.blender import farm_frames

    out = tmp_path / "out"
    lines = []

    def stop_after_one(line):
        lines.append(line)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        farm_frames.render_blend(blend, "1..3", out, "png", False, cluster["address"], log=stop_after_one)
    (first,) = [p for p in out.iterdir() if p.suffix == ".png"]
    stamp = first.stat().st_mtime_ns
    lines.clear()
    written = farm_frames.render_blend(blend, "1..3", out, "png", False, cluster["address"], log=lines.append)
    assert [p.name for p in written] == ["anim_0001.png", "anim_0002.png", "anim_0003.png"]
    assert first.stat().st_mtime_ns == stamp  # kept, not rendered again
    assert sum(".png: " in line and "warning" not in line for line in lines) == 2  # two frames rendered
    assert sorted(p.name for p in out.iterdir()) == [p.name for p in written]
    # the same frames asked again, no job of theirs kept: refused as render-blend refuses
    with pytest.raises(Exception, match="exists"):
        farm_frames.render_blend(blend, "1..3", out, "png", False, cluster["address"])


def test_render_on_cluster_from_blender(blend, cluster, tmp_path):
    """The panel's operator: the saved file through the thurston command in a child process (no
    Ray in Blender), the frame loaded as an image; a clear report for an unsaved file and for a
    cluster that does not answer."""
    bpy = bh.bpy()
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    sc = bpy.context.scene
    sc.thurston.farm_address = cluster["address"]
    sc.thurston.farm_command = str(bh.THURSTON)
    sc.render.filepath = str(tmp_path / "out" / "frame_###")
    sc.frame_current = 2
    saved = tmp_path / "panel.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(saved))
    assert bpy.ops.thurston.farm_render() == {"FINISHED"}
    image = bpy.data.images["frame_002.png"]
    assert tuple(image.size) == (16, 9)
    one = tmp_path / "one"
    one.mkdir()
    assert bh.render_blend(saved, one, "--format", "png", frames="2").returncode == 0
    reference = bpy.data.images.load(str(one / "panel_0002.png"))
    np.testing.assert_array_equal(bh.image_pixels(image), bh.image_pixels(reference))

    sc.thurston.farm_address = "127.0.0.1:1"
    bpy.ops.wm.save_mainfile()
    with pytest.raises(RuntimeError, match="no Ray cluster answers"):
        bpy.ops.thurston.farm_render()
    bh.fresh_scene()  # a new file, never saved
    with pytest.raises(RuntimeError, match="save the .blend file first"):
        bpy.ops.thurston.farm_render()


def test_the_scenes_frame_step_on_the_cluster(blend, cluster, tmp_path):
    """Without --frames, the scene's frame range by its step, as Blender renders an animation; an
    output path with '#' names the frames as Blender's do."""
    bpy = bh.bpy()
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    bpy.context.scene.frame_step = 2
    stepped = tmp_path / "step.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(stepped), copy=True)
    out = tmp_path / "out"
    argv = [str(bh.THURSTON), "render-blend", str(stepped), "--out", str(out / "shot_##"), "--format", "png"]
    run = subprocess.run([*argv, "--cluster", cluster["address"]], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert sorted(p.name for p in out.iterdir()) == ["shot_01.png", "shot_03.png"]


def test_a_worker_without_the_file_renders_the_copy_shipped(blend, tmp_path, monkeypatch):
    """A worker on another machine has no file at the .blend's path: it renders the bytes shipped."""
    import tempfile

    from thurston_addon import images
    from thurston_addon.blender import farm_frames

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the copy (this process is the worker)

    data = blend.read_bytes()
    here = farm_frames.BlendFile(blend.name, data, str(blend))
    elsewhere = farm_frames.BlendFile(blend.name, data, str(tmp_path / "not-here" / blend.name))
    pixels = []
    for key, shipped in (("here", here), ("elsewhere", elsewhere)):
        png, lines = farm_frames.render_frame(shipped, key, 2, "png", "shown.png")
        assert lines and lines[-1].startswith("shown.png: ")
        (tmp_path / f"{key}.png").write_bytes(png)
        pixels.append(images.read_texture(tmp_path / f"{key}.png"))
    np.testing.assert_array_equal(*pixels)
