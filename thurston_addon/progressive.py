"""Progressive rendering off the calling thread, for interactive views (Blender's rendered viewport):
each requested view is traced coarse to fine on a worker thread, then, as Cycles' viewport does,
more samples of the full-resolution frame are added to it up to the sample count (the running mean
and its noise estimate shown), under adaptive sampling only to the pixels not yet below the noise
threshold, until none is left; the newest finished frame is kept for drawing, and a new request
cancels the one in progress. No Blender here."""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from . import render

# Pixel block sizes, coarse to fine: the first frame is cheap, each next one four times the rays.
LEVELS = (8, 4, 2, 1)


@dataclass(frozen=True)
class Frame:
    """A finished frame: the view's key, its level (pixel block size), its pixels (where level is
    1, each pixel the mean of the full-resolution samples it took: `samples` of them, fewer where
    adaptive sampling stopped it), and the noise estimate of those means (render.pixel_noise, as
    render's with adaptive sampling; None below two samples). Under adaptive sampling also the
    samples per pixel taken, their mean, and `converged`: no pixel takes more."""

    key: Any
    level: int
    pixels: np.ndarray
    samples: int = 1
    noise: float | None = None
    samples_mean: float | None = None
    converged: bool = False


def one_sample(camera, settings, k: int, n: int):
    """(camera, settings) whose one-sample render is sample k of the n-sample render of `settings`
    from `camera`: render's sub-pixel position of sample k as a lens shift (the same rays up to
    rounding) and its random numbers (render numbers its passes from settings.seed, first the
    unshaded centre pass where no sample lies at the centre). One sample: no adaptive sampling nor
    time limit within it (the view applies them between samples)."""
    offsets = render.sample_offsets(n)
    x, y = offsets[k]
    W = settings.width
    shifted = replace(camera, shift=(camera.shift[0] + (x - 0.5) / W, camera.shift[1] - (y - 0.5) / W))
    one = replace(settings, samples=1, seed=settings.seed + k + (render.CENTRE not in offsets))
    return shifted, replace(one, noise_threshold=0.0, min_samples=0, time_limit=None)


class ProgressiveView:
    """`trace_frame(level, sample, cancelled) -> pixels` traces one frame at 1/level of the resolution
    (sample 0 at every level, then samples 1 .. samples - 1 at level 1; one_sample makes
    them), polling `cancelled()` (a progress callback returning False when it is true stops the
    trace); it runs on the worker thread and must not touch Blender data. Pixels: (h, w, c),
    the colour in their first three channels."""

    def __init__(self):
        self._lock = threading.Lock()
        self._key = None
        self._generation = 0
        self._thread: threading.Thread | None = None
        self._frame: Frame | None = None
        self.error: Exception | None = None

    def request(
        self,
        key,
        trace_frame: Callable[[int, int, Callable[[], bool]], np.ndarray],
        samples: int = 1,
        noise_threshold: float = 0.0,
        min_samples: int = 1,
    ):
        """Trace the view `key` (anything comparable: size, view matrix, scene version, sample
        count) unless it is the one being traced or shown; cancels the frame of any other key.
        Adaptive sampling (render.Settings' noise_threshold > 0, with its min_samples_per_pixel): a
        pixel whose standard error is below noise_threshold after min_samples takes no more, and
        when no pixel takes more the view is done."""
        with self._lock:
            if key == self._key:
                return
            self._key = key
            self._generation += 1
            generation = self._generation
            self.error = None
        self._thread = threading.Thread(
            target=self._run,
            args=(generation, key, trace_frame, samples, noise_threshold, min_samples),
            daemon=True,
        )
        self._thread.start()

    def cancel(self):
        with self._lock:
            self._generation += 1
            self._key = None

    def _run(self, generation, key, trace_frame, samples, noise_threshold=0.0, min_samples=1):
        def cancelled():
            return generation != self._generation

        total = squares = taken = None
        active = None  # adaptive sampling: the pixels still taking samples (None: all)
        for level, sample in [(level, 0) for level in LEVELS] + [(1, k) for k in range(1, samples)]:
            if cancelled():
                return
            try:
                pixels = trace_frame(level, sample, cancelled)
            except Exception as exc:  # cancelled or failed: a failure is shown by the caller
                with self._lock:
                    if not cancelled():
                        self.error = exc
                return
            if level > 1:
                frame = Frame(key, level, pixels)
            else:  # the running mean of the full-resolution samples (of the pixels taking them)
                pixels = np.asarray(pixels, np.float64)
                took = np.ones(pixels.shape[:2], bool) if active is None else active.reshape(pixels.shape[:2])
                pixels = pixels * took[..., None]
                brightness = pixels[..., :3].mean(axis=-1).ravel()
                total = pixels if total is None else total + pixels
                squares = brightness**2 if squares is None else squares + brightness**2
                taken = took.ravel().astype(np.int64) if taken is None else taken + took.ravel()
                n = sample + 1
                colours = total[..., :3].reshape(-1, 3)
                if noise_threshold > 0 and min_samples <= n < samples:
                    below = render.pixel_errors(colours, squares, taken) < noise_threshold
                    active = ~below if active is None else active & ~below
                frame = Frame(
                    key,
                    1,
                    (total / taken.reshape(*pixels.shape[:2], 1)).astype(np.float32),
                    n,
                    render.pixel_noise(colours, squares, n)
                    if np.all(taken == n)
                    else render.noise_of(colours, squares, taken),
                    None if noise_threshold <= 0 else float(taken.mean()),
                    active is not None and not active.any(),
                )
            with self._lock:
                if cancelled():
                    return
                self._frame = frame
            if frame.converged:
                return

    @property
    def frame(self) -> Frame | None:
        """The newest finished frame, or None."""
        with self._lock:
            return self._frame

    @property
    def busy(self) -> bool:
        thread = self._thread
        return thread is not None and thread.is_alive()

    def wait(self, timeout=None):
        """Until the worker has finished (for batch use and tests)."""
        thread = self._thread
        if thread is not None:
            thread.join(timeout)
