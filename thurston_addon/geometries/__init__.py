"""Geometry kernels: metric, geodesic flow, isometries and charts, float64 numpy, no Blender.

`get(name)` returns the geometry for a space file's `geometry` field. Every geometry fulfils the
contract of base.py (ProjectiveGeometry for E3, S3, H3; AffineGeometry for Nil, Sol and S2xR; H2xR
and SL2 their own; Graph, the graph of a height function, is configured per space by its space
file's table, `parameter_table`: the registry holds its flat instance); `register` adds one (tests register test-only geometries, `unregister` removes
them).
"""

from .base import Geometry
from .euclidean import Euclidean
from .graph import Graph
from .h2xr import H2xR
from .hyperbolic import Hyperbolic
from .nil import Nil
from .s2xr import S2xR
from .sl2 import SL2
from .sol import Sol
from .spherical import Spherical

GEOMETRIES = {g.name: g for g in (Euclidean(), Spherical(), Hyperbolic(), Nil(), Sol(), H2xR(), S2xR(), SL2(), Graph())}


def get(name: str) -> Geometry:
    try:
        return GEOMETRIES[name]
    except KeyError:
        raise ValueError(f"unknown geometry {name!r}; known: {', '.join(GEOMETRIES)}") from None


def register(geometry: Geometry) -> None:
    """Add a geometry to the registry under its name (ValueError where the name is taken)."""
    if not isinstance(geometry, Geometry):
        raise TypeError(f"{geometry!r} does not implement the geometry contract (geometries.base.Geometry)")
    if geometry.name in GEOMETRIES:
        raise ValueError(f"a geometry named {geometry.name!r} is already registered")
    GEOMETRIES[geometry.name] = geometry


def unregister(name: str) -> None:
    """Remove the geometry `name` from the registry."""
    del GEOMETRIES[name]
