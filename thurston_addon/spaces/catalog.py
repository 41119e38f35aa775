"""Where spaces come from: a space file's fields (from_data picks the kind of space), a file by
path, and the presets by id (the built-in folder and the user's, $THURSTON_SPACE_PATH)."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

from ..files import check_keys, read_text
from ..geometries import faces
from . import families, snappy_census
from .coordinate import CoordinateSpace
from .dirichlet import DirichletSpace
from .open_space import OpenSpace, opens
from .shells import FoldedShellSpace, ShellSpace
from .space import Space, read_geometry
from .values import SpaceError

PRESET_DIR = Path(__file__).parent.parent / "presets"
# Folders of a user's own presets (os.pathsep-separated), searched before the built-in ones.
SPACE_PATH_VARIABLE = "THURSTON_SPACE_PATH"
# The keys of a space file's tables (any other key is an error naming the nearest valid one).
SPACE_KEYS = (
    "id",
    "name",
    "description",
    "geometry",
    "scale",
    "max_distance",
    "max_crossings",
    "covolume",
    "camera",
    "generator",
    "graph",  # the graph geometry's height function (geometries/graph.py)
    "region",  # an open space's region of interest (spaces/open_space.py)
)
CAMERA_KEYS = ("position", "forward", "up", "fov")
GENERATOR_KEYS = ("name", "matrix", "face", "antipodal")


def _check_keys(data, source: str):
    """SpaceError naming a key the file's tables do not have (and the nearest one they do)."""
    if not isinstance(data, dict):
        raise SpaceError(f"{source}: expected a table of fields, got {type(data).__name__}")
    check_keys(data, SPACE_KEYS, source, SpaceError)
    if isinstance(data.get("camera"), dict):
        check_keys(data["camera"], CAMERA_KEYS, f"{source}: camera", SpaceError)
    for i, gen in enumerate(data.get("generator") if isinstance(data.get("generator"), list) else []):
        if isinstance(gen, dict):
            check_keys(gen, GENERATOR_KEYS, f"{source}: generator {gen.get('name', i)!r}", SpaceError)


def from_data(data: dict, source: str) -> Space:
    """The space a file's fields describe: a coordinate domain where the generators name their
    faces (a shell where the geometry's faces are spheres), else the Dirichlet domain of the
    chart origin."""
    _check_keys(data, source)
    gens = data.get("generator")
    folded = isinstance(gens, list) and any(isinstance(g, dict) and "antipodal" in g for g in gens)
    if folded and not isinstance(read_geometry(data, source).face_shape, faces.Spheres):
        first = next(g for g in gens if isinstance(g, dict) and "antipodal" in g)
        raise SpaceError(
            f"{source}: generator {first.get('name', '?')!r}: 'antipodal' is a reflection in a sphere "
            f"|x| = R, which only a geometry whose faces are spheres has; give {data.get('geometry')} "
            "generators a 'matrix'"
        )
    if opens(data, source):
        return OpenSpace(data, source)
    if "region" in data:
        raise SpaceError(f"{source}: 'region' belongs to an open space (a graph file without generators): remove it")
    given = isinstance(gens, list) and any(isinstance(g, dict) and "face" in g for g in gens)
    if not given:
        return DirichletSpace(data, source)
    if not isinstance(read_geometry(data, source).face_shape, faces.Spheres):
        return CoordinateSpace(data, source)
    return (FoldedShellSpace if folded else ShellSpace)(data, source)


def preset_dirs() -> list[Path]:
    """Where presets are found: the folders of $THURSTON_SPACE_PATH in order, then the built-in ones."""
    extra = [Path(p) for p in os.environ.get(SPACE_PATH_VARIABLE, "").split(os.pathsep) if p]
    return [*extra, PRESET_DIR]


def preset_path(space_id: str) -> Path | None:
    """The file of a preset id (the first folder of preset_dirs() that has it), None if there is none."""
    for folder in preset_dirs():
        path = folder / f"{space_id}.toml"
        if path.is_file():
            return path
    return None


def load(path_or_id: str | Path) -> Space:
    """A preset by id, a manifold SnapPy names (snappy:NAME) or a family's member (lens(7,2)), their
    files written to the cache folder first, or a space file by path."""
    path = Path(path_or_id)
    named = None if path.exists() else named_file(str(path_or_id))
    if named is not None:
        path = named
    elif not path.suffix and not path.exists():
        path = preset_path(str(path_or_id))
        if path is None:
            raise SpaceError(
                f"unknown space {str(path_or_id)!r}: not a preset ({', '.join(preset_ids())}) and not a file"
            )
    text = read_text(path, "space file", SpaceError, "space file")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpaceError(f"space file {str(path)!r} is not valid TOML: {exc}") from None
    except RecursionError:
        raise SpaceError(
            f"space file {str(path)!r}: its tables or arrays nest too deeply; a space needs a few levels"
        ) from None
    return from_data(data, str(path))


def named_file(name: str) -> Path | None:
    """The space file of a name mathematicians use, a family's member (lens(7,2)) or SnapPy's
    manifold (snappy:NAME), written to the cache folder first if it is not there; None for any
    other name."""
    if snappy_census.is_snappy_name(name):
        return snappy_census.census_file(name[len(snappy_census.PREFIX) :])
    return families.family_file(name)


def preset_ids() -> list[str]:
    """Every preset id, the user's and the built-in ones, sorted."""
    return sorted({p.stem for folder in preset_dirs() if folder.is_dir() for p in folder.glob("*.toml")})
