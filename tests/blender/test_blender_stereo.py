"""Stereoscopy through the Thurston engine against Cycles: a glowing ball 0.4 ahead in the 3-torus
(nearer than any of its copies, with the clip end and the distance limit at 0.45, so that Cycles'
one cell is the same scene), both eyes' views of F12 with Blender's Stereo 3D and individual view
files; the ball's brightness-weighted centre in each view within 0.3 pixel of Cycles' for each
convergence mode and pivot, and for an equirectangular camera's omni-directional stereo. Also
render-blend's view files, the stereo Bake Panorama, and Multi-View refused with its reason."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage
from support import blender_helpers as bh

pytestmark = pytest.mark.blender


def stereo_scene(panorama=False, mode="OFFAXIS", pivot="LEFT", size=(96, 54)):
    bpy = bh.bpy()
    sc = bh.fresh_scene("torus", size=size)
    sc.thurston.max_distance = 0.45
    sc.thurston.samples = 16
    sc.cycles.samples = 16
    sc.cycles.device = "CPU"
    sc.view_settings.view_transform = "Standard"
    sc.render.dither_intensity = 0.0  # no noise in the PNGs' background
    glow = bh.material("glow", color=(0, 0, 0), emission=(1, 1, 1), strength=1.0)
    bpy.ops.mesh.primitive_ico_sphere_add(radius=0.03, location=(0.0, 0.4, 0.0), subdivisions=3)
    bpy.context.active_object.data.materials.append(glow)
    camera = bh.camera()
    camera.data.clip_end = 0.45
    if panorama:
        camera.data.type = "PANO"
        camera.data.panorama_type = "EQUIRECTANGULAR"
        camera.data.stereo.use_spherical_stereo = True
    stereo = camera.data.stereo
    stereo.interocular_distance, stereo.convergence_distance = 0.2, 1.0
    stereo.convergence_mode, stereo.pivot = mode, pivot
    sc.render.use_multiview = True
    sc.render.views_format = "STEREO_3D"
    sc.render.image_settings.file_format = "PNG"
    sc.render.image_settings.views_format = "INDIVIDUAL"
    return sc


def ball_centres(path):
    """The brightness-weighted column of the ball in the _L and _R files of `path` (NaN: not seen)."""
    import OpenImageIO as oiio

    centres = []
    for view in ("_L", "_R"):
        image = oiio.ImageInput.open(str(path.with_name(path.stem + view + path.suffix)))
        pixels = np.asarray(image.read_image("float"))
        image.close()
        brightness = pixels[..., :3].mean(axis=-1)
        centres.append(ndimage.center_of_mass(brightness)[1] if brightness.max() > 0.5 else np.nan)
    return np.array(centres)


@pytest.mark.parametrize(
    "panorama, mode, pivot",
    [(False, "OFFAXIS", "LEFT"), (False, "TOE", "CENTER"), (False, "PARALLEL", "RIGHT"), (True, "OFFAXIS", "CENTER")],
)
def test_both_eyes_see_the_ball_where_cycles_does(registered_addon, tmp_path, panorama, mode, pivot):
    bpy = bh.bpy()
    found = {}
    for engine in ("THURSTON", "CYCLES"):
        sc = stereo_scene(panorama, mode, pivot, size=(128, 64) if panorama else (96, 54))
        sc.render.engine = engine
        sc.render.filepath = str(tmp_path / f"{engine}.png")
        bpy.ops.render.render(write_still=True)
        found[engine] = ball_centres(tmp_path / f"{engine}.png")
    seen = np.isfinite(found["CYCLES"])  # (pivot right: the left eye's view misses the ball)
    assert seen.any() and np.array_equal(seen, np.isfinite(found["THURSTON"]))
    assert np.abs(found["THURSTON"][seen] - found["CYCLES"][seen]).max() < 0.3, found
    if seen.all():
        assert abs(np.subtract(*found["THURSTON"])) > 2, found  # the eyes differ


def test_render_blend_writes_each_view_and_keeps_them(registered_addon, tmp_path):
    bpy = bh.bpy()
    stereo_scene(size=(32, 18))
    bpy.context.scene.thurston.samples = 1
    blend = tmp_path / "pair.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    done = bh.render_blend(blend, tmp_path / "out", "--format", "png")
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["pair_0001_L.png", "pair_0001_R.png"]
    again = bh.render_blend(blend, tmp_path / "out", "--format", "png")
    assert again.returncode == 2 and "pair_0001_L.png" in again.stderr and "--overwrite" in again.stderr


def test_a_stereo_bake_is_a_top_bottom_pair(registered_addon):
    bpy = bh.bpy()
    sc = stereo_scene(size=(32, 18))
    sc.render.use_multiview = False  # the bake takes the camera's Stereoscopy settings on its own
    sc.thurston.samples = 1
    sc.thurston.panorama_width = 64
    sc.thurston.panorama_stereo = True
    assert bpy.ops.thurston.bake_panorama() == {"FINISHED"}
    pair = bh.image_pixels(bpy.data.images["Thurston Stereo Panorama"])
    assert pair.shape[:2] == (64, 64)  # 2:1 per eye, left on top
    left, right = pair[:32, :, :3].mean(axis=-1), pair[32:, :, :3].mean(axis=-1)
    assert left.max() > 0.5 and right.max() > 0.5
    assert ndimage.center_of_mass(left)[1] > ndimage.center_of_mass(right)[1] + 1  # the left eye sees it to the right


def test_multi_view_is_refused_with_its_reason(registered_addon, tmp_path):
    bpy = bh.bpy()
    sc = stereo_scene(size=(32, 18))
    sc.render.views_format = "MULTIVIEW"
    sc.render.engine = "THURSTON"
    with pytest.raises(RuntimeError, match="Multi-View .* is not supported; choose Stereo 3D"):
        bpy.ops.render.render()


@pytest.mark.parametrize(
    "kind, fix",
    [
        ({"type": "ORTHO"}, "only perspective cameras and equirectangular panoramas"),
        ({"type": "PANO", "panorama_type": "FISHEYE_EQUIDISTANT"}, "is fisheye equidistant panorama"),
        ({"type": "PANO", "panorama_type": "EQUIRECTANGULAR", "latitude_max": 1.0}, "latitude to -90..90"),
    ],
)
def test_cameras_that_cannot_be_rendered_are_refused_with_the_reason(registered_addon, kind, fix):
    bpy = bh.bpy()
    sc = stereo_scene(size=(32, 18))
    sc.render.use_multiview = False
    for key, value in kind.items():
        setattr(sc.camera.data, key, value)
    sc.render.engine = "THURSTON"
    with pytest.raises(RuntimeError, match=fix):
        bpy.ops.render.render()
