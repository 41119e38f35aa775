"""What every space has: a geometry, generators, defaults, a fundamental domain with face pairings,
and the walk of points into it (the Space base class of the kinds of space)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from .. import geometries
from .domains import Fold, row_norms
from .values import SpaceError, count, evaluate, text, vector

_GROUP_LIMIT = 20000  # more elements than this within the needed radius: not a useful discrete group


@dataclass
class CameraDefaults:
    position: np.ndarray
    forward: np.ndarray
    up: np.ndarray
    fov: float  # horizontal field of view, degrees


class Space:
    """What every space has: a geometry, generators, defaults, a fundamental domain with face
    pairings, and the walk of points into it. How the domain comes about is the subclass's:
    DirichletSpace computes it from the generators, CoordinateSpace takes it from the file."""

    fold: Fold | None = None  # a folded space's fold; the tracer's domain is then its double cover's
    # The longest distance a render's rays may run (an open space's: its rays stay in its cube)
    max_reach: float = math.inf

    def __init__(self, data: dict, source: str):
        self.source = source
        where = source
        self.geometry = self._read_geometry(data, where)
        self.id = text(data, "id", Path(source).stem, where) or Path(source).stem
        self.name = text(data, "name", self.id, where)
        self.description = text(data, "description", "", where)
        self.scale = evaluate(data.get("scale", 1.0), f"{where}: scale")
        if not self.scale > 0:
            raise SpaceError(
                f"{where}: scale must be a positive number (Blender units per chart unit), got {self.scale:g}"
            )
        self.max_distance = evaluate(data.get("max_distance", 20.0), f"{where}: max_distance")
        if not self.max_distance > 0:  # evaluate() already rejects non-finite values
            raise SpaceError(f"{where}: max_distance must be a positive number, got {self.max_distance:g}")
        self.max_crossings = count(data.get("max_crossings", 64), f"{where}: max_crossings")
        self.generators = []
        self.generator_names = []
        for name, M in _generator_tables(data, where, self.geometry):
            self.generators.append(M)
            self.generator_names.append(name)
        try:  # a geometry made from the file's parameters (graph) checks them against the group
            self.geometry.check_group(self.generators, f"{where}: [{self.geometry.parameter_table}]")
        except ValueError as exc:
            raise SpaceError(str(exc)) from None
        if all(map(is_identity, self.generators)):
            raise SpaceError(
                f"{where}: every generator is the identity: the group is trivial, and the space would be "
                f"all of {self.geometry.name}, which no domain in its chart holds"
            )
        self.camera = self._camera(data.get("camera", {}), f"{where}: camera")
        self._build_domain(data)

    def _read_geometry(self, data: dict, where: str):
        return read_geometry(data, where)

    def _build_domain(self, data: dict):
        raise NotImplementedError

    def _camera(self, cam, where) -> CameraDefaults:
        """The [camera] table: a point of the chart, finite non-zero non-parallel forward and up,
        a horizontal field of view strictly between 0 and 180 degrees."""
        if not isinstance(cam, dict):
            raise SpaceError(f"{where}: expected a [camera] table (position, forward, up, fov), got {cam!r}")
        g = self.geometry
        position = vector(cam.get("position", [0, 0, 0]), 3, f"{where}.position")
        forward = vector(cam.get("forward", [0, 1, 0]), 3, f"{where}.forward")
        up = vector(cam.get("up", [0, 0, 1]), 3, f"{where}.up")
        fov = evaluate(cam.get("fov", 90.0), f"{where}.fov")
        if not g.in_chart(position):
            raise SpaceError(f"{where}.position {position.tolist()} is not a point of the chart of {g.name}")
        for label, v in (("forward", forward), ("up", up)):
            if not np.linalg.norm(v) > 0:
                raise SpaceError(f"{where}.{label} must be a non-zero vector, got {v.tolist()}")
        side = np.cross(forward, up)
        if not np.linalg.norm(side) > 1e-9 * np.linalg.norm(forward) * np.linalg.norm(up):
            raise SpaceError(f"{where}: up {up.tolist()} is parallel to forward {forward.tolist()}")
        if not 0 < fov < 180:
            raise SpaceError(f"{where}.fov must be between 0 and 180 degrees (exclusive), got {fov:g}")
        return CameraDefaults(position=position, forward=forward, up=up, fov=fov)

    # --- group elements ------------------------------------------------------------------------
    def _search(self, start, steps, accept, what: str) -> list[np.ndarray]:
        """Breadth-first closure of `start` under right multiplication by `steps`, keeping the
        elements that `accept`."""
        g = self.geometry
        found = {g.element_key(M): M for M in start}
        frontier = list(start)
        while frontier:
            nxt = []
            for M in frontier:
                for s in steps:
                    N = g.reorthonormalize(M @ s)
                    key = g.element_key(N)
                    if key in found or not accept(N):
                        continue
                    found[key] = N
                    nxt.append(N)
                    if len(found) > _GROUP_LIMIT:
                        raise SpaceError(
                            f"{self.source}: more than {_GROUP_LIMIT} group elements {what}: the "
                            "group is not discrete, or its domain is far thinner than some generators "
                            "are long, even after shortening them (give generators that pair the "
                            "domain's faces)"
                        )
            frontier = nxt
        return list(found.values())

    def neighbourhood(self, levels: int = 1) -> list[np.ndarray]:
        """Elements h whose copies hD surround D: level 1 are the copies that share at least a vertex
        with D (everything a small object sticking out of D can reach); each further level adds the
        copies touching the previous ones. Identity first."""
        if levels <= 0:
            return [np.eye(4)]
        cached = self.__dict__.setdefault("_neighbourhoods", {})
        if levels in cached:
            return cached[levels]
        g = self.geometry
        inner = self.neighbourhood(levels - 1)
        corners = np.array([M @ X for M in inner for X in g.to_model(self.domain.vertices)])
        steps = [f.element for f in self.domain.faces]

        def touches(N):
            back = g.normalize_point(np.linalg.solve(N, corners.T).T)
            return bool(np.any(self.domain.contains(back, tol=1e-9)))

        cached[levels] = self._search(inner, steps, touches, f"around the domain at level {levels}")
        return cached[levels]

    @cached_property
    def extent(self) -> float:
        """The domain's largest extent along a chart axis."""
        return float(np.ptp(self.domain.vertices, axis=0).max())

    @property
    def metric_extent(self) -> float:
        """The domain's size in the metric (the chart's extent where the chart is about isometric):
        the scale of the tolerances and footprints near the camera (render.Settings.tolerances)."""
        return self.extent

    @cached_property
    def face_feet(self) -> np.ndarray:
        """The chart points of the faces nearest the chart origin in the plane chart (the feet of
        the perpendiculars there: on a face whose plane chart is the chart, the nearest points)."""
        C = self.domain.covectors()
        n = C[:, :3]
        return self.geometry.from_plane_chart(-C[:, 3:4] * n / np.sum(n * n, axis=1)[:, None])

    @cached_property
    def chart_inradius(self) -> float:
        """The chart distance from the chart origin to the nearest face."""
        return float(np.min(np.linalg.norm(self.face_feet, axis=1)))

    @property
    def centre(self) -> np.ndarray:
        """The centre of the domain's largest inscribed chart ball (radius chart_inradius): where a
        scene fitted to the domain goes (the chart origin, about which the domain is built)."""
        return np.zeros(3)

    def size_ratio(self, vertices) -> float:
        """How many times the domain's size an object of these chart vertices is: the ratio of
        their chart diagonals (the chart is about isometric across the domain)."""
        V = np.asarray(vertices, float)
        return float(np.linalg.norm(np.ptp(V, axis=0)) / np.linalg.norm(np.ptp(self.domain.vertices, axis=0)))

    def outline(self, inset: float) -> list[list[tuple[np.ndarray, np.ndarray]]]:
        """Chart segments that draw the domain, grouped by class (the default scene's tubes)."""
        raise NotImplementedError

    @cached_property
    def plane_vertices(self) -> np.ndarray:
        """The domain's vertices in the plane chart, where its faces are planes."""
        g = self.geometry
        Y = g.plane_coordinates(g.to_model(self.domain.vertices))
        return Y[:, :3] / Y[:, 3:]

    def guide_mesh(self) -> tuple[np.ndarray, list, list]:
        """The domain as a mesh to model inside (Blender's domain guide): chart vertices, edges
        (vertex pairs) and faces (vertex rings, or triangles where the faces are curved in the
        chart), as the geometry's face shape draws them."""
        return self.geometry.face_shape.guide_mesh(self.domain, self.plane_vertices)

    @cached_property
    def face_classes(self) -> list[int]:
        """The class of each face: a face and its partner share one."""
        classes, seen = [], {}
        for i, face in enumerate(self.domain.faces):
            key = min(i, face.partner)
            classes.append(seen.setdefault(key, len(seen)))
        return classes

    # --- using the domain ---------------------------------------------------------------------
    def bring_inside(self, X, V=None):
        """One model point (and a tangent vector) moved into the domain: (X, V, M) with M the
        accumulated isometry; raises SpaceError if it cannot be."""
        X, V, M = self.move_inside(
            np.asarray(X, float)[None], None if V is None else np.asarray(V, float)[None], label=None
        )
        return X[0], (None if V is None else V[0]), self.geometry.reorthonormalize(M[0])

    def to_model(self, x, label="point"):
        """Chart points (rows) as model points; SpaceError naming a point (`label` i; None: the only
        one) so far out in the chart that its model point overflows."""
        g = self.geometry
        with np.errstate(all="ignore"):
            X = g.to_model(x)
            overflows = ~np.all(np.isfinite(g.normalize_point(X)), axis=-1)
        if overflows.any():
            i = int(np.argmax(overflows))
            raise SpaceError(
                f"{_point_name(label, i)} ({np.asarray(x[i], float).tolist()}) is too far out in the "
                f"chart of {g.name} (its model point overflows)"
            )
        return X

    def move_inside(self, X, V=None, max_steps=10000, label="point"):
        """Model points (rows; extended precision is kept) and optionally their tangent vectors,
        moved into the domain by the face pairings: each step applies, to the points still
        outside, the pairing of the face each is farthest outside of (so a far point costs only
        its own steps). Returns (X, V, M), M the isometry applied to each row; raises SpaceError
        naming a point (`label` i; None: the only one) that cannot be moved in: not a point of the
        geometry, so far out that the domain test overflows or the pairings no longer move it
        (rounding), or more than max_steps face crossings away."""
        g = self.geometry
        given = X

        def refuse(i, why):
            with np.errstate(all="ignore"):
                where = np.asarray(g.to_chart(np.asarray(given[i])), float).tolist()
            raise SpaceError(
                f"{_point_name(label, i)} ({where}) {why}; it cannot be brought into the domain of {self.id!r}"
            )

        with np.errstate(all="ignore"):
            X = g.normalize_point(np.array(X, copy=True))
            bad = ~(np.all(np.isfinite(X), axis=1) & g.in_chart(np.asarray(g.to_chart(X), float)))
        if bad.any():
            refuse(int(np.argmax(bad)), f"is not a point of {g.name}")
        C = np.asarray(self.domain.covectors(), X.dtype)
        C = C / np.sqrt(np.sum(C * C, axis=1))[:, None]
        maps = np.asarray([f.pairing for f in self.domain.faces], X.dtype)
        M = np.broadcast_to(np.eye(4, dtype=X.dtype), (len(X), 4, 4)).copy()
        active = np.arange(len(X))  # the points not yet inside
        for _ in range(max_steps):
            here = X if len(active) == len(X) else X[active]
            with np.errstate(over="ignore", invalid="ignore"):
                Y = g.plane_coordinates(here)
                s = Y @ C.T
            worst = np.argmax(s, axis=1)  # (a NaN is the largest)
            beyond = s[np.arange(len(active)), worst]
            overflow = ~np.isfinite(beyond)
            if overflow.any():
                refuse(int(active[np.argmax(overflow)]), f"is too far out: {g.name}'s domain test overflows there")
            outside = beyond > 1e-12 * row_norms(Y)
            active, worst, here = active[outside], worst[outside], here[outside]
            if len(active) == 0:
                if V is not None:
                    V = g.normalize_tangent(X, np.einsum("nij,nj->ni", M, np.asarray(V, X.dtype)))
                return X, V, M
            moved = g.normalize_point(np.einsum("nij,nj->ni", maps[worst], here))
            stuck = np.all(moved == here, axis=1)
            if stuck.any():
                refuse(int(active[np.argmax(stuck)]), "is too far out: the face pairings no longer move it (rounding)")
            X[active] = moved
            M[active] = maps[worst] @ M[active]
        refuse(int(active[0]), f"is more than {max_steps} face crossings from the domain")

    def reduces_to_identity(self, M, probes) -> bool:
        """Whether the isometry M is an element of the group: the probes' images under M reduce
        back onto the probes, by a reduction whose isometry undoes M."""
        g = self.geometry
        X = np.asarray(probes, float) @ np.asarray(M).T
        Y, _, R = self.move_inside(X)
        if not np.allclose(g.to_chart(Y), g.to_chart(probes), atol=1e-8):
            return False
        return bool(np.allclose(R @ M, np.eye(4), atol=1e-7))

    def _interior_points(self, rng, n):
        """Random chart points strictly inside the domain (by a relative margin of 1e-6, less in a
        domain too thin for that)."""
        g = self.geometry
        lo, hi = self.domain.vertices.min(axis=0), self.domain.vertices.max(axis=0)
        out = np.zeros((0, 3))
        margin, empty = 1e-6, 0
        while len(out) < n:
            x = rng.uniform(lo, hi, (4 * n, 3))
            x = x[g.in_chart(x)]  # the chart's own points only (the Klein disk's box reaches outside it)
            found = x[self.domain.contains(g.to_model(x), tol=-margin)]
            out = np.vstack([out, found])
            empty = 0 if len(found) else empty + 1
            if empty == 8:
                if margin < 1e-12:
                    raise SpaceError(f"{self.source}: the domain has no interior (its faces leave it flat)")
                margin, empty = margin / 100, 0
        return out[:n]

    def unfolded(self, x, v=None):
        """Chart points of the tracer's domain (and chart vectors there) as points of the space's
        own domain: themselves, except in a folded space, where those in f(D) go back by f."""
        x = np.array(x, float, copy=True)
        v = None if v is None else np.array(v, float, copy=True)
        if self.fold is not None:
            m = self.fold.mirrored(x)
            if v is not None:
                v[m] = self.fold.vectors(x[m], v[m])
            x[m] = self.fold.points(x[m])
        return x, v

    def summary(self) -> dict:
        return {
            "id": self.id,
            "name": self.name,
            "geometry": self.geometry.name,
            "description": self.description,
            "faces": len(self.domain.faces),
            "vertices": len(self.domain.vertices),
            "source": self.source,
        }


def _point_name(label: str | None, i: int) -> str:
    """How a message names point i of those given (label None: the only one)."""
    return "the point" if label is None else f"{label} {i}"


def read_geometry(data, where):
    known = ", ".join(geometries.GEOMETRIES)
    if not isinstance(data, dict):
        raise SpaceError(f"{where}: expected a table of fields, got {type(data).__name__}")
    if "geometry" not in data:
        raise SpaceError(f"{where}: missing field 'geometry' ({known})")
    if not isinstance(data["geometry"], str):
        raise SpaceError(f"{where}: geometry must be a string ({known}), got {data['geometry']!r}")
    try:
        g = geometries.get(data["geometry"])
        # a geometry with parameters (graph) is made from the space file's table of them
        table = g.parameter_table
        return g.with_parameters(data.get(table, {}), f"{where}: [{table}]") if table else g
    except ValueError as exc:
        raise SpaceError(f"{where}: {exc}") from None


def is_identity(M) -> bool:
    return bool(np.allclose(M, np.eye(4), rtol=0, atol=1e-12))


def _generator_tables(data, where, geometry):
    """(name, isometry) for each [[generator]] table."""
    gens = data.get("generator")
    if not isinstance(gens, list) or not gens:
        raise SpaceError(f"{where}: no [[generator]] tables: a space needs generator matrices")
    out = []
    for i, gen in enumerate(gens):
        if not isinstance(gen, dict):
            raise SpaceError(f"{where}: generator {i} must be a [[generator]] table with a 'matrix', got {gen!r}")
        name = str(gen.get("name", f"g{i}"))
        w = f"{where}: generator {name!r}"
        rows = gen.get("matrix")
        if not isinstance(rows, list) or len(rows) != 4:
            raise SpaceError(f"{w}: 'matrix' must be 4 rows of 4 numbers")
        M = np.array([vector(r, 4, f"{w} row {k}") for k, r in enumerate(rows)])
        largest = float(np.finfo(np.float32).max)  # (beyond it the isometry test's determinant overflows)
        if np.abs(M).max() > largest:
            raise SpaceError(
                f"{w}: the matrix has an entry of {np.abs(M).max():.3g}, beyond the {largest:.3g} of the "
                "tracer's float32 numbers"
            )
        if not geometry.is_isometry(M, tol=1e-9):
            raise SpaceError(f"{w}: the matrix is not an isometry of {geometry.name}")
        problem = geometry.generator_problem(M)
        if problem:
            raise SpaceError(f"{w}: the matrix {problem}")
        out.append((name, geometry.reorthonormalize(M)))
    return out
