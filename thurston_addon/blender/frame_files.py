"""The names of a .blend file's rendered frames (render-blend's and Render on Cluster's)."""

from __future__ import annotations

from pathlib import Path


def frame_path(blend: Path, out_dir: Path, frame: int, suffix: str) -> Path:
    """A frame's output: out_dir/<name>_<frame>.<suffix>."""
    return Path(out_dir) / f"{Path(blend).stem}_{frame:04d}.{suffix}"
