"""Progressive rendering off the calling thread, for interactive views (Blender's rendered viewport):
each requested view is traced coarse to fine on a worker thread, the newest finished level is kept
for drawing, and a new request cancels the frame in progress. No Blender here."""
from __future__ import annotations

import threading
from typing import Callable

import numpy as np

# Pixel block sizes, coarse to fine: the first frame is cheap, each next one four times the rays.
LEVELS = (8, 4, 2, 1)


class ProgressiveView:
    """`render(level, cancelled) -> pixels` traces one frame at 1/level of the resolution, polling
    `cancelled()` (a progress callback returning False when it is true stops the trace); it runs on
    the worker thread and must not touch Blender data."""

    def __init__(self):
        self._lock = threading.Lock()
        self._key = None
        self._generation = 0
        self._thread: threading.Thread | None = None
        self._frame = None  # (key, level, pixels) of the newest finished level
        self.error: Exception | None = None

    def request(self, key, render: Callable[[int, Callable[[], bool]], np.ndarray]):
        """Trace the view `key` (anything comparable: size, view matrix, scene version) unless it is
        the one being traced or shown; cancels the frame of any other key."""
        with self._lock:
            if key == self._key:
                return
            self._key = key
            self._generation += 1
            generation = self._generation
            self.error = None
        self._thread = threading.Thread(target=self._run, args=(generation, key, render), daemon=True)
        self._thread.start()

    def cancel(self):
        with self._lock:
            self._generation += 1
            self._key = None

    def _run(self, generation, key, render):
        def cancelled():
            return generation != self._generation

        for level in LEVELS:
            if cancelled():
                return
            try:
                pixels = render(level, cancelled)
            except Exception as exc:  # cancelled or failed: a failure is shown by the caller
                with self._lock:
                    if not cancelled():
                        self.error = exc
                return
            with self._lock:
                if cancelled():
                    return
                self._frame = (key, level, pixels)

    @property
    def frame(self):
        """(key, level, pixels) of the newest finished frame, or None."""
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
