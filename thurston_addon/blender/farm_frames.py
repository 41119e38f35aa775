"""A .blend file's frames on a Ray cluster, as `thurston render-blend` renders them one after the
other: the file shipped once through the object store, one task per frame rendering it through
Blender's Python module on a worker (blender/batch.py, the same path and output), each file written
here whole or not at all. A frame finished by a job is noted beside the outputs under the job's
key (the file's bytes, the frames, the format), so that the job started again renders only the rest;
a frame file not of this job is not overwritten unless asked."""

from __future__ import annotations

import atexit
import hashlib
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import bpy

from .. import files
from ..farm import FarmError, Line, connected, parse_address, run_tasks
from . import batch
from .frame_files import FrameFiles


@dataclass(frozen=True)
class BlendFile:
    """The .blend file a job renders: its bytes, and where it was (a worker on this machine, or
    one sharing its file system, opens it there, so that its relative paths resolve)."""

    name: str
    data: bytes
    source: str


@dataclass(frozen=True)
class Frame:
    index: int
    label = "frame"


# per worker process: the job key -> the .blend file it opens (and the folder of its copy, if any)
_opened: dict = {}


def render_frame(blend: BlendFile, key: str, frame: int, suffix: str, output: str) -> tuple[bytes, list[str]]:
    """On a worker: the frame's output file (its bytes) and the render's log lines (naming it `output`)."""
    if key not in _opened:
        for _, copy in _opened.values():  # a worker holds one job's file at a time
            if copy is not None:
                shutil.rmtree(copy, ignore_errors=True)
        _opened.clear()
        source, copy = Path(blend.source), None
        if not (source.is_file() and source.stat().st_size == len(blend.data) and source.read_bytes() == blend.data):
            copy = Path(tempfile.mkdtemp(prefix="thurston-farm-"))
            atexit.register(shutil.rmtree, copy, True)  # also when the worker ends
            source = copy / blend.name
            source.write_bytes(blend.data)
        _opened[key] = (source, copy)
    lines: list[str] = []
    with tempfile.TemporaryDirectory(prefix="thurston-frame-") as out:
        (written,) = batch.render_frames(
            _opened[key][0], str(frame), Path(out), suffix, True, lambda label: lambda done, total: True, lines.append
        )
        return written.read_bytes(), [line.replace(str(written), output) for line in lines]


def render_blend(path: Path, frames: str | None, out_dir: Path, suffix: str, overwrite: bool, address: str, log=print):
    """render-blend's frames (batch.render_frames' names and checks) on the cluster of `address`."""
    parse_address(address)
    batch.open_blend(path)  # its checks, and the frame range
    span = batch.frame_range(frames, bpy.context.scene)
    if batch.view_suffixes(bpy.context.scene) != [""]:
        raise FarmError(
            f"{str(path)!r}: Stereoscopy's individual view files are not rendered on a cluster; set Output > "
            "Views Format to Stereo 3D (both eyes in one file per frame), or render without --cluster"
        )
    data = path.read_bytes()
    key = hashlib.sha256(data + repr((span.start, span.stop, suffix)).encode()).hexdigest()[:24]
    names = FrameFiles.of(path, out_dir, suffix)
    outputs = {f: names.path(f) for f in span}
    batch.make_folder(names.folder)
    kept = names.folder / f".{path.name}.farm-{key}"
    for other in names.folder.glob(f".{batch.glob_escape(path.name)}.farm-*"):
        if other != kept:
            shutil.rmtree(other, ignore_errors=True)  # another job's (the file or the frames changed)
    finished = {f for f in span if (kept / f"frame-{f}").exists() and outputs[f].exists()}
    todo = [f for f in span if f not in finished]
    for f in todo:
        files.check_output(outputs[f], overwrite)  # before any work, as render-blend
    progress = Line("frames")

    def done(part, result):
        data, lines = result
        files.write_bytes(outputs[part.index], data, overwrite)
        kept.mkdir(exist_ok=True)
        (kept / f"frame-{part.index}").touch()
        finished.add(part.index)
        for line in lines:
            log(line)

    if todo:
        with connected(address):
            blend = BlendFile(path.name, data, str(path.resolve()))
            calls = [((key, f, suffix, str(outputs[f])), Frame(f)) for f in todo]
            run_tasks(render_frame, blend, calls, done, 1, lambda busy: progress(len(finished), len(span), busy))
    progress(len(span), len(span), 0)
    shutil.rmtree(kept, ignore_errors=True)
    return [outputs[f] for f in span]
