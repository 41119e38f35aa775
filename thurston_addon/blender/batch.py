"""Background batch rendering of a .blend file with its own Thurston settings (no GUI)."""
from __future__ import annotations

from pathlib import Path

import bpy

from .. import images, render
from . import export


def ensure_registered():
    if not hasattr(bpy.types.Scene, "thurston"):
        from .. import register

        register()


def open_blend(path: Path):
    if not path.is_file():
        raise export.ExportError(f"blend file {str(path)!r} does not exist")
    try:
        bpy.ops.wm.open_mainfile(filepath=str(path))
    except RuntimeError as exc:
        raise export.ExportError(f"cannot open {str(path)!r}: {exc}") from None
    ensure_registered()


def frame_range(spec: str | None, bscene) -> range:
    if not spec:
        return range(bscene.frame_start, bscene.frame_end + 1)
    try:
        a, _, b = spec.partition("..")
        first, last = int(a), int(b or a)
    except ValueError:
        raise export.ExportError(f"frames must be N or A..B, got {spec!r}") from None
    if last < first:
        raise export.ExportError(f"frames {spec!r}: the last frame comes before the first")
    return range(first, last + 1)


def render_frames(path: Path, frames: str | None, out_dir: Path, suffix: str, overwrite: bool, progress_for, log):
    """Render each frame (animated cameras and objects follow the timeline) to out_dir/<name>_<frame>.<suffix>."""
    open_blend(path)
    bscene = bpy.context.scene
    outputs = [out_dir / f"{path.stem}_{f:04d}.{suffix}" for f in frame_range(frames, bscene)]
    for out in outputs:  # refuse before spending time on any frame
        images.check_output(out, overwrite)
    names = [p.lower() for p in bscene.thurston.passes] or ["color"]
    for frame, out in zip(frame_range(frames, bscene), outputs):
        bscene.frame_set(frame)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        space, scene, camera, settings, notes = export.collect(bscene, depsgraph)
        for note in notes:
            log(f"frame {frame}: {note}")
        result = render.render(space, scene, settings, camera=camera, progress=progress_for(f"frame {frame}"))
        images.write(out, export.blender_passes(result, bscene.thurston.scale), names=names,
                     metadata={"frame": frame, "summary": result.summary()})
        log(f"{out}: {result.summary()}")
    return outputs
