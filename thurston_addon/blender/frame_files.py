"""Where a .blend file's rendered frames go (render-blend's, its farm's, Render on Cluster's): into a
folder as <name>_<frame>.<format>, or by a path with a run of '#' for the frame number, as
Blender's output paths have it."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class FrameFiles:
    """folder/<head><frame, zero-padded to width><tail>."""

    folder: Path
    head: str
    width: int
    tail: str

    @classmethod
    def of(cls, blend: Path, out: str | Path, suffix: str) -> FrameFiles:
        """`out` a folder: <blend's name>_<frame, 4 digits>.<suffix> in it; a path whose name holds
        '#': that name, its last run of '#' the frame number padded to the run's length, then
        .<suffix> (frames/shot_### -> frames/shot_001.exr)."""
        out = Path(out)
        found = re.fullmatch(r"(.*?)(#+)([^#]*)", out.name)
        if found:
            head, run, tail = found.groups()
            return cls(out.parent, head, len(run), f"{tail}.{suffix}")
        return cls(out, f"{Path(blend).stem}_", 4, f".{suffix}")

    def path(self, frame: int, view: str = "") -> Path:
        """The frame's file; `view`: a stereo view's suffix (_L, _R), before the extension as Blender
        puts it."""
        rest, dot, extension = self.tail.rpartition(".")
        return self.folder / f"{self.head}{frame:0{self.width}d}{rest}{view}{dot}{extension}"
