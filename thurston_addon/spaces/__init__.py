"""Spaces (manifolds) as data: a geometry, generators of a discrete group of isometries, defaults.

A space file is TOML (see presets/*.toml). The fundamental domain is either
- the Dirichlet domain of the chart origin, computed from the generators where geodesics are chart
  lines (E3, S3, H3): the intersection of the half-spaces closer to the origin O than to gO over
  the group elements g, which are planes in the projective chart; validated by Poincaré's
  polyhedron theorem (pairings are isometries that map faces onto faces, edge cycles sum to 2 pi)
  (dirichlet.py); or
- a coordinate domain (any geometry): each generator names the face beyond which its copy of the
  domain lies; points that leave are reduced into the domain by the face maps; validated by
  discreteness, unique reduction and the covolume (coordinate.py; shells.py where the faces are
  spheres).
Leaving the domain through the face of g means entering the copy gD, so the ray is carried back by
g^-1. A space that fails validation raises SpaceError naming the file and the problem.
families.py writes the members of the families of spaces (lens(7,2), flat(amphicosm1), ...) and
snappy_census.py SnapPy's manifolds (snappy:NAME) as space files (writing.py: the text, the cache
folder); homology.py gives a Dirichlet space's presentation and first homology.
values.py reads a file's values, domains.py holds the domain and its faces, space.py the Space base
class, catalog.py the loading and the presets.
"""

from .catalog import (
    PRESET_DIR,
    SPACE_KEYS,
    SPACE_PATH_VARIABLE,
    from_data,
    load,
    named_file,
    preset_dirs,
    preset_ids,
    preset_path,
)
from .coordinate import CoordinateSpace
from .dirichlet import DirichletSpace
from .families import FAMILIES
from .shells import FoldedShellSpace, ShellSpace
from .snappy_census import SUMMARY as SNAPPY_SUMMARY
from .space import Space
from .values import SpaceError

__all__ = [
    "PRESET_DIR",
    "SPACE_KEYS",
    "SPACE_PATH_VARIABLE",
    "FAMILIES",
    "SNAPPY_SUMMARY",
    "CoordinateSpace",
    "DirichletSpace",
    "FoldedShellSpace",
    "ShellSpace",
    "Space",
    "SpaceError",
    "from_data",
    "load",
    "named_file",
    "preset_dirs",
    "preset_ids",
    "preset_path",
]
