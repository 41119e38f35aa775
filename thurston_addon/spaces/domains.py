"""A fundamental domain: its faces (covectors, the elements whose copies lie beyond them, vertex
rings, partners), the domain (vertices, faces, edges, the inside test), a fold, and the convex
polyhedron that half-spaces of the chart cut out."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import HalfspaceIntersection, QhullError

from .values import SpaceError


def row_norms(Y) -> np.ndarray:
    """The Euclidean norms of the rows of Y, also where their squares overflow (far points)."""
    rows = np.reshape(Y, (-1, np.shape(Y)[-1]))
    with np.errstate(over="ignore", invalid="ignore"):
        norms = np.sqrt(np.sum(rows * rows, axis=-1))
        far = ~np.isfinite(norms)
        if far.any():  # scaled to their largest entry first
            largest = np.max(np.abs(rows[far]), axis=-1)
            norms[far] = largest * np.sqrt(np.sum((rows[far] / largest[:, None]) ** 2, axis=-1))
    return norms.reshape(np.shape(Y)[:-1])


@dataclass
class Face:
    covector: np.ndarray  # c with c . X <= 0 inside
    element: np.ndarray  # group element g whose bisector this face is
    vertices: list[int]  # indices into Domain.vertices, counter-clockwise seen from outside
    partner: int = -1  # face through which a ray leaving through this one re-enters
    vertex_map: dict = field(default_factory=dict)  # vertex index -> partner's vertex index under g^-1

    @property
    def pairing(self):
        """The isometry applied to a ray that leaves through this face."""
        return np.linalg.inv(self.element)


@dataclass
class Domain:
    vertices: np.ndarray  # (V, 3) chart coordinates
    faces: list[Face]
    # model points -> the homogeneous vectors the covectors pair with (the geometry's)
    plane_coordinates: Callable = staticmethod(lambda X: X)

    @cached_property
    def edges(self) -> list[tuple[int, int, int, int]]:
        """(vertex a, vertex b, face i, face j) for each edge, a < b."""
        owners: dict[tuple[int, int], list[int]] = {}
        for fi, face in enumerate(self.faces):
            ring = face.vertices
            for k in range(len(ring)):
                a, b = sorted((ring[k], ring[(k + 1) % len(ring)]))
                owners.setdefault((a, b), []).append(fi)
        return [(a, b, fs[0], fs[1]) for (a, b), fs in sorted(owners.items())]

    def covectors(self):
        return np.array([f.covector for f in self.faces])

    def contains(self, X, tol=1e-12):
        """Whether model points lie in the domain (with a relative tolerance)."""
        with np.errstate(over="ignore", invalid="ignore"):
            X = np.asarray(self.plane_coordinates(np.asarray(X, float)), float)
            c = self.covectors()
            scale = np.linalg.norm(c, axis=1) * row_norms(X)[..., None]
            return np.all(X @ c.T <= tol * scale, axis=-1)


@dataclass
class Fold:
    """An isometry f = f^-1 that a space's group holds beside its matrices, where no 4x4 linear
    model of the geometry holds it with them (S2xR's antipodal reflections): the space is traced
    through its double cover, whose domain is D and f(D), with the scene and the lights doubled by f
    (render.compile_scene); what is seen in f(D) is reported at its image in D."""

    points: Callable  # chart points -> their images
    vectors: Callable  # (chart points, chart vectors there) -> the vectors' images
    mirrored: Callable  # chart points of the double cover's domain -> whether they lie in f(D)


def halfspace_domain(covectors, elements, source, geometry) -> Domain:
    """The convex polyhedron {c . (x, 1) <= 0 for all c} around the chart origin, with a face for
    each covector that bounds it (vertex rings counter-clockwise seen from outside)."""
    C = np.array(covectors, float)
    C /= np.linalg.norm(C[:, :3], axis=1)[:, None]
    away = _unbounded_direction(C)
    if away is not None:
        raise SpaceError(
            f"{source}: the domain is not compact: it reaches out of every bound along "
            f"{np.round(away, 6).tolist()} in the chart (the group has too few generators to close it)"
        )
    try:
        hs = HalfspaceIntersection(C, np.zeros(3))
    except (QhullError, ValueError):
        raise SpaceError(
            f"{source}: the faces of the domain cannot be intersected: some of them are parallel or "
            "coincide to rounding (generators given to too few digits, or a group that is not "
            "discrete)"
        ) from None
    pts = hs.intersections
    if not np.all(np.isfinite(pts)) or not np.all(geometry.in_chart(pts)):
        raise SpaceError(f"{source}: the domain is not compact (the group has too few generators)")
    # merge vertices that several planes produce
    verts: list[np.ndarray] = []
    for p in pts:
        if not any(np.linalg.norm(p - q) < 1e-9 * (1 + np.linalg.norm(p)) for q in verts):
            verts.append(p)
    V = np.array(verts)
    Y = np.hstack([V, np.ones((len(V), 1))])
    faces = []
    for c, M in zip(C, elements):
        on = np.nonzero(np.abs(Y @ c) < 1e-8 * (1 + np.abs(c[3])))[0]
        if len(on) < 3:
            continue
        faces.append(Face(covector=c, element=M, vertices=_ring(V, on, c[:3])))
    return Domain(vertices=geometry.from_plane_chart(V), faces=faces, plane_coordinates=geometry.plane_coordinates)


def _unbounded_direction(C) -> np.ndarray | None:
    """An axis direction d on which the polyhedron {x : C (x, 1) <= 0} (the origin inside) has no
    largest d . x, None if it is bounded: a polyhedron unbounded along some direction r (a ray
    x + t r in it) has no largest d . x for the axis direction d of a non-zero coordinate of r, its
    sign's."""
    for d in np.vstack([np.eye(3), -np.eye(3)]):
        if linprog(-d, A_ub=C[:, :3], b_ub=-C[:, 3], bounds=[(None, None)] * 3, method="highs").status == 3:
            return d
    return None


def _ring(V, idx, normal):
    """Order a face's vertices counter-clockwise seen from outside (outward normal)."""
    P = V[idx]
    centre = P.mean(axis=0)
    n = normal / np.linalg.norm(normal)
    a = P[0] - centre
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    ang = np.arctan2((P - centre) @ b, (P - centre) @ a)
    return [int(i) for i in idx[np.argsort(ang)]]
