"""Geometry kernels: metric, geodesic flow, isometries and charts, float64 numpy, no Blender.

`get(name)` returns the geometry for a space file's `geometry` field.
"""
from .euclidean import Euclidean
from .hyperbolic import Hyperbolic
from .spherical import Spherical

GEOMETRIES = {g.name: g for g in (Euclidean(), Spherical(), Hyperbolic())}


def get(name: str):
    try:
        return GEOMETRIES[name]
    except KeyError:
        raise ValueError(f"unknown geometry {name!r}; known: {', '.join(GEOMETRIES)}") from None
