"""The members of the geometry contract (base.py) written once for the geometries that share them."""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np

from . import faces
from .base import Geometry


def floats(a):
    """As a float array, keeping extended precision (np.longdouble) where the input has it."""
    a = np.asarray(a)
    return a.astype(np.result_type(a.dtype, np.float64), copy=False)


class SharedGeometry(Geometry):
    """Defaults: faces are chart planes of the model vectors, isometries not chart-affine, no
    antipodes; the bounds of distances from the closed form; the core's kernel named like the
    geometry."""

    volume_order = 16
    light_reach_circumradii = 1.0
    chord_scale = 1.0
    affine_isometries = False
    antipode_distance = math.inf

    @property
    def kernel(self) -> str:
        return self.name

    @cached_property
    def face_shape(self):
        return faces.ChartPlanes(self)

    def chart_geodesic(self, x, u, t):
        """Chart position and chart velocity at arclength t from chart point x, chart direction u
        (u is normalised in the metric at x)."""
        X = self.to_model(x)
        V = self.normalize_tangent(X, self.tangent_to_model(x, u))
        Xt, Vt = self.geodesic(X, V, t)
        return self.to_chart(Xt), self.tangent_to_chart(Xt, Vt)

    def repair_products(self, M):
        """Unchanged: the products of these isometries keep their relative rounding."""
        return M

    def point_coordinates(self, X):
        """The model vector's direction (a point's model vectors may differ by a factor: projective
        models), known to ~1e-16 of its size however far the point."""
        X = floats(X)
        return X / np.linalg.norm(X, axis=-1, keepdims=True)

    def distance_bound(self, A, B):
        """An upper bound of the distance between model points A and B (the length of some curve
        between them): the distance itself where it has a closed form."""
        return self.distance(A, B)

    def farthest_distance(self, X, domain):
        """An upper bound of the largest distance from the model point X to the points of a
        coordinate domain: the largest to its vertices, which is that where distance functions are
        convex and the domain is the convex hull of its vertices (H2xR)."""
        return float(np.max(self.distance(X, self.to_model(domain.vertices))))

    def chord_distance(self, A, B):
        """The distance of nearby points to first order: the metric length at A of B - A."""
        d = floats(B) - floats(A)
        return np.sqrt(np.maximum(self.dot(A, d, d), 0))

    def transform_points(self, M, x):
        """Apply isometries (matrices acting linearly on model vectors) to chart points."""
        return self.to_chart(np.einsum("...ij,...j->...i", floats(M), self.to_model(x)))

    def plane_coordinates(self, X):
        """The homogeneous vectors of model points X that face covectors pair with: the model
        vectors themselves where the chart is their projective image (E3, S3, H3, Nil, Sol)."""
        return floats(X)

    def from_plane_chart(self, y):
        """Chart points of plane-chart points y = Y[:3] / Y[3] (Y = plane_coordinates(X))."""
        return floats(y)

    def plane_chart_density(self, y):
        """The volume density in the plane chart."""
        return self.volume_density(y)

    def mesh_to_chart(self, Y):
        """Chart points of a small connected mesh's model vertices."""
        return self.to_chart(Y)

    def charted(self, Y):
        """Whether model vectors are points of the chart (S3: its hemisphere X[3] > 0)."""
        Y = floats(Y)
        return Y[..., 3] > 1e-9 * np.linalg.norm(Y, axis=-1)

    def generator_problem(self, M):
        """Why a space file may not use the isometry M as a generator (None: it may)."""
        return None

    def pull_back_plane(self, c, M):
        """The covector of the plane that the isometry M maps onto the plane c."""
        return np.asarray(c, float) @ np.asarray(M, float)
