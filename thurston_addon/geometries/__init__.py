"""Geometry kernels: metric, geodesic flow, isometries and charts, float64 numpy, no Blender.

`get(name)` returns the geometry for a space file's `geometry` field. Every geometry offers the
same interface (see ProjectiveGeometry for E3, S3, H3 and AffineGeometry for Nil, Sol): points and
tangent vectors as 4-vectors, isometries as 4x4 matrices acting on them, the chart metric and its
Christoffel symbols, geodesics, connecting geodesics and the falloff of a point light along them.
The C++ tracer has a kernel of the same name for each.
"""
from .euclidean import Euclidean
from .hyperbolic import Hyperbolic
from .nil import Nil
from .sol import Sol
from .spherical import Spherical

GEOMETRIES = {g.name: g for g in (Euclidean(), Spherical(), Hyperbolic(), Nil(), Sol())}


def get(name: str):
    try:
        return GEOMETRIES[name]
    except KeyError:
        raise ValueError(f"unknown geometry {name!r}; known: {', '.join(GEOMETRIES)}") from None
