"""A mesh file of any supported format, read by its suffix into cleaned scene objects."""

from __future__ import annotations

import struct
from pathlib import Path

from ..files import check_input, reference_folders
from .model import SceneError, SceneObject, clean
from .obj import read_obj
from .trimesh_formats import read_trimesh_file

MESH_SUFFIXES = {".obj", ".ply", ".stl", ".glb", ".gltf"}


def load_mesh_file(path: str | Path, folders: tuple[Path, ...] | None = None) -> list[SceneObject]:
    """The cleaned objects of a mesh file; the files it refers to (material libraries, textures,
    buffers) are read from `folders` (files.reference_folders; default: its own folder)."""
    path = check_input(
        path, "scene file", SceneError, "OBJ file" if Path(path).suffix.lower() == ".obj" else "mesh file"
    )
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SceneError(
            f"{path}: unsupported file type {path.suffix!r} (mesh files: {', '.join(sorted(MESH_SUFFIXES))}; scenes: .toml)"
        )
    try:
        folders = folders or reference_folders(path)
        objects = read_obj(path, folders) if path.suffix.lower() == ".obj" else read_trimesh_file(path, folders)
    except SceneError:
        raise
    except Exception as exc:  # trimesh and the file system raise many types
        raise SceneError(f"cannot read mesh file {str(path)!r}: {_reader_failure(exc)}") from None
    if not objects:
        raise SceneError(f"{path}: the file holds no triangles")
    return [clean(o, str(path)) for o in objects]


def _reader_failure(exc: Exception) -> str:
    """What a mesh reader's exception says about the file, in words about the file where Python's
    own would show (a corrupt file makes the readers index, look up and decode past its data)."""
    if isinstance(exc, UnicodeDecodeError):
        return f"it is not UTF-8 text where text is expected (byte {exc.start})"
    if isinstance(exc, KeyError):
        return f"an entry it needs is missing ({exc})"
    if isinstance(exc, (IndexError, struct.error, EOFError)):
        return "it refers past the end of its data (truncated or corrupt)"
    if isinstance(exc, (TypeError, AttributeError)):
        return "an entry has the wrong type (corrupt)"
    if isinstance(exc, OSError) and exc.strerror:  # the file system's (the one a texture is unpacked to)
        return exc.strerror + (f" ({exc.filename})" if exc.filename else "")
    # the reader's own words (trimesh's ValueErrors), where it has any
    return str(exc).strip() or "its data is corrupt or truncated (an embedded buffer or image that does not decode)"
