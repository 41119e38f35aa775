"""The progressive view behind Blender's rendered viewport (no Blender needed): coarse-to-fine frames
on a worker thread, the newest kept, a new request cancelling the frame in progress; then samples
added up to the count, their running mean the F12 render's."""

import threading
from dataclasses import replace

import numpy as np
import pytest

from thurston_addon import progressive, render, spaces
from thurston_addon.scenes import Camera, default_scene


def space_camera(space):
    c = space.camera
    return Camera(c.position, c.forward, c.up, c.fov)


def frames_of(space, tracer, size, quality, log):
    """trace_frame(level, sample, cancelled) at 1/level of `size` from the space's camera (one
    sample), recording what happened to each level."""
    camera = space_camera(space)

    def frame(level, sample, cancelled):
        settings = render.Settings(width=size[0] // level, height=size[1] // level, quality=quality, threads=2)
        try:
            result = render.render(
                space, None, settings, camera=camera, tracer=tracer, progress=lambda done, total: not cancelled()
            )
        except render.Cancelled:
            log.append(("cancelled", level))
            raise
        log.append(("done", level))
        return result.passes["color"]

    return frame


def test_progressive_view_refines_then_a_new_request_cancels():
    space = spaces.load("torus")
    tracer = render.make_tracer(space, default_scene(space))
    view = progressive.ProgressiveView()
    first = []
    view.request("first", frames_of(space, tracer, (64, 32), "draft", first))
    view.wait(120)
    key, level, pixels = view.frame.key, view.frame.level, view.frame.pixels
    assert (key, level, view.frame.samples) == ("first", 1, 1) and [e for e, _ in first] == ["done"] * len(
        progressive.LEVELS
    )
    direct = render.render(
        space,
        None,
        render.Settings(width=64, height=32, quality="draft", threads=2),
        camera=space_camera(space),
        tracer=tracer,
    )
    np.testing.assert_array_equal(pixels, direct.passes["color"])

    # the same key again: nothing is traced
    view.request("first", frames_of(space, tracer, (64, 32), "draft", first))
    assert not view.busy and len(first) == len(progressive.LEVELS)

    # a slow view, replaced by a quick one while its first level is being traced
    slow, quick = [], []
    started = threading.Event()

    def slow_frame(level, sample, cancelled):
        started.set()
        return frames_of(space, tracer, (2048, 1024), "final", slow)(level, sample, cancelled)

    view.request("slow", slow_frame)
    assert started.wait(60)
    view.request("quick", frames_of(space, tracer, (32, 16), "draft", quick))
    view.wait(120)
    for thread in threading.enumerate():
        if thread is not threading.current_thread() and thread.daemon:
            thread.join(120)
    assert slow == [("cancelled", progressive.LEVELS[0])]  # stopped inside its first level
    assert (view.frame.key, view.frame.level) == ("quick", 1) and view.error is None


def accumulating(space, tracer, size, samples, settings, log=None):
    """The viewport's trace_frame (as engine._viewport_job makes it): sample k of `samples` as a
    one-sample render (progressive.one_sample)."""
    camera = space_camera(space)

    def frame(level, sample, cancelled):
        view = replace(settings, width=size[0] // level, height=size[1] // level)
        shifted, one = progressive.one_sample(camera, view, sample, samples)
        result = render.render(
            space, None, one, camera=shifted, tracer=tracer, progress=lambda done, total: not cancelled()
        )
        if log is not None:
            log.append((level, sample))
        return result.passes["color"]

    return frame


def test_samples_accumulate_to_the_final_render_with_its_noise():
    """With bounces, after the full-resolution frame the view adds samples up to the count: after
    n of them its frame is the mean of n one-sample renders, each of them the ray and random numbers
    of sample k of render() with n samples, so the mean is that render's image (the same rays up
    to the rounding of a lens shift against a jitter: equal but at a few silhouette pixels), and its
    noise estimate render()'s."""
    space = spaces.load("torus")
    tracer = render.make_tracer(space, default_scene(space))
    size, samples = (48, 27), 4
    settings = render.Settings(
        width=size[0], height=size[1], samples=samples, bounces=2, seed=5, quality="draft", threads=2
    )
    view = progressive.ProgressiveView()
    log = []
    view.request("gi", accumulating(space, tracer, size, samples, settings, log), samples)
    view.wait(300)
    assert view.error is None
    assert log == [(level, 0) for level in progressive.LEVELS] + [(1, k) for k in range(1, samples)]
    frame = view.frame
    assert (frame.level, frame.samples) == (1, samples)
    final = render.render(space, None, settings, camera=space_camera(space), tracer=tracer)
    same = np.all(np.isclose(frame.pixels, final.passes["color"], rtol=1e-5, atol=1e-6), axis=2)
    print(f"pixels equal to render()'s: {same.mean():.4f}; noise {frame.noise:.4e} vs {final.stats['noise']:.4e}")
    assert same.mean() > 0.99
    assert frame.noise == pytest.approx(final.stats["noise"], rel=0.03)


def test_a_new_request_cancels_the_accumulation():
    """A view that would add 64 samples, replaced after its second: no sample of it follows."""
    space = spaces.load("torus")
    tracer = render.make_tracer(space, default_scene(space))
    settings = render.Settings(samples=64, bounces=1, quality="draft")
    view = progressive.ProgressiveView()
    log = []
    second = threading.Event()

    def watched(level, sample, cancelled):
        pixels = accumulating(space, tracer, (32, 18), 64, settings, log)(level, sample, cancelled)
        if sample == 2:
            second.set()
        return pixels

    view.request("long", watched, 64)
    assert second.wait(120)
    view.request("short", accumulating(space, tracer, (16, 9), 1, settings), 1)
    view.wait(120)
    assert (view.frame.key, view.frame.samples) == ("short", 1)
    assert max(k for _, k in log) <= 3 < 63


def test_one_sample_is_sample_k_of_the_render():
    """A one-sample render of one_sample(k) traces the rays of sample k of an n-sample render: the
    shifted camera's view directions at the pixel centres against render's jittered ones, and the
    seed render gives that sample (its passes count from the centre pass where there is one)."""
    camera = Camera((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), 70.0)
    settings = render.Settings(width=40, height=30, seed=7)
    for n, first in ((5, 7), (4, 8)):  # 5 samples: one at the centre; 4: a centre pass first
        for k, jitter in enumerate(render.sample_offsets(n)):
            moved, one = progressive.one_sample(camera, settings, k, n)
            np.testing.assert_allclose(
                render.view_directions(moved, one), render.view_directions(camera, settings, jitter), atol=1e-14
            )
            assert (one.samples, one.seed) == (1, first + k)


def test_adaptive_accumulation_is_the_adaptive_render():
    """With a noise threshold the view adds each sample only to the pixels whose standard error is
    still above it after min samples: its frame is render()'s adaptive render of the same samples
    (pixels, samples used, noise), equal but at a few silhouette pixels (see above); a threshold
    above every pixel's error stops them all at min samples, and no sample follows."""
    space = spaces.load("torus")
    tracer = render.make_tracer(space, default_scene(space))
    size, samples = (48, 27), 8
    settings = render.Settings(
        width=size[0],
        height=size[1],
        samples=samples,
        bounces=1,
        quality="draft",
        threads=2,
        noise_threshold=0.03,
        min_samples=3,
        # the exact light sum: sampled light learns visibility from the rays traced before in a
        # chunk, which differ where only the pixels still sampling are traced
        light_paths=0,
    )
    view = progressive.ProgressiveView()
    view.request("a", accumulating(space, tracer, size, samples, settings), samples, 0.03, 3)
    view.wait(300)
    assert view.error is None
    frame = view.frame
    final = render.render(space, None, settings, camera=space_camera(space), tracer=tracer)
    print(f"samples used: view {frame.samples_mean:.3f}, render {final.stats['samples_mean']:.3f}")
    assert 3 < final.stats["samples_mean"] < samples - 1
    assert frame.samples_mean == pytest.approx(final.stats["samples_mean"], rel=0.01)
    same = np.all(np.isclose(frame.pixels, final.passes["color"], rtol=1e-5, atol=1e-6), axis=2)
    assert same.mean() > 0.98
    assert frame.noise == pytest.approx(final.stats["noise"], rel=0.03)
    log = []
    view.request("b", accumulating(space, tracer, size, samples, settings, log), samples, 10.0, 3)
    view.wait(300)
    assert (view.frame.samples, view.frame.samples_mean, view.frame.converged) == (3, 3.0, True)
    assert log == [(level, 0) for level in progressive.LEVELS] + [(1, 1), (1, 2)]
