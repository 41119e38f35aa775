"""The shapes of a domain's faces in the chart. Every face is a plane c . Y = 0 of the geometry's
plane coordinates Y = plane_coordinates(X) (the plane chart y = Y[:3] / Y[3]); the shape says what
that is in the chart and how to draw it, so that spaces and the renderer ask the shape instead of
the geometry's name:
- ChartPlanes: the plane chart is the chart, faces are chart planes (a convex chart polyhedron);
- PlanesOfChart: planes of another chart (SL2's (Klein(w), phi) over its Poincare chart), curved
  in the chart;
- Spheres: spheres |x| = e^w0 (S2xR's, plane coordinates (0, 0, w, 1)): a shell between two, with
  no edges, whose spheres may be glued to themselves by reflections.
"""

from __future__ import annotations

import abc

import numpy as np


class FaceShape(abc.ABC):
    def __init__(self, geometry):
        self.geometry = geometry


class PolyhedralFaces(FaceShape):
    """Faces that are planes of the plane chart: the domain is a convex polyhedron there."""

    @abc.abstractmethod
    def chart_segments(self, a, b) -> list[tuple[np.ndarray, np.ndarray]]:
        """The plane-chart segment a b as chart segments (chords of its image)."""

    @abc.abstractmethod
    def guide_mesh(self, domain, plane_vertices) -> tuple[np.ndarray, list, list]:
        """The domain as a mesh in the chart: vertices, edges (vertex pairs), faces (vertex rings or
        triangles), from the domain and its vertices in the plane chart."""


class ChartPlanes(PolyhedralFaces):
    """The plane chart is the chart: faces are chart planes, edges chart segments."""

    def chart_segments(self, a, b):
        return [(a, b)]

    def guide_mesh(self, domain, plane_vertices):
        return domain.vertices, [(a, b) for a, b, _, _ in domain.edges], [f.vertices for f in domain.faces]


class PlanesOfChart(PolyhedralFaces):
    """Faces are planes of another chart (geometry.from_plane_chart carries its points to the chart):
    curved in the chart, drawn by chords."""

    PIECES = 16  # chart chords per plane-chart segment

    def chart_segments(self, a, b):
        x = self.geometry.from_plane_chart(a + np.linspace(0, 1, self.PIECES + 1)[:, None] * (b - a))
        return list(zip(x[:-1], x[1:]))

    def guide_mesh(self, domain, plane_vertices):
        """Each face's fan of triangles from its centre subdivided in the plane chart, and each edge
        in PIECES, carried to the chart."""
        import trimesh

        V = plane_vertices
        points, triangles, pairs, count = [], [], [], 0
        for face in domain.faces:
            ring = V[face.vertices]
            k = len(ring)
            y, t = np.vstack([ring, ring.mean(axis=0)]), np.array([[i, (i + 1) % k, k] for i in range(k)])
            for _ in range(4):
                y, t = trimesh.remesh.subdivide(y, t)
            points.append(y)
            triangles += (t + count).tolist()
            count += len(y)
        steps = np.linspace(0, 1, self.PIECES + 1)[:, None]
        for a, b, _, _ in domain.edges:
            points.append(V[a] + steps * (V[b] - V[a]))
            pairs += [(count + i, count + i + 1) for i in range(self.PIECES)]
            count += self.PIECES + 1
        return self.geometry.from_plane_chart(np.vstack(points)), pairs, triangles


class Spheres(FaceShape):
    """Faces are the spheres |x| = e^w0, the planes w = w0 of the plane coordinates (0, 0, w, 1):
    the covector (0, 0, c, d) is the sphere c log|x| + d = 0. `reflection(x, radius)` and
    `reflection_tangent(x, v, radius)` are the isometry that glues the sphere |x| = radius to itself
    antipodally (fixing no point) and its differential."""

    def __init__(self, geometry, reflection, reflection_tangent):
        super().__init__(geometry)
        self.reflection = reflection
        self.reflection_tangent = reflection_tangent

    def sphere(self, c) -> tuple[float, bool]:
        """(w0, whether the domain lies inside it) of a face covector (0, 0, c, d); ValueError where
        it is not a sphere."""
        if c[0] != 0 or c[1] != 0 or c[2] == 0:
            raise ValueError(
                f"the face {np.asarray(c, float).tolist()} is not a sphere |x| = const "
                f"({self.geometry.name} faces are [0, 0, c, d]: the sphere c log|x| + d = 0)"
            )
        return -c[3] / c[2], bool(c[2] > 0)
