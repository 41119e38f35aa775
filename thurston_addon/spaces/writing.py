"""Space files written by the program (SnapPy's manifolds, the members of the families): the TOML
text of a space's fields, and the cache folder where such files are kept for users to reuse and
edit."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ..files import OutputError, write_bytes
from .values import SpaceError

# Where written space files go: $THURSTON_CACHE_DIR, else $XDG_CACHE_HOME/thurston, else ~/.cache/thurston.
CACHE_VARIABLE = "THURSTON_CACHE_DIR"


def cache_dir(kind: str) -> Path:
    """The folder of written space files of one kind ('snappy', 'family'), created if absent."""
    root = (
        os.environ.get(CACHE_VARIABLE) or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "thurston"
    )
    folder = Path(root) / kind
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SpaceError(
            f"cannot make the folder {str(folder)!r} for written space files ({exc.strerror}); "
            f"set ${CACHE_VARIABLE} to a writable folder"
        ) from None
    return folder


def file_name(name: str) -> str:
    """A file name for a space's name: its safe characters kept, the others written as _XX (hex)."""
    return re.sub(r"[^A-Za-z0-9_.-]", lambda m: f"_{ord(m.group()):02X}", name) + ".toml"


def _value(v) -> str:
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return repr(float(v))  # the shortest text that reads back as the same double


def space_text(data: dict, comment: str) -> str:
    """A space's fields (as catalog.from_data takes them) as the text of a space file."""
    lines = [f"# {line}" for line in comment.splitlines()]
    tables = {k: v for k, v in data.items() if isinstance(v, (dict, list)) and k in ("camera", "generator")}
    lines += [f"{k} = {_value(v)}" for k, v in data.items() if k not in tables]
    if "camera" in tables:
        lines += ["", "[camera]"] + [f"{k} = {_value(v)}" for k, v in tables["camera"].items()]
    for gen in tables.get("generator", []):
        lines += ["", "[[generator]]"] + [f"{k} = {_value(v)}" for k, v in gen.items()]
    return "\n".join(lines) + "\n"


def write_space(path: Path, data: dict, comment: str) -> Path:
    """The space file at path, whole or not at all; one already there (by another run) is kept."""
    try:
        return write_bytes(path, space_text(data, comment).encode(), overwrite=False)
    except OutputError:
        if path.is_file():
            return path
        raise
