"""Render on Cluster's command line: the saved .blend file sent to a Ray cluster by the user's
`thurston render-blend --cluster` (blender/farm_frames.py), so that Ray is never imported into
Blender."""

from __future__ import annotations

import shutil
from pathlib import Path

import bpy

from . import export
from .frame_files import FrameFiles


def command(bscene, animation: bool) -> tuple[list[str], Path]:
    """For Blender's Render on Cluster: the `thurston render-blend --cluster` command line that
    renders the saved file's current frame (or its frame range) by Blender's output path (a folder,
    or a name with '#' for the frame number), in its format (EXR, else PNG), overwriting only where Blender's Overwrite is on; and the
    last frame's file. ExportError where the file is not saved or no thurston command is found."""
    if not bpy.data.filepath:
        raise export.ExportError("save the .blend file first: the cluster renders the saved file")
    if bpy.data.is_dirty and not bpy.app.background:  # (without a UI, Blender counts every file as changed)
        raise export.ExportError(
            "the .blend file has unsaved changes: save it first (the cluster renders the saved file)"
        )
    s = bscene.thurston
    thurston = bpy.path.abspath(s.farm_command) if s.farm_command else shutil.which("thurston")
    if not thurston or not Path(thurston).is_file():
        raise export.ExportError(
            f"no thurston command{' at ' + repr(thurston) if thurston else ' on the PATH'}: set Thurston Command "
            "to the thurston of an install with the 'farm' extra (its .venv/bin/thurston)"
        )
    # Blender's output path: a folder, or a name whose '#' run is the frame number (none: 4 appended)
    output = bpy.path.abspath(bscene.render.filepath or "//")
    if not output.endswith(("/", "\\")) and "#" not in Path(output).name:
        output += "####"
    suffix = "exr" if bscene.render.image_settings.file_format.startswith("OPEN_EXR") else "png"
    first, last = (bscene.frame_start, bscene.frame_end) if animation else (bscene.frame_current,) * 2
    blend = Path(bpy.data.filepath)
    argv = [thurston, "render-blend", str(blend), "--frames", f"{first}..{last}", "--out", output]
    argv += ["--format", suffix, "--cluster", s.farm_address]
    if bscene.render.use_overwrite:
        argv.append("--overwrite")
    return argv, FrameFiles.of(blend, output, suffix).path(last)
