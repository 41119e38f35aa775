"""What the tests of outputs share: a small real file system to fill or make read-only, the
folder's listing, and the one error line a failed run prints."""
import contextlib
import os
import subprocess
from pathlib import Path

import pytest

PREVIOUS = b"the user's previous file\n"


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
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                             capture_output=True, text=True)
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
