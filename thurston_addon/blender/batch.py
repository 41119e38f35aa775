"""Background batch rendering of a .blend file with its own Thurston settings (no GUI)."""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
from pathlib import Path

import bpy

from .. import files, images
from . import engine, export, registration
from .frame_files import FrameFiles


def ensure_registered():
    if not hasattr(bpy.types.Scene, "thurston"):
        registration.register()


def open_blend(path: Path):
    files.check_input(path, "blend file", export.ExportError)
    ensure_registered()  # before loading, so that the add-on's load_post handler updates old settings
    try:
        bpy.ops.wm.open_mainfile(filepath=str(path))
    except RuntimeError as exc:
        raise export.ExportError(f"cannot open {str(path)!r}: {exc}") from None


def frame_range(spec: str | None, bscene) -> range:
    """The frames of `--frames` (N or A..B, every frame), or else the scene's frame range by its
    step, as Blender renders an animation."""
    if not spec:
        return range(bscene.frame_start, bscene.frame_end + 1, bscene.frame_step)
    try:
        a, _, b = spec.partition("..")
        first, last = int(a), int(b or a)
    except ValueError:
        raise export.ExportError(f"frames must be N or A..B, got {spec!r}") from None
    if last < first:
        raise export.ExportError(f"frames {spec!r}: the last frame comes before the first")
    return range(first, last + 1)


def glob_escape(name: str) -> str:
    """A name as a glob pattern that matches only itself."""
    return "".join(f"[{c}]" if c in "*?[" else c for c in name)


def existing_frames(names: FrameFiles, frames: range, views=("",)) -> list[Path]:
    """The files of `frames` (and their `views`: view_suffixes) already there, from the folder's
    listing, not each frame's path."""
    found = []
    extension = names.tail[names.tail.rfind(".") :]
    for file in sorted(names.folder.glob(f"{glob_escape(names.head)}*{glob_escape(extension)}")):
        middle = file.name[len(names.head) : len(file.name) - len(extension)]
        for view in views:
            number = re.match(r"-?\d+", middle)
            if number and int(number[0]) in frames and file == names.path(int(number[0]), view):
                found.append(file)
    return found


def make_folder(folder: Path):
    """The output folder, created with its parents where missing, as Blender creates a render's."""
    if folder.is_dir():
        return
    if folder.exists():
        raise files.OutputError(f"output folder {str(folder)!r} is a file: choose a folder for --out")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise files.OutputError(f"cannot create output folder {str(folder)!r}: {exc.strerror or exc}") from None


def _configure_output(bscene, suffix: str):
    """The THURSTON engine, on every view layer the passes that the settings ask for (and no others),
    and the file format."""
    bscene.render.engine = "THURSTON"
    wanted = {p.lower() for p in bscene.thurston.passes}
    for layer in bscene.view_layers:
        on = {}  # a switch shared by several passes is on where any of them is wanted
        for p in export.BLENDER_PASSES:
            on[p.flag] = on.get(p.flag, False) or p.source in wanted
        for p in export.BLENDER_PASSES:
            setattr(layer.thurston if p.addon_flag else layer, p.flag, on[p.flag])
    settings = bscene.render.image_settings
    if suffix == "exr":
        if hasattr(settings, "media_type"):  # Blender 5
            settings.media_type = "MULTI_LAYER_IMAGE"
        settings.file_format = "OPEN_EXR_MULTILAYER"
        settings.color_depth = "32"
    else:
        if hasattr(settings, "media_type"):
            settings.media_type = "IMAGE"
        settings.file_format = "PNG"
        settings.color_depth = "8"
    bscene.render.use_file_extension = False


def view_suffixes(bscene) -> list[str]:
    """The name suffixes of a frame's files: Stereoscopy's views written as files of their own (Views
    Format: Individual, with Blender's view suffixes: _L, _R), else one file ("": one view, or the
    views in one image as Stereo 3D lays them out, or in one multi-view EXR)."""
    r = bscene.render
    if r.use_multiview and r.image_settings.views_format == "INDIVIDUAL":
        return [v.file_suffix for v in r.views if v.use]
    return [""]


def render_frames(path: Path, frames: str | None, out_dir: Path, suffix: str, overwrite: bool, progress_for, log):
    """Render each frame through the THURSTON engine, as `blender -b FILE -E THURSTON -f N` would (render
    visibility, render modifier levels, animated cameras and objects), to out_dir/<name>_<frame>.<suffix>
    (or out_dir a path with '#': frame_files.FrameFiles; with Stereoscopy's individual views,
    <name>_<frame>_L.<suffix> and _R): a multilayer EXR with the passes the settings ask for, or a PNG
    of the view-transformed colour."""
    open_blend(path)
    bscene = bpy.context.scene
    span = frame_range(frames, bscene)
    views = view_suffixes(bscene)

    names = FrameFiles.of(path, out_dir, suffix)
    output = names.path
    make_folder(names.folder)
    for view in views:
        files.check_output(output(span[0], view), overwrite)  # the folder and the name
    if not overwrite:  # refuse before spending time on any frame
        for existing in existing_frames(names, span, views):
            files.check_output(existing, overwrite)
    _configure_output(bscene, suffix)
    outputs = []
    for frame in span:
        outputs += [output(frame, view) for view in views]
        bscene.frame_set(frame)
        listener = progress_for(f"frame {frame}")
        engine.progress_listeners.append(listener)
        stats = bscene.thurston.stats
        stats.valid = False  # set again by a render that finished
        try:
            bpy.ops.render.render()
        except RuntimeError as exc:  # the engine's self.report(ERROR) arrives here, as "Error: ..."
            reported = "; ".join(line.removeprefix("Error: ") for line in str(exc).strip().splitlines())
            raise export.ExportError(f"frame {frame}: {reported}") from None
        finally:
            engine.progress_listeners.remove(listener)
        if not stats.valid:
            raise export.ExportError(f"frame {frame}: the render did not finish")
        written = save_views({view: output(frame, view) for view in views}, overwrite, bscene)
        for note in stats.notes:
            log(f"{written}: warning: {note.message}")
        log(f"{written}: {stats.summary}")
    return outputs


def save_views(outputs: dict[str, Path], overwrite: bool, bscene) -> str:
    """Blender writes the Render Result (its multilayer EXR, its view transform, its stereo layout) to
    the files of `outputs` (by view suffix); each whole or not at all, as every output
    (files.replacing), and read back, since its writer may fail silently. Returns their names."""
    names = ", ".join(str(out) for out in outputs.values())
    with contextlib.ExitStack() as stack:
        temporary = {view: stack.enter_context(files.replacing(out, overwrite)) for view, out in outputs.items()}
        # absolute: Blender cannot write a bare relative name (it reads names as the .blend's)
        if list(outputs) == [""]:
            _save_render(Path(temporary[""]).absolute(), bscene, names)
        else:  # Blender writes each view beside the name it is given, with the view's suffix
            folder = Path(stack.enter_context(tempfile.TemporaryDirectory(dir=next(iter(outputs.values())).parent)))
            given = (folder / "frame").with_suffix(next(iter(outputs.values())).suffix)
            views_written = [given.with_name(f"frame{view}{given.suffix}") for view in outputs]
            _save_render(given.absolute(), bscene, names, views_written)
            for view, written in zip(outputs, views_written):
                os.replace(written, temporary[view])
        for view, out in outputs.items():
            images.check_image_file(temporary[view], out)
    return names


def _save_render(filepath: Path, bscene, names: str, views_written=()):
    try:
        bpy.data.images["Render Result"].save_render(filepath=str(filepath), scene=bscene)
    except RuntimeError as exc:
        # with individual views Blender writes them, then fails on the name it was given
        if not (views_written and all(p.is_file() for p in views_written)):
            raise files.OutputError(f"cannot write {names}: {str(exc).strip()}") from None
