"""What the tests of outputs share: a small real file system to fill or make read-only, the
folder's listing, the one error line a failed run prints, the words an error message must never
show, and a signal to a running `thurston`."""

import contextlib
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

PREVIOUS = b"the user's previous file\n"
# what an error message must never show: Python's and Qhull's own words
INTERNALS = re.compile(
    r"object is not|has no attribute|not subscriptable|unhashable|Traceback|IndexError|KeyError|"
    r"TypeError|cannot reshape|QH\d|[Qq]hull"
)


def error_line(err: str) -> str:
    """The single `thurston: error:` line of a run that failed cleanly (no traceback)."""
    lines = [ln for ln in err.splitlines() if ln.startswith("thurston: error:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


@contextlib.contextmanager
def tmpfs(folder: Path, size: str):
    """A tmpfs of `size` mounted on folder (needs root; the test is skipped where mounting fails)."""
    folder.mkdir()
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)], capture_output=True, text=True
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root): {mounted.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=True)


def fill(folder: Path):
    """Fills the file system of folder to the last byte."""
    fd = os.open(folder / "filler", os.O_WRONLY | os.O_CREAT)
    try:
        with contextlib.suppress(OSError):
            while True:
                os.write(fd, b"\0" * 4096)
    finally:
        os.close(fd)


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def default_signals():
    """A child's preexec_fn: SIGINT and SIGTERM as a terminal's command has them. A background job
    of a shell without job control (a CI runner's, say) starts with SIGINT ignored, and a child
    inherits that: the signal tests would then wait for a signal that never arrives."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, (signal.SIGINT, signal.SIGTERM))


def stop(run: subprocess.Popen, signum: int) -> tuple[int, float, str]:
    """Sends the signal to the running `thurston` and waits for it: (exit status, seconds it took
    to end, its stderr); asserts it ended as a signal ends it, with its one last line."""
    start = time.perf_counter()
    run.send_signal(signum)
    try:
        code = run.wait(timeout=30)
    finally:
        run.kill()
    took = time.perf_counter() - start
    stderr = run.stderr.read()
    assert code == 128 + signum and took < 5.0, (code, took, stderr)
    assert "Traceback" not in stderr
    assert stderr.strip().splitlines()[-1] == (
        "thurston: interrupted" if signum == signal.SIGINT else f"thurston: stopped by {signal.Signals(signum).name}"
    )
    return code, took, stderr
