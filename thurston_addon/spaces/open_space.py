"""Open spaces: all of the chart (R^3), from a space file without generators whose geometry has
such spaces (Geometry.open_torus: graph). Rays run to the distance limit. The tracer walks a
domain with face pairings, so the space is traced as the flat 3-torus of the cube |x_i| <= H that
no ray leaves: rays start in the region of interest (the camera must lie in it) and run at most
max_distance, which is no longer than their chart length (the geometry's metric is at least the
chart's), so with H >= the region's reach along each axis plus max_distance they never meet a face,
and the geometry repeated on 2H Z^3 (open_torus) equals the chart's wherever they go. The region
of interest (the file's `region`, two opposite corners; default the cube |x_i| <= 1) holds the
camera and is what Blender's guide draws; the default scene's grid through it, of cubic cells a
third of its shortest side, sizes what a domain sizes elsewhere (the default scene's tubes, ring
and ball, the tolerances near the camera)."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from .coordinate import CoordinateSpace
from .space import read_geometry
from .values import SpaceError, evaluate, vector

DEFAULT_REGION = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]
# The cube's margin beyond the rays' reach (chart units): a face is never met, not even grazed.
FACE_MARGIN = 1.0


def opens(data: dict, source: str) -> bool:
    """Whether a space file describes an open space: no generators, and a geometry that has them."""
    return not data.get("generator") and read_geometry(data, source).open_spaces


class OpenSpace(CoordinateSpace):
    """All of the chart (see the module): a coordinate domain, the cube |x_i| <= H, its faces
    paired by the translations 2H e_i, made here (the file gives none)."""

    def __init__(self, data: dict, source: str):
        corners = data.get("region", DEFAULT_REGION)
        if not isinstance(corners, list) or len(corners) != 2:
            raise SpaceError(f"{source}: region must be two opposite corners [[x, y, z], [x, y, z]], got {corners!r}")
        a, b = (vector(c, 3, f"{source}: region") for c in corners)
        self.region = np.array([np.minimum(a, b), np.maximum(a, b)])
        if not np.all(self.region[1] > self.region[0]):
            raise SpaceError(f"{source}: region {self.region.tolist()} has no volume: give two opposite corners")
        max_distance = evaluate(data.get("max_distance", 20.0), f"{source}: max_distance")
        reach = float(np.abs(self.region).max()) + max_distance + FACE_MARGIN
        try:
            self._torus, half = read_geometry(data, source).open_torus(reach)
        except ValueError as exc:
            raise SpaceError(f"{source}: [{data.get('geometry')}] {exc}") from None
        translations = []
        for i, axis in enumerate("xyz"):
            M = np.eye(4)
            M[i, 3] = 2 * half
            face = [0.0, 0.0, 0.0, -half]
            face[i] = 1.0
            translations.append({"name": axis, "matrix": M.tolist(), "face": face})
        super().__init__({**data, "generator": translations}, source)
        self.half = half
        self.max_reach = self.max_distance  # (a longer one would let rays meet the faces)
        inside = self.region[0] <= self.camera.position
        if not (np.all(inside) and np.all(self.camera.position <= self.region[1])):
            raise SpaceError(
                f"{source}: camera position {self.camera.position.tolist()} lies outside the region "
                f"{self.region.tolist()}: move it into the region, or widen the region"
            )
        self.validated = True

    def _read_geometry(self, data: dict, where: str):
        return self._torus

    def move_inside(self, X, V=None, max_steps=10000, label="point"):
        """As in any space while the torus is validated; then SpaceError for points outside the
        cube: no ray reaches them, and the pairings would bring in copies that R^3 does not have."""
        if self.__dict__.get("validated"):
            outside = ~self.domain.contains(np.asarray(X), tol=1e-9)
            if outside.any():
                i = int(np.argmax(outside))
                where = np.asarray(self.geometry.to_chart(np.asarray(X[i], float)), float).tolist()
                name = "the point" if label is None else f"{label} {i}"
                raise SpaceError(
                    f"{name} ({where}) lies beyond the reach of the rays of {self.id!r} (an open space: R^3, "
                    f"traced within |x_i| <= {self.half:g}, which its rays never leave): move it nearer"
                )
        return super().move_inside(X, V, max_steps, label)

    def bring_inside(self, X, V=None):
        """As in any space, for points in the region; elsewhere SpaceError: the rays from them
        could leave the cube (and the camera is where this is asked)."""
        x = np.asarray(self.geometry.to_chart(np.asarray(X, float)), float)
        if not (np.all(self.region[0] <= x) and np.all(x <= self.region[1])):
            raise SpaceError(
                f"the point {x.tolist()} lies outside the region of interest {self.region.tolist()} of "
                f"{self.id!r} (an open space: R^3); keep the camera in the region, or widen the region"
            )
        return super().bring_inside(X, V)

    # --- the region and its grid's cell size what a domain sizes elsewhere ------------------------
    @cached_property
    def cell(self) -> float:
        """The side of the default scene's grid cells: a third of the region's shortest side."""
        return float(np.ptp(self.region, axis=0).min() / 3)

    @property
    def extent(self) -> float:
        """A cell's side: it plays the domain's part (the default scene's sizes, the tolerances near
        the camera: a torus preset of that period and this space trace alike)."""
        return self.cell

    @property
    def chart_inradius(self) -> float:
        return self.cell / 2

    @property
    def centre(self) -> np.ndarray:
        return self.region.mean(axis=0)

    def size_ratio(self, vertices) -> float:
        V = np.asarray(vertices, float)
        return float(np.linalg.norm(np.ptp(V, axis=0)) / np.linalg.norm(np.ptp(self.region, axis=0)))

    @cached_property
    def _box(self):
        """The region's box: its 8 corners (bit i of k: the upper side along axis i), 12 edges, 6
        faces."""
        V = np.array([[self.region[(k >> i) & 1][i] for i in range(3)] for k in range(8)])
        edges = [(k, k | 1 << i) for k in range(8) for i in range(3) if not k >> i & 1]
        faces = [(0, 2, 6, 4), (1, 5, 7, 3), (0, 4, 5, 1), (2, 3, 7, 6), (0, 1, 3, 2), (4, 6, 7, 5)]
        return V, edges, faces

    def outline(self, inset: float) -> list[list[tuple[np.ndarray, np.ndarray]]]:
        """A regular grid through the region (the paper's), by axis: cubic cells of a third of its
        shortest side (as many as fit along the others), the lines along each axis through the
        cells' corners (`inset` is not needed: nothing is paired)."""
        lo, hi = self.region
        cell = self.cell
        ticks = [lo[i] + cell * np.arange(int(np.floor((hi[i] - lo[i]) / cell + 1e-9)) + 1) for i in range(3)]
        groups: list[list] = [[], [], []]
        for axis in range(3):
            j, k = (axis + 1) % 3, (axis + 2) % 3
            for u in ticks[j]:
                for v in ticks[k]:
                    p, q = np.empty(3), np.empty(3)
                    p[axis], q[axis] = lo[axis], hi[axis]
                    p[j] = q[j] = u
                    p[k] = q[k] = v
                    groups[axis].append((p, q))
        return groups

    def guide_mesh(self) -> tuple[np.ndarray, list, list]:
        """The region of interest (Blender draws it where a closed space's domain is drawn)."""
        V, edges, faces = self._box
        return V, edges, [list(f) for f in faces]
