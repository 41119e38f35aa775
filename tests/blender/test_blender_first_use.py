"""A user's first renders (real bpy 5.0.1, background): Blender's startup scene (a cube, a 1000 W
point light, a camera) under every preset, shells included, after Fit Scale; the render report's one
note and its fix; the exposure proposed from the gathered light and Set Exposure; Bring Camera
Inside on a constrained and on an animated camera. Pixels are judged as Blender shows them: the
Render Result saved through the scene's view transform."""

import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")

from support import blender_helpers as bh  # noqa: E402
from support.presets import presets  # noqa: E402

from thurston_addon import checks  # noqa: E402
from thurston_addon.blender import domain_guide, export  # noqa: E402


def note_kinds(sc):
    return {n.kind for n in sc.thurston.stats.notes}


def startup_scene(space=None, size=(bh.W, bh.H)):
    """Blender's factory startup scene with the engine switched to Thurston: draft, two threads."""
    bpy.ops.wm.read_factory_settings(use_empty=False)
    sc = bpy.context.scene
    sc.render.engine = "THURSTON"
    sc.render.resolution_x, sc.render.resolution_y = size
    sc.render.resolution_percentage = 100
    sc.thurston.quality = "draft"
    sc.thurston.threads = 2
    if space is not None:
        sc.thurston.space = space
    sc.view_layers[0].use_pass_z = True
    return sc


def shown(sc, tmp_path, name, view_transform=None):
    """F12, then (hit mask, the pixels' grey levels as Blender shows them: the Render Result saved
    as an 8-bit PNG through the scene's view transform and exposure)."""
    if view_transform is not None:
        sc.view_settings.view_transform = view_transform
    channels = bh.f12(sc, tmp_path / f"{name}.exr")
    hit = channels["ViewLayer.Depth.Z"] < 1e9
    png = tmp_path / f"{name}.png"
    settings = sc.render.image_settings
    settings.media_type, settings.file_format, settings.color_depth = "IMAGE", "PNG", "8"
    bpy.data.images["Render Result"].save_render(str(png), scene=sc)
    image = bpy.data.images.load(str(png))
    try:
        grey = bh.image_pixels(image)[..., :3].mean(axis=-1)
    finally:
        bpy.data.images.remove(image)
    return hit, grey


def assert_lit(hit, grey, least=3):
    """Surfaces show (some pixels hit), and most of them neither black nor white."""
    assert hit.sum() >= least, f"{hit.sum()} pixels hit"
    values = grey[hit]
    assert 0.05 < np.median(values) < 0.95, np.quantile(values, [0.1, 0.5, 0.9])
    assert np.mean((values > 0.05) & (values < 0.95)) > 0.5, np.quantile(values, [0.1, 0.5, 0.9])


# --- A. every preset, shells included (graph's are unlit: support.presets.SWEPT_APART) -----------------------
@pytest.mark.parametrize("space", presets())
def test_fit_scale_shows_the_startup_scene_lit_in_every_preset(tmp_path, space):
    """Fit Scale alone (the scale, in a shell the scene moved to the domain's centre, the exposure
    measured) turns the startup scene into a lit image in each preset: hits, most neither black nor
    white under Standard, and no note but the camera's (outside: the same view)."""
    sc = startup_scene(space)
    assert bpy.ops.thurston.fit_scale() == {"FINISHED"}
    hit, grey = shown(sc, tmp_path, space, "Standard")
    assert_lit(hit, grey)
    assert note_kinds(sc) <= {checks.CAMERA_OUTSIDE}, [n.message for n in sc.thurston.stats.notes]


@pytest.mark.parametrize("space", ["s2xs1", "rp3_rp3"])
def test_a_shell_scene_goes_to_the_domains_centre(space):
    """In a shell the chart's origin is no point of the space: a scene about it is too large (a
    note naming Fit Scale), and Fit Scale moves it, camera and light with it, into the shell's
    middle, about the domain's centre."""
    sc = startup_scene(space)
    job = export.RenderJob(sc, bpy.context.evaluated_depsgraph_get(), bh.W, bh.H)
    (note,) = job.notes
    assert note.kind == checks.SCENE_TOO_LARGE and "origin" in note.message
    before = {o.name: np.array(o.location) for o in sc.objects}
    assert bpy.ops.thurston.fit_scale() == {"FINISHED"}
    shell = export.load_space(sc.thurston)
    moved = {o.name: np.array(o.location) - before[o.name] for o in sc.objects}
    np.testing.assert_allclose(moved["Camera"], moved["Cube"], atol=1e-5)
    np.testing.assert_allclose(moved["Light"], moved["Cube"], atol=1e-5)
    cube = np.array(sc.objects["Cube"].location) / sc.thurston.scale
    assert shell.radii[0] < np.linalg.norm(cube) < shell.radii[1]
    assert shell.size_ratio(cube + np.array([[-1.0, -1, -1], [1, 1, 1]]) / sc.thurston.scale) > 1 / checks.TOO_SMALL


def test_a_hand_placed_shell_scene_is_judged_where_it_lies(tmp_path):
    """A cube placed by hand in the middle of s2xs1's shell, metres across at scale 1, is a speck
    there (the metric is |dx| / |x|): the note says so; Fit Scale then keeps it there, larger."""
    sc = bh.fresh_scene("s2xs1")
    sc.render.engine = "THURSTON"
    middle = -0.5 * (1 + math.exp(2 * math.pi))
    bh.box("Cube", 2.0, (0, middle, 0))
    bh.point_light((1.5, middle - 1.5, 1.5), energy=100.0)
    bh.camera((0, middle - 6, 0), lens=30.0)
    sc.view_layers[0].use_pass_z = True
    bh.f12(sc, tmp_path / "speck.exr")
    assert checks.SCENE_TOO_SMALL in note_kinds(sc)
    assert bpy.ops.thurston.fit_scale() == {"FINISHED"}
    hit, grey = shown(sc, tmp_path, "fitted", "Standard")
    assert_lit(hit, grey)
    assert checks.SCENE_TOO_SMALL not in note_kinds(sc)


# --- B. first use of the startup scene ----------------------------------------------------------------
@pytest.mark.parametrize("view_transform", ["AgX", "Standard"])
def test_first_use_one_note_one_fix(tmp_path, view_transform):
    """F12 on the startup scene (Poincaré space, scale 1): one note, the cube larger than the domain,
    naming Fit Scale; after it, the cube and its copies lit, most pixels neither black nor white
    under Blender's default view transform (AgX) and Standard; the light's power as it was."""
    sc = startup_scene(size=(96, 54))
    assert sc.view_settings.view_transform == "AgX"  # Blender 5's default
    bh.f12(sc, tmp_path / "first.exr")
    notes = list(sc.thurston.stats.notes)
    assert [n.kind for n in notes] == [checks.SCENE_TOO_LARGE], [n.message for n in notes]
    assert "'Cube'" in notes[0].message and "Fit Scale" in notes[0].message
    assert bpy.ops.thurston.fit_scale() == {"FINISHED"}
    assert sc.objects["Light"].data.energy == 1000.0
    hit, grey = shown(sc, tmp_path, "fitted", view_transform)
    assert_lit(hit, grey, least=200)
    assert note_kinds(sc) <= {checks.CAMERA_OUTSIDE}


def test_exposure_note_and_set_exposure(tmp_path):
    """A light made 1000 times stronger after Fit Scale: the report says the lit surfaces show white
    and proposes an exposure (Set Exposure); it sets Color Management's exposure, the light's power
    stays, and the next render is neither black nor white, with no note about the light."""
    sc = startup_scene()
    assert bpy.ops.thurston.fit_scale() == {"FINISHED"}
    light = sc.objects["Light"].data
    light.energy *= 1000
    _, grey = shown(sc, tmp_path, "white", "Standard")
    (note,) = [n for n in sc.thurston.stats.notes if n.kind == checks.EXPOSURE]
    assert "white" in note.message and "Set Exposure" in note.message
    assert note.value < sc.view_settings.exposure - 9
    assert bpy.ops.thurston.set_exposure() == {"FINISHED"}
    assert sc.view_settings.exposure == pytest.approx(note.value)
    assert light.energy == pytest.approx(1e6)
    hit, grey = shown(sc, tmp_path, "set", "Standard")
    assert_lit(hit, grey)
    assert checks.EXPOSURE not in note_kinds(sc) and checks.UNLIT not in note_kinds(sc)


def test_set_exposure_without_a_proposal():
    sc = startup_scene()
    sc.thurston.stats.notes.clear()
    with pytest.raises(RuntimeError, match="proposed no exposure"):
        bpy.ops.thurston.set_exposure()


# --- C. Bring Camera Inside on constrained and animated cameras --------------------------------------------
def fitted_torus_scene():
    sc = startup_scene("torus")
    assert bpy.ops.thurston.fit_scale() == {"FINISHED"}
    assert domain_guide.camera_outside(sc)
    return sc


def colour(sc, tmp_path, name):
    return bh.rgb(bh.f12(sc, tmp_path / f"{name}.exr"), "ViewLayer.Combined.")


def test_camera_inside_keeps_a_tracking_cameras_view(tmp_path):
    """A camera with a Track To constraint (aimed at the light, away from where its rotation
    points): brought inside from its evaluated matrix, its constraint muted, the view the same."""
    sc = fitted_torus_scene()
    cam = sc.camera
    track = cam.constraints.new("TRACK_TO")
    track.target = sc.objects["Light"]
    track.track_axis, track.up_axis = "TRACK_NEGATIVE_Z", "UP_Y"
    bpy.context.view_layer.update()
    before = colour(sc, tmp_path, "before")
    kinds = note_kinds(sc)
    assert checks.CAMERA_OUTSIDE in kinds
    (note,) = [n for n in sc.thurston.stats.notes if n.kind == checks.CAMERA_OUTSIDE]
    assert "muting its constraints ('Track To')" in note.message
    assert bpy.ops.thurston.camera_inside() == {"FINISHED"}
    bpy.context.view_layer.update()
    assert not track.enabled and not domain_guide.camera_outside(sc)
    after = colour(sc, tmp_path, "after")
    assert np.ptp(before) > 0.05
    assert np.abs(after - before).mean() < 1e-3 * (1 + np.abs(before).mean())


def test_an_animated_camera_outside_is_not_offered_the_fix(tmp_path):
    """A keyframed camera outside the domain: the note says the render is the same and names no
    fix; Bring Camera Inside refuses it, saying why, and leaves it where it was."""
    sc = fitted_torus_scene()
    cam = sc.camera
    cam.keyframe_insert("location", frame=1)
    bh.f12(sc, tmp_path / "animated.exr")
    notes = list(sc.thurston.stats.notes)
    assert [n.kind for n in notes] == [export.CAMERA_OUTSIDE_ANIMATED], [n.message for n in notes]
    assert "Bring Camera Inside" not in notes[0].message and "animated" in notes[0].message
    assert export.FIXES.get(notes[0].kind) is None
    before = np.array(cam.matrix_world)
    with pytest.raises(RuntimeError, match="animated"):
        bpy.ops.thurston.camera_inside()
    np.testing.assert_array_equal(np.array(cam.matrix_world), before)
