"""What every geometry shares: the interface and the pieces written once for all of them.

A geometry (ProjectiveGeometry for E3, S3, H3; AffineGeometry for Nil, Sol) works on points and
tangent vectors as homogeneous 4-vectors ("model" coordinates) with chart point x = X[:3] / X[3],
and on isometries as 4x4 matrices acting linearly on them. It offers: `name`, `projective`
(geodesics and bisectors straight in the chart: Dirichlet domains), `affine_isometries` (the
isometries act on chart points as the affine maps M themselves: E3, Nil, Sol), `diameter`,
`copy_rings`, `reference_depth`, `light_reach_circumradii`, `chord_scale`; charts (`to_chart`,
`to_model`, `in_chart`, `tangent_to_model`, `tangent_to_chart`, `normalize_point`,
`normalize_tangent`); the metric (`metric`, `christoffel`, `volume_density`, `dot`); geodesics
(`geodesic`, `chart_geodesic`); isometries (`is_isometry`, `reorthonormalize`, `element_key`,
`transform_points`, `pull_back_plane`); distances (`distance`, `chord_distance`; the bounds that
render.cover_copies' walk to a light's copies uses: `distance_bound`, `farthest_distance`,
`domain_distance`) and light (`connect`, `falloff_along`); `plane_coordinates`, the homogeneous
vectors a domain's face covectors pair with. The C++ core has a kernel of the same name for each.
"""
from __future__ import annotations

import numpy as np


def _floats(a):
    """As a float array, keeping extended precision (np.longdouble) where the input has it."""
    a = np.asarray(a)
    return a.astype(np.result_type(a.dtype, np.float64), copy=False)


class Geometry:
    # Gauss-Legendre points per axis of a coordinate domain's volume integral (spaces.py)
    volume_order = 16
    # Whether a coordinate domain's faces are chart planes (a convex chart polyhedron); S2xR's are
    # the spheres |x| = const (spaces.ShellSpace)
    chart_plane_faces = True
    # Whether the face planes' coordinates (plane_coordinates, as y = Y[:3] / Y[3]) are the chart's
    # own; SL2's are (Klein(w), phi) over its Poincare chart, so its faces are curved in the chart
    plane_chart_is_chart = True
    # Whether an isometry M maps chart points affinely, as M on (x, 1): copies of an instanced mesh
    # are then instances themselves (render.py)
    affine_isometries = False
    # The default light reach in circumradii of the domain (render.default_light_reach): more where
    # the copies within a reach grow slowly
    light_reach_circumradii = 1.0
    # The chord tolerance of a quality in units of its error bound (render.Settings.tolerances):
    # 1, where the chords' bound K h^2 / 8 keeps silhouettes within the bound; up to 4 where the
    # error/time front shows every quality within half its bound at it and the time it saves
    # (benchmarks/bench_front.py, docs/front.md "The chord rule"; E3, S3 and H3 have exact chords)
    chord_scale = 1.0

    def chart_geodesic(self, x, u, t):
        """Chart position and chart velocity at arclength t from chart point x, chart direction u
        (u is normalised in the metric at x)."""
        X = self.to_model(x)
        V = self.normalize_tangent(X, self.tangent_to_model(x, u))
        Xt, Vt = self.geodesic(X, V, t)
        return self.to_chart(Xt), self.tangent_to_chart(Xt, Vt)

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
        d = _floats(B) - _floats(A)
        return np.sqrt(np.maximum(self.dot(A, d, d), 0))

    def transform_points(self, M, x):
        """Apply isometries (matrices acting linearly on model vectors) to chart points."""
        return self.to_chart(np.einsum("...ij,...j->...i", _floats(M), self.to_model(x)))

    def plane_coordinates(self, X):
        """The homogeneous vectors of model points X that face covectors pair with: the model
        vectors themselves where the chart is their projective image (E3, S3, H3, Nil, Sol)."""
        return _floats(X)

    def from_plane_chart(self, y):
        """Chart points of plane-chart points y = Y[:3] / Y[3] (Y = plane_coordinates(X))."""
        return _floats(y)

    def plane_chart_density(self, y):
        """The volume density in the plane chart."""
        return self.volume_density(y)

    def mesh_to_chart(self, Y):
        """Chart points of a small connected mesh's model vertices (SL2: on one branch of phi)."""
        return self.to_chart(Y)

    def charted(self, Y):
        """Whether model vectors are points of the chart (S3: its hemisphere X[3] > 0)."""
        Y = _floats(Y)
        return Y[..., 3] > 1e-9 * np.linalg.norm(Y, axis=-1)

    def generator_problem(self, M):
        """Why a space file may not use the isometry M as a generator (None: it may)."""
        return None

    def pull_back_plane(self, c, M):
        """The covector of the plane that the isometry M maps onto the plane c."""
        return np.asarray(c, float) @ np.asarray(M, float)
