"""The progressive view behind Blender's rendered viewport (no Blender needed): coarse-to-fine frames
on a worker thread, the newest kept, a new request cancelling the frame in progress."""
import threading

import numpy as np

from thurston_addon import progressive, render, spaces
from thurston_addon.scene import Camera, default_scene


def space_camera(space):
    c = space.camera
    return Camera(c.position, c.forward, c.up, c.fov)


def frames_of(space, tracer, size, quality, log):
    """render(level, cancelled) at 1/level of `size` from the space's camera, recording what
    happened to each level."""
    camera = space_camera(space)

    def frame(level, cancelled):
        settings = render.Settings(width=size[0] // level, height=size[1] // level, quality=quality, threads=2)
        try:
            result = render.render(space, None, settings, camera=camera, tracer=tracer,
                                   progress=lambda done, total: not cancelled())
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
    key, level, pixels = view.frame
    assert (key, level) == ("first", 1) and [e for e, _ in first] == ["done"] * len(progressive.LEVELS)
    direct = render.render(space, None, render.Settings(width=64, height=32, quality="draft", threads=2),
                           camera=space_camera(space), tracer=tracer)
    np.testing.assert_array_equal(pixels, direct.passes["color"])

    # the same key again: nothing is traced
    view.request("first", frames_of(space, tracer, (64, 32), "draft", first))
    assert not view.busy and len(first) == len(progressive.LEVELS)

    # a slow view, replaced by a quick one while its first level is being traced
    slow, quick = [], []
    started = threading.Event()

    def slow_frame(level, cancelled):
        started.set()
        return frames_of(space, tracer, (2048, 1024), "final", slow)(level, cancelled)

    view.request("slow", slow_frame)
    assert started.wait(60)
    view.request("quick", frames_of(space, tracer, (32, 16), "draft", quick))
    view.wait(120)
    for thread in threading.enumerate():
        if thread is not threading.current_thread() and thread.daemon:
            thread.join(120)
    assert slow == [("cancelled", progressive.LEVELS[0])]  # stopped inside its first level
    assert view.frame[:2] == ("quick", 1) and view.error is None
