"""Sampling as a Cycles user sets it (real bpy 5.0.1, background): the render's and the viewport's
settings under Cycles' names, ranges and defaults (against Cycles' own properties), translated into
render.Settings; F12 with adaptive sampling on a scene with a flat region (misses and unlit
surfaces, of one colour) and a noisy one (path-traced surfaces) against the fixed-sample render;
the time limit; a file saved before these settings renders as before; render-blend honours them."""

import math
import re
from types import SimpleNamespace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")

from support import blender_helpers as bh  # noqa: E402

from thurston_addon import progressive, render, scenes  # noqa: E402
from thurston_addon.blender import engine, export  # noqa: E402

SAMPLES = 16
# The settings that Cycles has under the same names, with the same ranges and defaults.
AS_CYCLES = (
    "adaptive_threshold",
    "adaptive_min_samples",
    "time_limit",
    "preview_adaptive_threshold",
    "preview_adaptive_min_samples",
)
# Cycles' switches default to on, its sample counts to 4096 and 1024: here off and 0 (the quality's;
# the viewport's: the render's), so that a file saved before the settings existed renders as then.
SWITCHES = ("use_adaptive_sampling", "use_preview_adaptive_sampling")
COUNTS = ("samples", "preview_samples")
NEW = (*AS_CYCLES, *SWITCHES, "preview_samples")
RNA = (
    "type",
    "name",
    "default",
    "hard_min",
    "hard_max",
    "soft_min",
    "soft_max",
    "precision",
    "step",
    "unit",
    "subtype",
)


def sampling_scene():
    """A lit floor and box below the camera, path traced (one bounce, noisy); above it nothing
    within the distance limit (misses: colour 0, flat); unlit faces are flat too."""
    sc = bh.fresh_scene("torus", size=(40, 24))
    bh.box("Red", 0.15, (0.1, 0.3, -0.05), color=(0.9, 0.2, 0.1))
    bh.box("Floor", (0.8, 0.8, 0.02), (0, 0.2, -0.12), color=(0.5, 0.5, 0.7))
    bh.point_light((0.05, 0.05, 0.1), energy=3.0)
    bh.camera((0, -0.1, 0), lens=30.0)
    t = sc.thurston
    t.samples, t.bounces, t.max_distance = SAMPLES, 1, 0.6
    sc.view_layers[0].use_pass_z = True
    return sc


def combined(channels):
    return bh.rgb(channels, "ViewLayer.Combined.")


def last(sc):
    st = sc.thurston.stats
    assert st.valid
    return st.samples_mean, st.samples_max, st.time_limit_reached


def test_settings_have_cycles_names_ranges_and_defaults():
    sc = bh.fresh_scene()
    ours, cycles = sc.thurston.bl_rna.properties, sc.cycles.bl_rna.properties
    for name in AS_CYCLES:
        for attr in RNA:
            assert getattr(ours[name], attr, None) == getattr(cycles[name], attr, None), (name, attr)
    for name in SWITCHES:
        assert (
            (ours[name].type, ours[name].name)
            == (cycles[name].type, cycles[name].name)
            == ("BOOLEAN", cycles[name].name)
        )
        assert cycles[name].default and not ours[name].default
    for name in COUNTS:
        assert (ours[name].type, ours[name].name) == ("INT", cycles[name].name)
        assert (ours[name].default, ours[name].hard_min, ours[name].hard_max) == (0, 0, 4096)
    assert not set(NEW) & set(sc.thurston.keys())  # nothing stored until set: old files lack them


def test_settings_reach_render_settings_for_render_and_viewport():
    t = bh.fresh_scene().thurston
    t.quality = "standard"

    def both():
        r, v = (export.render_settings(t, 8, 6, viewport=viewport) for viewport in (False, True))
        r.check(), v.check()
        return (r.samples, r.noise_threshold, r.min_samples, r.time_limit), (
            v.samples,
            v.noise_threshold,
            v.min_samples,
            v.time_limit,
        )

    assert both() == ((None, 0.0, 0, None), (None, 0.0, 0, None))  # at the defaults: as before
    t.samples, t.use_adaptive_sampling, t.adaptive_threshold, t.adaptive_min_samples, t.time_limit = 64, 1, 0.02, 8, 2.5
    t.preview_samples, t.use_preview_adaptive_sampling = 32, True
    t.preview_adaptive_threshold, t.preview_adaptive_min_samples = 0.25, 3
    assert both() == ((64, pytest.approx(0.02), 8, 2.5), (32, 0.25, 3, None))  # the viewport has no time limit
    t.preview_samples = 0  # the viewport's 0: the render's samples
    assert both()[1] == (64, 0.25, 3, None)
    t.adaptive_threshold, t.use_preview_adaptive_sampling, t.time_limit = 0.0, False, 0.0  # all off
    assert both() == ((64, 0.0, 0, None), (64, 0.0, 0, None))
    # Min Samples above the samples per pixel (here the quality's 4): every pixel takes them all
    t.samples, t.adaptive_threshold, t.adaptive_min_samples = 0, 0.02, 8
    assert both()[0] == (None, pytest.approx(0.02), render.QUALITY["standard"].samples, None)
    t.use_adaptive_sampling = False  # the switch off: off, whatever the threshold
    assert both()[0] == (None, 0.0, 0, None)


def test_light_paths_reach_render_settings():
    """Light Paths: -1 (the default) automatic, 0 the exact sum, N walks per shaded point."""
    t = bh.fresh_scene().thurston
    assert t.light_paths == -1
    for given, expected in ((-1, None), (0, 0), (6, 6)):
        t.light_paths = given
        settings = export.render_settings(t, 8, 6)
        settings.check()
        assert settings.light_paths == expected
    t.light_paths, t.bounces = -1, 0
    assert export.render_settings(t, 8, 6).light_budget == 0  # direct light: the exact sum
    t.bounces = 2
    assert export.render_settings(t, 8, 6).light_budget == render.PATH_TRACED_LIGHT_PATHS


def test_f12_adaptive_sampling_stops_flat_pixels_and_runs_noisy_ones_to_max(tmp_path):
    """Against the fixed render of the same samples: a pixel that ran to the end is its pixel bit for
    bit; a flat one (every sample the same colour, here 0) stops at Min Samples. The mean samples used
    is what the stopped pixels make it; with a threshold that stops nothing noisy, the stats' max is
    Max Samples."""
    sc = sampling_scene()
    t = sc.thurston
    fixed = bh.f12(sc, tmp_path / "fixed.exr")
    assert last(sc) == (SAMPLES, SAMPLES, False)
    assert "samples per pixel used" not in t.stats.summary
    t.use_adaptive_sampling, t.adaptive_threshold, t.adaptive_min_samples = True, 1e-6, 4
    image = combined(bh.f12(sc, tmp_path / "adaptive.exr"))
    reference = combined(fixed)
    zero = np.all(image == 0, axis=2)
    same = np.all(image == reference, axis=2)
    hit = fixed["ViewLayer.Depth.Z"] < 1e10
    lit = ~np.all(reference == 0, axis=2)
    assert np.all(same | zero)  # every pixel the fixed render's, or stopped flat
    assert np.all(zero[~lit])
    # where they differ, a pixel partly black (misses, unlit faces) whose first 4 samples all saw
    # black (adaptive sampling's blind spot): within 2 pixels of the black, never deeper in the lit
    assert np.all(~same <= ~bh.interior(bh.interior(lit))) and (~same).sum() < 0.03 * same.size
    noisy = ~zero
    assert 0.3 < noisy.mean() < 0.5 and noisy[bh.interior(hit)].mean() > 0.9
    mean, most, reached = last(sc)
    assert most == SAMPLES and not reached
    expected = (4 * zero.sum() + SAMPLES * noisy.sum()) / zero.size
    assert mean == pytest.approx(expected, rel=1e-6) and expected < 0.6 * SAMPLES
    used = f"samples per pixel used: mean {expected:.2f}, max {SAMPLES} (adaptive, noise threshold 1e-06)"
    assert used in t.stats.summary
    # Min Samples 8: the flat pixels take 8, and no more edges are missed
    t.adaptive_min_samples = 8
    image = combined(bh.f12(sc, tmp_path / "adaptive8.exr"))
    zero8 = np.all(image == 0, axis=2)
    assert np.all(zero8 <= zero) and np.all(zero8 | np.all(image == reference, axis=2))
    assert zero8.sum() <= zero.sum()  # (the first 4 samples already spread over each pixel)
    assert last(sc)[0] == pytest.approx((8 * zero8.sum() + SAMPLES * (~zero8).sum()) / zero.size, rel=1e-6)


def test_the_operators_take_the_render_sampling():
    """Render View to Image and Preview (the preview quality's 2 samples: Min Samples 8 becomes 2)."""
    sc = sampling_scene()
    t = sc.thurston
    t.quality, t.samples = "final", 0
    t.use_adaptive_sampling, t.adaptive_threshold, t.adaptive_min_samples = True, 1e-6, 8
    assert bpy.ops.thurston.render_view() == {"FINISHED"}
    mean, most, _ = last(sc)
    assert most == render.QUALITY["final"].samples and 8 < mean < most
    assert bpy.ops.thurston.preview() == {"FINISHED"}
    mean, most, _ = last(sc)
    assert most == render.QUALITY["preview"].samples == 2 and mean == 2


def test_time_limit_zero_is_none_and_a_tiny_one_stops_after_a_whole_pass(tmp_path):
    sc = sampling_scene()
    t = sc.thurston
    t.time_limit = 0.0
    bh.f12(sc, tmp_path / "none.exr")
    assert last(sc) == (SAMPLES, SAMPLES, False)
    t.time_limit = 1e-6
    image = combined(bh.f12(sc, tmp_path / "tiny.exr"))
    assert last(sc) == (1, 1, True)  # one whole pass: every pixel its first sample
    assert "time limit 1e-06 s reached" in t.stats.summary
    assert np.all(np.isfinite(image)) and image.max() > 0.05


def test_a_file_saved_before_the_settings_renders_as_before(tmp_path):
    """No sampling settings stored (as in a file saved before they existed): F12 is the fixed render
    that render.Settings without them gives, bit for bit, every pixel all its samples."""
    sc = sampling_scene()
    assert not set(NEW) & set(sc.thurston.keys())
    blend = tmp_path / "old.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    sc = bpy.context.scene
    image = combined(bh.f12(sc, tmp_path / "old.exr"))
    assert last(sc) == (SAMPLES, SAMPLES, False)
    assert "samples per pixel used" not in sc.thurston.stats.summary
    job = export.RenderJob(sc, bpy.context.evaluated_depsgraph_get())
    settings = render.Settings(width=40, height=24, quality="draft", samples=SAMPLES, bounces=1, max_distance=0.6)
    before = render.render(job.space, job.scene, settings, camera=job.camera, tracer=job.tracer)
    np.testing.assert_array_equal(image, before.passes["color"])


def test_render_blend_honours_the_sampling_settings(tmp_path):
    sc = sampling_scene()
    t = sc.thurston
    t.use_adaptive_sampling, t.adaptive_threshold, t.adaptive_min_samples = True, 1e-6, 4
    f12 = combined(bh.f12(sc, tmp_path / "f12.exr"))
    used = re.search(r"samples per pixel used: mean [0-9.]+, max \d+ \(adaptive[^)]*\)", t.stats.summary)[0]
    blend = tmp_path / "adaptive.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    run = bh.render_blend(blend, tmp_path, "--format", "exr")
    assert run.returncode == 0, run.stderr
    assert f"max {SAMPLES} (adaptive" in used and used in run.stdout + run.stderr
    np.testing.assert_array_equal(combined(bh.read_exr(tmp_path / "adaptive_0001.exr")), f12)
    t.use_adaptive_sampling, t.time_limit = False, 1e-6
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    run = bh.render_blend(blend, tmp_path, "--format", "exr", "--overwrite")
    assert run.returncode == 0, run.stderr
    assert "samples per pixel used: mean 1.00, max 1; time limit 1e-06 s reached" in run.stdout + run.stderr


def test_viewport_takes_its_own_sampling_and_stops_when_every_pixel_is_below_the_threshold():
    """The viewport's job (engine._viewport_job) carries the viewport's settings; its progressive view
    adds samples only to the pixels above the threshold, and is done when none is left: its frame is
    then render()'s adaptive render of the same samples (its pixels, samples used and noise)."""
    from mathutils import Matrix

    sc = sampling_scene()
    t = sc.thurston
    t.use_adaptive_sampling, t.adaptive_threshold = True, 0.5  # the render's: not the viewport's
    t.preview_samples, t.use_preview_adaptive_sampling = 8, True
    t.preview_adaptive_threshold, t.preview_adaptive_min_samples = 1e-6, 2
    # the exact light sum: sampled light learns visibility from the rays traced before in a chunk,
    # which differ where only the pixels still sampling are traced
    t.light_paths = 0
    space = export.load_space(t)
    tracer = render.make_tracer(space, export.export_scene(bpy.context.evaluated_depsgraph_get(), t.scale, []), 2)
    fov = sc.camera.data.angle_x
    window = Matrix.Identity(4)
    window[0][0] = 1 / math.tan(fov / 2)
    view = SimpleNamespace(is_perspective=True, view_matrix=sc.camera.matrix_world.inverted(), window_matrix=window)
    host = SimpleNamespace(_viewport_world=(space, tracer))
    job, settings = engine.ThurstonRenderEngine._viewport_job(host, sc, view, 40, 24)
    assert (settings.samples_per_pixel, settings.noise_threshold, settings.min_samples_per_pixel) == (
        8,
        pytest.approx(1e-6),
        2,
    )
    assert settings.time_limit is None
    log = []

    def logged(level, sample, cancelled):
        log.append(sample)
        return job(level, sample, cancelled)

    pv = progressive.ProgressiveView()
    pv.request("v", logged, 8, settings.noise_threshold, settings.min_samples_per_pixel)
    pv.wait(120)
    frame = pv.frame
    assert pv.error is None and frame.level == 1
    M = np.array(sc.camera.matrix_world, float)
    camera = scenes.Camera(M[:3, 3], -M[:3, 2], M[:3, 1], math.degrees(fov))
    direct = render.render(space, None, settings, camera=camera, tracer=tracer)
    mean = direct.stats["samples_mean"]
    assert 2 < mean < 8 and frame.samples_mean == pytest.approx(mean, rel=0.02)
    same = np.isclose(frame.pixels[::-1, :, :3], direct.passes["color"], rtol=1e-4, atol=1e-5).all(axis=2)
    assert same.mean() > 0.98
    assert frame.noise == pytest.approx(direct.stats["noise"], rel=0.05)
    assert log[-1] == 7 and frame.samples == 8  # the noisy pixels ran to the end
    assert re.fullmatch(
        r"viewport: sample 8/8 \(mean [0-9.]+ per pixel\), noise \S+ \(done\)", engine.viewport_status(frame, 8)
    )
    # a threshold above every pixel's error: all stop at Min Samples, and no sample follows
    log.clear()
    pv.request("w", logged, 8, 10.0, 2)
    pv.wait(120)
    frame = pv.frame
    assert (frame.samples, frame.samples_mean, frame.converged) == (2, 2.0, True)
    assert log == [0, 0, 0, 0, 1]  # sample 0 at each level, then sample 1
    assert engine.viewport_status(frame, 8).endswith("(done)")


class Layout:
    """Records what a panel's draw() shows: (property, text) of each prop."""

    def __init__(self, shown=None):
        self.shown = [] if shown is None else shown

    def column(self, **_):
        return Layout(self.shown)

    row = column

    def prop(self, data, name, text=None, **_):
        self.shown.append((name, text))


def test_the_sampling_panel_shows_cycles_layout_under_thurston():
    sc = bh.fresh_scene()
    t = sc.thurston
    panels = {name: getattr(bpy.types, f"THURSTON_PT_sampling{name}") for name in ("", "_viewport", "_render")}
    assert panels[""].bl_label == "Sampling" and panels[""].bl_context == "render"
    assert [panels[k].bl_label for k in ("_viewport", "_render")] == ["Viewport", "Render"]
    assert {panels[k].bl_parent_id for k in ("_viewport", "_render")} == {"THURSTON_PT_sampling"}
    sc.render.engine = "CYCLES"
    assert not any(p.poll(bpy.context) for p in panels.values())
    sc.render.engine = "THURSTON"
    assert all(p.poll(bpy.context) for p in panels.values())

    def shown(name):
        layout = Layout()
        panels[name].draw(SimpleNamespace(layout=layout), bpy.context)
        return layout.shown

    assert shown("_render") == [
        ("use_adaptive_sampling", ""),
        ("adaptive_threshold", ""),
        ("samples", "Samples"),
        ("time_limit", None),
    ]
    t.use_adaptive_sampling = t.use_preview_adaptive_sampling = True
    assert shown("_render") == [
        ("use_adaptive_sampling", ""),
        ("adaptive_threshold", ""),
        ("samples", "Max Samples"),
        ("adaptive_min_samples", "Min Samples"),
        ("time_limit", None),
    ]
    assert shown("_viewport") == [
        ("use_preview_adaptive_sampling", ""),
        ("preview_adaptive_threshold", ""),
        ("preview_samples", "Max Samples"),
        ("preview_adaptive_min_samples", "Min Samples"),
    ]
    assert shown("") == []
