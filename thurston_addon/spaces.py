"""Spaces (manifolds) as data: a geometry, generators of a discrete group of isometries, defaults.

A space file is TOML (see presets/*.toml). The fundamental domain is either
- the Dirichlet domain of the chart origin, computed here from the generators (E3, S3, H3): the
  intersection of the half-spaces closer to the origin O than to gO over the group elements g, which
  are planes in the projective chart; validated by Poincaré's polyhedron theorem (pairings are
  isometries that map faces onto faces, edge cycles sum to 2 pi); or
- a coordinate domain (Nil, Sol, any geometry): each generator names the face beyond which its copy
  of the domain lies; points that leave are reduced into the domain by the face maps; validated by
  discreteness, unique reduction and the covolume.
Leaving the domain through the face of g means entering the copy gD, so the ray is carried back by
g^-1. A space that fails validation raises SpaceError naming the file and the problem.
"""
from __future__ import annotations

import ast
import itertools
import math
import operator
import os
import tomllib
from dataclasses import dataclass, field
from typing import Callable
from functools import cached_property
from pathlib import Path

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import HalfspaceIntersection, QhullError

from . import geometries
from .files import check_keys, read_text

PRESET_DIR = Path(__file__).parent / "presets"
# Folders of a user's own presets (os.pathsep-separated), searched before the built-in ones.
SPACE_PATH_VARIABLE = "THURSTON_SPACE_PATH"
_SHORTENING_ROUNDS = 64  # passes over the generator pairs that shorten a generating set (each pass
# shortens every generator as far as single products go; a discrete group's set settles in a few)
_GROUP_LIMIT = 20000  # more elements than this within the needed radius: not a useful discrete group
CENTRE_RESOLUTION = 1e-6  # elements moving the domain centre by less are not told apart from the identity
# The keys of a space file's tables (any other key is an error naming the nearest valid one).
SPACE_KEYS = ("id", "name", "description", "geometry", "scale", "max_distance", "max_crossings", "covolume",
              "camera", "generator")
CAMERA_KEYS = ("position", "forward", "up", "fov")
GENERATOR_KEYS = ("name", "matrix", "face", "antipodal")


class SpaceError(ValueError):
    """A space file that cannot be read or does not describe a valid space."""


# --- safe arithmetic for matrix entries such as "sqrt(3)/2" ------------------------------------
_FUNCS = {n: getattr(math, n) for n in ("sqrt", "sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "asinh", "acosh", "atanh", "exp", "log")}
_CONSTS = {"pi": math.pi, "phi": (1 + math.sqrt(5)) / 2, "e": math.e}
_OPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv, ast.Pow: operator.pow, ast.USub: operator.neg, ast.UAdd: operator.pos}


def evaluate(value, where: str) -> float:
    """A number, or a string of arithmetic with sqrt, sin, ..., pi, phi."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if not isinstance(value, str):
        raise SpaceError(f"{where}: expected a number or an arithmetic string, got {value!r}")

    def ev(node):
        if isinstance(node, ast.Expression):
            return ev(node.body)
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
            return float(node.value)
        if isinstance(node, ast.Name) and node.id in _CONSTS:
            return _CONSTS[node.id]
        if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
            return _OPS[type(node.op)](ev(node.left), ev(node.right))
        if isinstance(node, ast.UnaryOp) and type(node.op) in _OPS:
            return _OPS[type(node.op)](ev(node.operand))
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in _FUNCS and len(node.args) == 1:
            return _FUNCS[node.func.id](ev(node.args[0]))
        raise SpaceError(f"{where}: cannot evaluate {value!r} (numbers, + - * / **, pi, phi, sqrt, sin, cos, ... only)")

    try:
        result = ev(ast.parse(value, mode="eval"))
    except SpaceError:
        raise
    except SyntaxError:
        raise SpaceError(f"{where}: cannot evaluate {value!r}: it is not an arithmetic expression") from None
    except (OverflowError, MemoryError, RecursionError):
        raise SpaceError(f"{where}: cannot evaluate {value!r}: it is too large") from None
    except (ZeroDivisionError, ValueError, TypeError) as exc:  # division by zero, math domain error
        raise SpaceError(f"{where}: cannot evaluate {value!r}: {exc}") from None
    if not isinstance(result, float) or not math.isfinite(result):
        raise SpaceError(f"{where}: cannot evaluate {value!r}: not a finite real number")
    return result


def _vector(value, n, where):
    if not isinstance(value, list) or len(value) != n:
        raise SpaceError(f"{where}: expected a list of {n} numbers, got {value!r}")
    return np.array([evaluate(v, f"{where}[{i}]") for i, v in enumerate(value)])


_INT32_MAX = 2**31 - 1  # the tracer's counters are 32-bit


def _count(value, where) -> int:
    """A whole number >= 0 (an integral float such as 64.0 is accepted, 2.7 is not)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SpaceError(f"{where}: expected a whole number >= 0, got {value!r}")
    if isinstance(value, float) and not (math.isfinite(value) and value.is_integer()):
        raise SpaceError(f"{where}: expected a whole number >= 0, got {value!r}")
    if not 0 <= value <= _INT32_MAX:
        raise SpaceError(f"{where}: expected a whole number between 0 and {_INT32_MAX}, got {value!r}")
    return int(value)


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


# --- the space ---------------------------------------------------------------------------------
@dataclass
class CameraDefaults:
    position: np.ndarray
    forward: np.ndarray
    up: np.ndarray
    fov: float  # horizontal field of view, degrees


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


class Space:
    """What every space has: a geometry, generators, defaults, a fundamental domain with face
    pairings, and the walk of points into it. How the domain comes about is the subclass's:
    DirichletSpace computes it from the generators, CoordinateSpace takes it from the file."""

    fold: Fold | None = None  # a folded space's fold; the tracer's domain is then its double cover's

    def __init__(self, data: dict, source: str):
        self.source = source
        where = source
        self.geometry = _geometry(data, where)
        self.id = _text(data, "id", Path(source).stem, where) or Path(source).stem
        self.name = _text(data, "name", self.id, where)
        self.description = _text(data, "description", "", where)
        self.scale = evaluate(data.get("scale", 1.0), f"{where}: scale")
        if not self.scale > 0:
            raise SpaceError(f"{where}: scale must be a positive number (Blender units per chart unit), got {self.scale:g}")
        self.max_distance = evaluate(data.get("max_distance", 20.0), f"{where}: max_distance")
        if not self.max_distance > 0:  # evaluate() already rejects non-finite values
            raise SpaceError(f"{where}: max_distance must be a positive number, got {self.max_distance:g}")
        self.max_crossings = _count(data.get("max_crossings", 64), f"{where}: max_crossings")
        self.generators = []
        self.generator_names = []
        for name, M in _generator_tables(data, where, self.geometry):
            self.generators.append(M)
            self.generator_names.append(name)
        if all(map(_is_identity, self.generators)):
            raise SpaceError(f"{where}: every generator is the identity: the group is trivial, and the space would be "
                             f"all of {self.geometry.name}, which no domain in its chart holds")
        self.camera = self._camera(data.get("camera", {}), f"{where}: camera")
        self._build_domain(data)

    def _build_domain(self, data: dict):
        raise NotImplementedError

    def _camera(self, cam, where) -> CameraDefaults:
        """The [camera] table: a point of the chart, finite non-zero non-parallel forward and up,
        a horizontal field of view strictly between 0 and 180 degrees."""
        if not isinstance(cam, dict):
            raise SpaceError(f"{where}: expected a [camera] table (position, forward, up, fov), got {cam!r}")
        g = self.geometry
        position = _vector(cam.get("position", [0, 0, 0]), 3, f"{where}.position")
        forward = _vector(cam.get("forward", [0, 1, 0]), 3, f"{where}.forward")
        up = _vector(cam.get("up", [0, 0, 1]), 3, f"{where}.up")
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
                        raise SpaceError(f"{self.source}: more than {_GROUP_LIMIT} group elements {what}: the "
                                         "group is not discrete, or its domain is far thinner than some generators "
                                         "are long, even after shortening them (give generators that pair the "
                                         "domain's faces)")
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

    def outline(self, inset: float) -> list[list[tuple[np.ndarray, np.ndarray]]]:
        """Chart segments that draw the domain, grouped by class (the default scene's tubes)."""
        raise NotImplementedError

    def guide_mesh(self) -> tuple[np.ndarray, list, list]:
        """The domain as a mesh to model inside (Blender's domain guide): chart vertices, edges
        (vertex pairs) and faces (vertex rings)."""
        d = self.domain
        return d.vertices, [(a, b) for a, b, _, _ in d.edges], [f.vertices for f in d.faces]

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
        X, V, M = self.move_inside(np.asarray(X, float)[None], None if V is None else np.asarray(V, float)[None], label=None)
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
            raise SpaceError(f"{_point_name(label, i)} ({np.asarray(x[i], float).tolist()}) is too far out in the "
                             f"chart of {g.name} (its model point overflows)")
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
            raise SpaceError(f"{_point_name(label, i)} ({where}) {why}; it cannot be brought into the domain of "
                             f"{self.id!r}")

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
            "id": self.id, "name": self.name, "geometry": self.geometry.name, "description": self.description,
            "faces": len(self.domain.faces), "vertices": len(self.domain.vertices), "source": self.source,
        }


def _point_name(label: str | None, i: int) -> str:
    """How a message names point i of those given (label None: the only one)."""
    return "the point" if label is None else f"{label} {i}"


def _text(data: dict, key: str, default: str, where: str) -> str:
    value = data.get(key, default)
    if not isinstance(value, str):
        raise SpaceError(f"{where}: {key} must be a string, got {value!r}")
    return value


def _check_keys(data, source: str):
    """SpaceError naming a key the file's tables do not have (and the nearest one they do)."""
    if not isinstance(data, dict):
        raise SpaceError(f"{source}: expected a table of fields, got {type(data).__name__}")
    check_keys(data, SPACE_KEYS, source, SpaceError)
    if isinstance(data.get("camera"), dict):
        check_keys(data["camera"], CAMERA_KEYS, f"{source}: camera", SpaceError)
    for i, gen in enumerate(data.get("generator") if isinstance(data.get("generator"), list) else []):
        if isinstance(gen, dict):
            check_keys(gen, GENERATOR_KEYS, f"{source}: generator {gen.get('name', i)!r}", SpaceError)


def _geometry(data, where):
    known = ", ".join(geometries.GEOMETRIES)
    if not isinstance(data, dict):
        raise SpaceError(f"{where}: expected a table of fields, got {type(data).__name__}")
    if "geometry" not in data:
        raise SpaceError(f"{where}: missing field 'geometry' ({known})")
    if not isinstance(data["geometry"], str):
        raise SpaceError(f"{where}: geometry must be a string ({known}), got {data['geometry']!r}")
    try:
        return geometries.get(data["geometry"])
    except ValueError as exc:
        raise SpaceError(f"{where}: {exc}") from None


def _is_identity(M) -> bool:
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
        M = np.array([_vector(r, 4, f"{w} row {k}") for k, r in enumerate(rows)])
        if not geometry.is_isometry(M, tol=1e-9):
            raise SpaceError(f"{w}: the matrix is not an isometry of {geometry.name}")
        problem = geometry.generator_problem(M)
        if problem:
            raise SpaceError(f"{w}: the matrix {problem}")
        out.append((name, geometry.reorthonormalize(M)))
    return out


def _halfspace_domain(covectors, elements, source, geometry) -> Domain:
    """The convex polyhedron {c . (x, 1) <= 0 for all c} around the chart origin, with a face for
    each covector that bounds it (vertex rings counter-clockwise seen from outside)."""
    C = np.array(covectors, float)
    C /= np.linalg.norm(C[:, :3], axis=1)[:, None]
    away = _unbounded_direction(C)
    if away is not None:
        raise SpaceError(f"{source}: the domain is not compact: it reaches out of every bound along "
                         f"{np.round(away, 6).tolist()} in the chart (the group has too few generators to close it)")
    try:
        hs = HalfspaceIntersection(C, np.zeros(3))
    except (QhullError, ValueError):
        raise SpaceError(f"{source}: the faces of the domain cannot be intersected: some of them are parallel or "
                         "coincide to rounding (generators given to too few digits, or a group that is not "
                         "discrete)") from None
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


class DirichletSpace(Space):
    """The domain is the Dirichlet domain of the chart origin, computed from the generators (the
    projective geometries, where bisectors are planes of the chart)."""

    def _build_domain(self, data: dict):
        if not self.geometry.projective:
            raise SpaceError(f"{self.source}: {self.geometry.name} has no Dirichlet domains in its chart: "
                             "give each [[generator]] the 'face' its copy of the domain lies beyond")
        self._elements: list[np.ndarray] = [np.eye(4)]
        self._radius = 0.0
        self._dirichlet_domain()

    def elements_within(self, radius: float) -> list[np.ndarray]:
        """All group elements g with d(O, gO) <= radius (identity first, then by distance)."""
        if radius > self._radius:
            self._enumerate(radius)
        g = self.geometry
        O = geometries.projective.ORIGIN
        return [M for M in self._elements if g.distance(O, M[:, 3]) <= radius + 1e-9]

    def _enumerate(self, radius):
        """Breadth-first search over words. Once the domain is known the steps are its face elements
        and h is expanded while the copy hD can meet the ball B(O, radius): those copies are connected
        through faces, so none is missed. Before that the steps are the generators and the horizon
        is one step beyond the radius; the Dirichlet construction checks what it gets."""
        g = self.geometry
        O = geometries.projective.ORIGIN
        domain = getattr(self, "domain", None)
        if domain is not None:
            steps = [f.element for f in domain.faces]
            reaches = lambda M: np.max(self.face_distances(np.linalg.solve(M, O))) <= radius + 1e-9
        else:
            steps = [*self._steps, *(np.linalg.inv(s) for s in self._steps)]
            horizon = radius + max(g.distance(O, s[:, 3]) for s in steps)

            def reaches(M):
                self._check_moves_centre(M, "a word in the generators")
                return g.distance(O, M[:, 3]) <= horizon + 1e-9
        found = self._search([np.eye(4)], steps, reaches, f"near the ball of radius {radius:.3g}")
        self._elements = sorted(found, key=lambda M: g.distance(O, M[:, 3]))
        self._radius = radius

    def face_distances(self, X):
        """Signed geodesic distances from model points to the planes of the domain's faces
        (positive outside); their maximum bounds the distance to the domain from below."""
        return self.geometry.plane_distances(X, self.domain.covectors())

    @cached_property
    def group_order(self) -> int | None:
        """Number of elements of a finite group (S3), None for infinite groups."""
        if not math.isfinite(self.geometry.diameter):
            return None
        return len(self.elements_within(self.geometry.diameter + 1e-6))

    # --- the Dirichlet domain --------------------------------------------------------------------
    def _dirichlet_domain(self) -> Domain:
        """First the polyhedron of the bisectors of the generators and their inverses: where it
        passes Poincaré's polyhedron theorem (faces paired by isometries, edge cycles of 2 pi) and
        every generator is a word in its face pairings, it is a fundamental domain of the group
        cut out by bisectors of O, so it holds the Dirichlet domain and has its volume: it is the
        Dirichlet domain (thin or long lattices get here, whose balls about O hold too many
        elements to list). Else grow the set of elements, all of those within a radius, until
        the polyhedron of their bisectors passes the theorem."""
        g = self.geometry
        O = geometries.projective.ORIGIN
        given = [(name, M) for name, M in zip(self.generator_names, self.generators) if not _is_identity(M)]
        for name, M in given:
            self._check_moves_centre(M, f"generator {name!r}", generator=True)
        self._steps = [M for _, M in given]
        shortened, moved = self._shortened(self._steps)
        # (the shortened ones too where shortening changed them: else theirs is the polyhedron just tried)
        for generators in (self._steps, shortened) if moved else (self._steps,):
            distinct = {g.element_key(N): N for M in generators + [np.linalg.inv(M) for M in generators]
                        for N in [g.reorthonormalize(M)]}
            try:
                self._bisector_domain(sorted(distinct.values(), key=lambda M: g.distance(O, M[:, 3])))
                self._check_pairings()
                rng = np.random.default_rng(20261203)
                probes = g.to_model(self._interior_points(rng, 8))
                if all(self.reduces_to_identity(M, probes) for _, M in given):
                    return self.domain
            except SpaceError:
                pass
        self._steps = shortened  # (the ball to enumerate is as large as the longest step)
        full = g.diameter + 1e-6  # in S3 every element lies within distance pi
        radius = max(g.distance(O, s[:, 3]) for s in self._steps) + 1e-6
        while True:
            # the enumeration steps by the generators, not by the faces of a polyhedron that failed
            self.__dict__.pop("domain", None)
            radius = min(radius, full)
            # (each element passed _check_moves_centre as the enumeration found it)
            self._bisector_domain(self.elements_within(radius)[1:])
            try:
                self._check_pairings()
            except SpaceError:
                # faces can only come from elements within twice the circumradius
                if 2 * self.circumradius <= radius or radius >= full:
                    raise
                radius = min(2 * self.circumradius + 1e-6, 1.5 * radius)
                continue
            self._elements, self._radius = [np.eye(4)], 0.0  # enumerate again with face steps
            return self.domain

    def _shortened(self, generators: list[np.ndarray]) -> tuple[list[np.ndarray], bool]:
        """(generators of the same group that move O less, whether any changed): each replaced by
        its product with powers of another (on either side, the power doubled while the product
        keeps shortening: Nielsen moves, which keep the group) while that shortens it, and those
        that become the identity dropped. A skewed lattice basis becomes a reduced one, whose
        bisectors bound the domain and whose ball about O holds few elements."""
        g = self.geometry
        gens = [g.reorthonormalize(M) for M in generators]
        moved = False
        for _ in range(_SHORTENING_ROUNDS):
            changed = False
            for i, j in itertools.permutations(range(len(gens)), 2):
                for s, left in itertools.product((gens[j], np.linalg.inv(gens[j])), (False, True)):
                    if _is_identity(gens[i]) or _is_identity(gens[j]):
                        break
                    shorter = self._shortened_by(gens[i], s, left)
                    if shorter is not gens[i]:
                        gens[i], changed = shorter, True
            moved |= changed
            if not changed:
                break
        kept = [M for M in gens if not _is_identity(M)]
        return kept, moved or len(kept) < len(gens)

    def _shortened_by(self, M, s, left: bool):
        """M times powers of s (s^k M where left, else M s^k) while that moves O less, the power
        doubled while the product keeps shortening and back to s where it overshoots; M itself
        where no power shortens it, the identity where one cancels it."""
        g = self.geometry
        O = geometries.projective.ORIGIN
        length = lambda N: g.distance(O, N[:, 3])
        step = s
        while not _is_identity(M):
            shorter = g.reorthonormalize(step @ M if left else M @ step)
            if not length(shorter) < length(M) * (1 - 1e-9):
                if step is s:
                    break
                step = s  # the doubled power overshot: go on from single steps
                continue
            if not _is_identity(shorter):
                self._check_moves_centre(shorter, "a word in the generators")
            M, step = shorter, g.reorthonormalize(step @ step)
        return M

    def _bisector_domain(self, elements):
        """self.domain: the polyhedron of the bisectors of O and the elements' images of it."""
        g = self.geometry
        self.domain = _halfspace_domain([g.bisector(M[:, 3]) for M in elements], elements, self.source, g)
        for cached in ("edge_cycles", "circumradius"):
            self.__dict__.pop(cached, None)

    def _check_pairings(self):
        """SpaceError unless the domain's faces are paired, and glue a manifold (Poincaré's theorem)."""
        self._pair_faces(self.domain)
        self._validate()

    def _check_moves_centre(self, M, what: str, generator: bool = False):
        """SpaceError where the element M (not the identity) fixes the domain centre O, or moves it
        by less than the domain's computation resolves (group elements are told apart to 1e-7)."""
        X = np.asarray(M, float)[:, 3]
        moved = float(np.linalg.norm(X[:3]))  # d, sin d or sinh d for the distance d: exact where d is small
        if X[3] < 0 or moved >= CENTRE_RESOLUTION:  # (X[3] < 0: O's antipode in S3)
            return
        if moved < 1e-12:
            raise SpaceError(f"{self.source}: {what} fixes the domain centre (the chart origin) without being the "
                             "identity: the group does not act freely, so the space is not a manifold")
        if generator:
            raise SpaceError(f"{self.source}: {what} moves the domain centre by only {moved:.3g}, less than the "
                             f"{CENTRE_RESOLUTION:g} the domain's computation resolves (a flat space can be written "
                             "in larger chart units, with `scale` set to match)")
        raise SpaceError(f"{self.source}: {what} moves the domain centre by only {moved:.3g}, less than the "
                         f"{CENTRE_RESOLUTION:g} the domain's computation resolves: a word in the generators that "
                         "should be the identity is not (their entries disagree at that level: give them exactly, "
                         "e.g. 'sqrt(3)/2'), or the group is not discrete")

    def _pair_faces(self, domain: Domain):
        g = self.geometry
        where = self.source
        keys = {g.element_key(f.element): i for i, f in enumerate(domain.faces)}
        for i, face in enumerate(domain.faces):
            inv = np.linalg.inv(face.element)
            j = keys.get(g.element_key(inv))
            if j is None:
                raise SpaceError(f"{where}: face {i} has no partner face (the inverse of its element is not a face)")
            face.partner = j
            image = g.transform_points(face.pairing, domain.vertices[face.vertices])
            target = domain.faces[j].vertices
            for v, p in zip(face.vertices, image):
                d = np.linalg.norm(domain.vertices[target] - p, axis=1)
                k = int(np.argmin(d))
                if d[k] > 1e-7 * (1 + np.linalg.norm(p)):
                    raise SpaceError(f"{where}: the pairing of face {i} does not map its vertex {v} onto a vertex of face {j}")
                face.vertex_map[v] = target[k]
            if sorted(face.vertex_map.values()) != sorted(target):
                raise SpaceError(f"{where}: the pairing of face {i} does not map it onto face {j}")

    # --- validation and invariants ----------------------------------------------------------------
    @cached_property
    def edge_cycles(self) -> list[list[tuple[int, int]]]:
        """Edge classes: each a list of (edge index, face index) visited by the pairings."""
        dom = self.domain
        index = {(a, b): e for e, (a, b, _, _) in enumerate(dom.edges)}
        seen = set()
        cycles = []
        for e0, (a, b, f0, _) in enumerate(dom.edges):
            if e0 in seen:
                continue
            cycle = []
            e, f = e0, f0
            for _ in range(len(dom.edges) + 1):
                cycle.append((e, f))
                seen.add(e)
                a, b = dom.edges[e][:2]
                face = dom.faces[f]
                image = tuple(sorted((face.vertex_map[a], face.vertex_map[b])))
                e = index[image]
                _, _, fi, fj = dom.edges[e]
                f = fj if fi == face.partner else fi
                if e == e0:
                    break
            cycles.append(cycle)
        return cycles

    def outline(self, inset: float) -> list[list[tuple[np.ndarray, np.ndarray]]]:
        """The domain's edges, by edge class (`inset` is not needed: an edge is its own class's)."""
        dom = self.domain
        edge_class = {e: c for c, cycle in enumerate(self.edge_cycles) for e, _ in cycle}
        groups: list[list] = [[] for _ in self.edge_cycles]
        for e, (a, b, _, _) in enumerate(dom.edges):
            groups[edge_class[e]].append((dom.vertices[a], dom.vertices[b]))
        return groups

    def dihedral_angle(self, edge: int) -> float:
        _, _, fi, fj = self.domain.edges[edge]
        faces = self.domain.faces
        return float(self.geometry.dihedral_angle(faces[fi].covector, faces[fj].covector))

    def _validate(self):
        where = self.source
        for i, face in enumerate(self.domain.faces):
            if not self.geometry.is_isometry(face.pairing, tol=1e-8):
                raise SpaceError(f"{where}: the pairing of face {i} is not an isometry")
        for cycle in self.edge_cycles:
            total = sum(self.dihedral_angle(e) for e, _ in cycle)
            if abs(total - 2 * math.pi) > 1e-6:
                e = cycle[0][0]
                a, b = self.domain.edges[e][:2]
                raise SpaceError(
                    f"{where}: the dihedral angles around the edge class of edge {a}-{b} sum to {total:.6f}, not 2 pi; "
                    "the face pairings do not glue a manifold"
                )

    @cached_property
    def inradius(self) -> float:
        return float(min(self.geometry.plane_distance(f.covector) for f in self.domain.faces))

    @cached_property
    def circumradius(self) -> float:
        g = self.geometry
        return float(max(g.distance(geometries.projective.ORIGIN, g.to_model(v)) for v in self.domain.vertices))

    @cached_property
    def volume(self) -> float:
        """Riemannian volume of the domain: cones from the origin over the faces, the radial integral
        in closed form and a Gauss-Legendre (Duffy) rule on each face triangle."""
        g = self.geometry
        u, w = np.polynomial.legendre.leggauss(24)
        u, w = 0.5 * (u + 1), 0.5 * w
        U, W = np.meshgrid(u, u, indexing="ij")
        WW = np.outer(w, w)
        total = 0.0
        V = self.domain.vertices
        for face in self.domain.faces:
            ring = V[face.vertices]
            centre = ring.mean(axis=0)
            n = face.covector[:3]
            h = abs(face.covector[3]) / np.linalg.norm(n)
            for p, q in zip(ring, np.roll(ring, -1, axis=0)):
                # x(U, W) = centre + U (p - centre) + U W (q - p); dA = 2 area U dU dW
                X = centre + U[..., None] * (p - centre) + (U * W)[..., None] * (q - p)
                area2 = np.linalg.norm(np.cross(p - centre, q - centre))
                r = np.linalg.norm(X, axis=-1)
                total += np.sum(WW * U * area2 * g.cone_radial_integral(r) * h / r**3)
        return float(total)

    @cached_property
    def holonomy(self) -> list[np.ndarray]:
        """Linear parts of the group (E3): the holonomy group of a flat manifold."""
        found = {tuple(np.round(np.eye(3).ravel(), 6)): np.eye(3)}
        frontier = [np.eye(3)]
        while frontier:
            nxt = []
            for R in frontier:
                for s in self.generators:
                    N = s[:3, :3] @ R
                    key = tuple(np.round(N.ravel(), 6))
                    if key not in found:
                        found[key] = N
                        nxt.append(N)
            frontier = nxt
        return list(found.values())


class CoordinateSpace(Space):
    """The domain is given: each generator g names the face plane beyond which its copy gD lies
    (`face = [a, b, c, d]`: the plane a x + b y + c z + d = 0 with the domain on the side <= 0).
    The opposite face, beyond which g^-1 D lies, is its image under g^-1. Face maps need not map
    faces onto faces (Nil's shear, Sol's lids): a point that leaves is carried back by the face's
    map and then reduced into the domain by the maps of the faces it lies outside of.
    Validated on load: the generators are isometries, the faces bound a compact domain around the
    chart origin, conjugates of generators by generators and their inverses reduce to the identity
    (the group is discrete with this domain), random points and their images under random words
    reduce to one point, and the domain's volume equals the file's `covolume` where it gives one."""

    def _build_domain(self, data: dict):
        where = self.source
        gens = data.get("generator")
        covectors, elements = [], []
        for (name, M), gen in zip(zip(self.generator_names, self.generators), gens):
            if "face" not in gen:
                raise SpaceError(f"{where}: generator {name!r} has no 'face', but others do: "
                                 "give every generator of a coordinate domain its face")
            c = _vector(gen["face"], 4, f"{where}: generator {name!r} face")
            if not np.linalg.norm(c[:3]) > 0:
                raise SpaceError(f"{where}: generator {name!r} face {c.tolist()} is not a plane")
            if not c[3] < 0:
                raise SpaceError(f"{where}: generator {name!r} face {c.tolist()} must have the chart origin "
                                 "strictly inside (its last entry < 0)")
            if _is_identity(M):
                raise SpaceError(f"{where}: generator {name!r} is the identity: it pairs its face with no other")
            try:
                image = -self.geometry.pull_back_plane(c, M)
            except ValueError as exc:
                raise SpaceError(f"{where}: generator {name!r}: {exc}") from None
            covectors += [c, image]
            elements += [M, np.linalg.inv(M)]
        self.domain = self._face_domain(covectors, elements)
        if len(self.domain.faces) != len(covectors):
            raise SpaceError(f"{where}: {len(covectors) - len(self.domain.faces)} of the generators' faces "
                             "do not bound the domain (each face and its image must be faces of it)")
        keys = {self.geometry.element_key(f.element): i for i, f in enumerate(self.domain.faces)}
        for face in self.domain.faces:
            face.partner = keys[self.geometry.element_key(np.linalg.inv(face.element))]
        self._validate(data)

    def _face_domain(self, covectors, elements) -> Domain:
        """The polyhedron of the faces (each generator's, then its image), around the chart origin."""
        for k, image in enumerate(covectors[1::2]):
            if not image[3] < 0:
                raise SpaceError(f"{self.source}: generator {self.generator_names[k]!r} carries its face "
                                 f"{np.round(covectors[2 * k], 12).tolist()} to {np.round(image, 12).tolist()}, which does "
                                 "not have the chart origin inside: the face must lie between the domain and the "
                                 "generator's copy of it")
        return _halfspace_domain(covectors, elements, self.source, self.geometry)

    group_order = None  # lattices and bundles: infinite

    def farthest_distance(self, X) -> float:
        """The largest distance from the model point X to the domain's points, or an upper bound of it
        (the geometry's farthest_distance)."""
        return self.geometry.farthest_distance(X, self.domain)

    @cached_property
    def circumradius(self) -> float:
        """The largest distance from the chart origin (the domain's centre) to the domain (or the
        geometry's upper bound of it)."""
        return self.farthest_distance(self.geometry.to_model(np.zeros(3)))

    @property
    def inradius(self) -> float:
        """The inradius to first order at the chart origin: the metric length there of the chart
        vectors to the faces' feet (Nil's, Sol's and H2xR's metrics are Euclidean at the origin)."""
        feet = self.face_feet
        g0 = self.geometry.metric(np.zeros(3))
        return float(np.sqrt(np.min(np.einsum("fi,ij,fj->f", feet, g0, feet))))

    @cached_property
    def plane_vertices(self) -> np.ndarray:
        """The domain's vertices in the plane chart, where its faces are planes."""
        g = self.geometry
        Y = g.plane_coordinates(g.to_model(self.domain.vertices))
        return Y[:, :3] / Y[:, 3:]

    def outline(self, inset: float) -> list[list[tuple[np.ndarray, np.ndarray]]]:
        """Each face's frame, its edges moved `inset` into the face, by face class: a face and its
        partner share a colour (as in the paper's Nil and Sol figures), so where the pairing twists
        the frames seen through a face do not continue those around it."""
        V = self.plane_vertices
        groups: list[list] = [[] for _ in range(max(self.face_classes) + 1)]
        for face, c in zip(self.domain.faces, self.face_classes):
            ring = V[face.vertices]
            centre = ring.mean(axis=0)
            n = face.covector[:3] / np.linalg.norm(face.covector[:3])
            k = len(ring)
            inward = [np.cross(n, ring[(i + 1) % k] - ring[i]) for i in range(k)]
            inward = [d / np.linalg.norm(d) * np.sign(d @ (centre - ring[i])) for i, d in enumerate(inward)]
            corners = []
            for i in range(k):
                a, b = inward[i - 1], inward[i]  # unit inward normals of the sides before and after vertex i
                # the point of the face at distance `inset` from both sides: ring[i] + x a + y b
                G = np.array([[a @ a, a @ b], [a @ b, b @ b]])
                corners.append(ring[i] + np.linalg.solve(G, [inset, inset]) @ np.array([a, b]))
            groups[c] += [piece for i in range(k) for piece in self._chart_segments(corners[i], corners[(i + 1) % k])]
        return groups

    PIECES = 16  # chart chords per plane-chart segment where the faces are curved in the chart

    def _chart_segments(self, a, b):
        """The plane-chart segment a b in the chart: itself, or chart chords of its image (curved
        where the plane chart is not the chart)."""
        g = self.geometry
        if g.plane_chart_is_chart:
            return [(a, b)]
        x = g.from_plane_chart(a + np.linspace(0, 1, self.PIECES + 1)[:, None] * (b - a))
        return list(zip(x[:-1], x[1:]))

    def guide_mesh(self) -> tuple[np.ndarray, list, list]:
        """The domain's faces and edges; where the plane chart is not the chart, each face's fan of
        triangles from its centre subdivided in the plane chart, and each edge in PIECES, carried
        to the chart."""
        if self.geometry.plane_chart_is_chart:
            return super().guide_mesh()
        import trimesh

        V = self.plane_vertices
        points, triangles, pairs, count = [], [], [], 0
        for face in self.domain.faces:
            ring = V[face.vertices]
            k = len(ring)
            y, t = np.vstack([ring, ring.mean(axis=0)]), np.array([[i, (i + 1) % k, k] for i in range(k)])
            for _ in range(4):
                y, t = trimesh.remesh.subdivide(y, t)
            points.append(y)
            triangles += (t + count).tolist()
            count += len(y)
        steps = np.linspace(0, 1, self.PIECES + 1)[:, None]
        for a, b, _, _ in self.domain.edges:
            points.append(V[a] + steps * (V[b] - V[a]))
            pairs += [(count + i, count + i + 1) for i in range(self.PIECES)]
            count += self.PIECES + 1
        return self.geometry.from_plane_chart(np.vstack(points)), pairs, triangles

    @cached_property
    def volume(self) -> float:
        """Riemannian volume of the domain: the volume density integrated over the cones from the
        origin over the face triangles in the plane chart, by a collapsed Gauss-Legendre rule on
        each (the Dirichlet domains' radial closed form needs a projective chart)."""
        g = self.geometry
        u, w = np.polynomial.legendre.leggauss(g.volume_order)
        u, w = 0.5 * (u + 1), 0.5 * w
        # (a, b, c) in the unit cube -> the tetrahedron (0, p, q, r): x = a (p + b (q - p + c (r - q)))
        A, B, Cc = np.meshgrid(u, u, u, indexing="ij")
        W = np.einsum("i,j,k->ijk", w, w, w) * A**2 * B
        V = self.plane_vertices
        total = 0.0
        for face in self.domain.faces:
            ring = V[face.vertices]
            centre = ring.mean(axis=0)
            for p, q in zip(ring, np.roll(ring, -1, axis=0)):
                X = A[..., None] * (centre + B[..., None] * (p - centre + Cc[..., None] * (q - p)))
                jac = abs(np.linalg.det(np.array([centre, p - centre, q - p])))
                total += float(np.sum(W * jac * g.plane_chart_density(X)))
        return total

    def _validate(self, data: dict):
        where = self.source
        g = self.geometry
        rng = np.random.default_rng(20261201)
        probes = g.to_model(self._interior_points(rng, 8))
        words = [*self.generators, *(np.linalg.inv(M) for M in self.generators)]
        for (i, a), b in ((p, b) for p in enumerate(self.generators) for b in words):
            if not self.reduces_to_identity(b @ a @ np.linalg.inv(b), probes):
                raise SpaceError(f"{where}: the conjugate of generator {self.generator_names[i]!r} by another generator "
                                 "is not in the group the domain tiles by: the group is not discrete with this domain")
        # p and w(p) reduce to one point for random words w
        points = g.to_model(self._interior_points(rng, 64))
        for _ in range(8):
            W = np.eye(4)
            for k in rng.integers(0, len(words), 6):
                W = W @ words[k]
            Y, _, _ = self.move_inside(points @ W.T)
            # the float64 generators satisfy the group's relations to rounding of the word's size
            if not np.allclose(g.to_chart(Y), g.to_chart(points), atol=1e-8 * max(1.0, np.abs(W).max())):
                raise SpaceError(f"{where}: points and their images under the group reduce to different points of "
                                 "the domain: the faces do not bound a fundamental domain of the group")
        if "covolume" in data:
            covolume = evaluate(data["covolume"], f"{where}: covolume")
            if abs(self.volume - covolume) > 1e-6 * max(1.0, covolume):
                raise SpaceError(f"{where}: the domain's volume {self.volume:.9g} is not the covolume {covolume:.9g} "
                                 "the file states")


def _sphere_face(c, where, geometry) -> tuple[float, bool]:
    """(w0, whether the shell lies inside it) of a shell's face covector (0, 0, c, d): the sphere
    c log|x| + d = 0, the domain on the side <= 0."""
    if c[0] != 0 or c[1] != 0 or c[2] == 0:
        raise SpaceError(f"{where}: the face {c.tolist()} is not a sphere |x| = const "
                         f"({geometry.name} faces are [0, 0, c, d]: the sphere c log|x| + d = 0)")
    return -c[3] / c[2], bool(c[2] > 0)


class ShellSpace(CoordinateSpace):
    """A coordinate domain whose faces are the spheres |x| = e^w0 of S2xR: the shell between the
    inner and the outer one. Each face is given as the covector (0, 0, c, d) of the geometry's
    plane coordinates (0, 0, w, 1), w = log|x|: the sphere c w + d = 0, the domain on the side
    <= 0. A shell has no edges (its faces no vertex rings); `domain.vertices` are the spheres'
    points on the chart axes (they span the domain's chart box, and the group's copies of them its
    neighbours)."""

    def _face_domain(self, covectors, elements) -> Domain:
        where = self.source
        bounds = [_sphere_face(c, where, self.geometry) for c in covectors]  # (w0, an outer face w <= w0)
        outer = min((w for w, s in bounds if s), default=math.inf)
        inner = max((w for w, s in bounds if not s), default=-math.inf)
        if not inner < outer < math.inf:
            raise SpaceError(f"{where}: the faces do not bound a shell between two spheres")
        if any(abs(w - (outer if s else inner)) > 1e-12 * (1 + abs(w)) for w, s in bounds):
            raise SpaceError(f"{where}: a face sphere does not bound the shell between |x| = e^{inner:g} and e^{outer:g}")
        axes = np.vstack([np.eye(3), -np.eye(3)])
        vertices = np.vstack([math.exp(inner) * axes, math.exp(outer) * axes])
        faces = [Face(covector=np.asarray(c, float) / np.linalg.norm(c[:3]), element=M, vertices=[])
                 for c, M in zip(covectors, elements)]
        self.radii = (math.exp(inner), math.exp(outer))
        return Domain(vertices=vertices, faces=faces, plane_coordinates=self.geometry.plane_coordinates)

    @property
    def inradius(self) -> float:
        """Half the shell's width, log(R_out / R_in) / 2: the radius of the largest metric ball in it."""
        return 0.5 * math.log(self.radii[1] / self.radii[0])

    def farthest_distance(self, X) -> float:
        """The antipodal direction on the farther face sphere: hypot(pi, the larger difference of w)."""
        w = float(self.geometry.plane_coordinates(np.asarray(X, float))[2])
        lo, hi = np.log(self.radii)
        return math.hypot(math.pi, max(w - lo, hi - w))

    @cached_property
    def circumradius(self) -> float:
        """About a point of the middle sphere: hypot(pi, half the shell's width)."""
        return math.hypot(math.pi, self.inradius)

    @property
    def metric_extent(self) -> float:
        """The shell's metric diameter: the line's extent and half a great circle."""
        return math.hypot(math.log(self.radii[1] / self.radii[0]), math.pi)

    @cached_property
    def chart_inradius(self) -> float:
        """The radius of the largest chart ball inside the shell."""
        return 0.5 * (self.radii[1] - self.radii[0])

    @cached_property
    def volume(self) -> float:
        """The volume density integrated over the shell in the coordinates (w, cos theta, phi),
        x = e^w u(theta, phi) (chart volume e^{3 w} dw dcos dphi), by Gauss-Legendre rules."""
        g = self.geometry
        u, weights = np.polynomial.legendre.leggauss(g.volume_order)
        lo, hi = np.log(self.radii)
        w = lo + (hi - lo) * (u + 1) / 2
        cos, phi = u, np.pi * (u + 1)
        W, C, P = np.meshgrid(w, cos, phi, indexing="ij")
        S = np.sqrt(1 - C**2)
        x = np.exp(W)[..., None] * np.stack([S * np.cos(P), S * np.sin(P), C], axis=-1)
        jacobian = np.exp(3 * W) * (hi - lo) / 2 * np.pi
        weight = np.einsum("i,j,k->ijk", weights, weights, weights)
        return float(np.sum(weight * jacobian * g.volume_density(x)))

    def outline(self, inset: float) -> list[list[tuple[np.ndarray, np.ndarray]]]:
        """Three great circles on each face sphere, moved `inset` into the shell, by face class
        (a sphere and its partner share one; a class is drawn once, on its outer sphere)."""
        groups: list[list] = [[] for _ in range(max(self.face_classes) + 1)]
        angles = np.linspace(0, 2 * np.pi, 97)
        circle = np.c_[np.cos(angles), np.sin(angles), np.zeros_like(angles)]
        drawn = set()
        for face, c in sorted(zip(self.domain.faces, self.face_classes), key=lambda fc: -fc[0].covector[2]):
            if c in drawn:
                continue
            drawn.add(c)
            outer = face.covector[2] > 0
            radius = self.radii[1] - inset if outer else self.radii[0] + inset * self.radii[0] / self.radii[1]
            for axes in ([0, 1, 2], [1, 2, 0], [2, 0, 1]):
                ring = radius * circle[:, axes]
                groups[c] += list(zip(ring[:-1], ring[1:]))
        return groups

    def guide_mesh(self) -> tuple[np.ndarray, list, list]:
        """The shell's two spheres, as latitude-longitude meshes."""
        import trimesh

        sphere = trimesh.creation.uv_sphere(radius=1.0, count=[12, 24])
        V = np.vstack([r * sphere.vertices for r in self.radii])
        faces = np.vstack([sphere.faces, sphere.faces + len(sphere.vertices)])
        return V, [], faces.tolist()


class FoldedShellSpace(ShellSpace):
    """A shell each of whose two spheres is glued to itself by the antipodal reflection in it,
    x -> -R^2 x / |x|^2 (S2xR: RP^3 # RP^3), written `antipodal = true` in a generator's place of a
    matrix, with its sphere as the face. No 4x4 linear model holds those reflections beside the
    dilations, so the space is traced through its double cover (a Fold): the shell doubled by the
    inner reflection, w in [2 a - b, b] for the file's a <= w <= b, its spheres paired by the
    dilation e^(2 (b - a)) that the two reflections compose to. The file's shell is the space's
    domain for everything a user sees (guide, outline, volume, inradius); `domain` is the cover's,
    which the tracer walks. Validated on load beyond the cover's checks: the reflections pull the
    metric back onto itself, and random points and their images under words in the reflections
    reduce to one point of the file's shell."""

    def __init__(self, data: dict, source: str):
        g = _geometry(data, source)
        faces = []
        for i, gen in enumerate(data.get("generator") or []):
            name = gen.get("name", f"g{i}") if isinstance(gen, dict) else f"g{i}"
            where = f"{source}: generator {name!r}"
            if not isinstance(gen, dict) or gen.get("antipodal") is not True:
                raise SpaceError(f"{where}: in a shell whose spheres are glued to themselves every generator is "
                                 "'antipodal = true' with its sphere as the face")
            if "matrix" in gen:
                raise SpaceError(f"{where}: an antipodal reflection has no matrix (no 4x4 linear map is one); "
                                 "give only its face")
            faces.append(_sphere_face(_vector(gen.get("face"), 4, f"{where} face"), where, g))
        if len(faces) != 2:
            raise SpaceError(f"{source}: a shell glued to itself has two antipodal reflections, one in each sphere; "
                             f"got {len(faces)}")
        (a, a_outer), (b, b_outer) = sorted(faces)
        if not (b > a and b_outer and not a_outer):
            raise SpaceError(f"{source}: the two reflections' faces do not bound a shell (the inner sphere's face is "
                             "[0, 0, -1, log R_in], the outer's [0, 0, 1, -log R_out], R_in < R_out)")
        self.folded_radii = (math.exp(a), math.exp(b))
        self.fold = Fold(points=lambda x: geometries.s2xr.antipodal_reflection(x, self.folded_radii[0]),
                         vectors=lambda x, v: geometries.s2xr.antipodal_reflection_tangent(x, v, self.folded_radii[0]),
                         mirrored=lambda x: np.sum(np.asarray(x) ** 2, axis=-1) < self.folded_radii[0] ** 2)
        period = 2 * (b - a)
        cover = dict(data, generator=[{
            "name": "reflections",  # the outer reflection after the inner: the dilation by e^period
            "matrix": np.diag([math.exp(period)] * 3 + [1.0]).tolist(), "face": [0, 0, 1, -b]}])
        super().__init__(cover, source)

    def _face_domain(self, covectors, elements) -> Domain:
        domain = super()._face_domain(covectors, elements)
        self.radii = self.folded_radii  # the file's shell, for what a user sees
        return domain

    def _validate(self, data: dict):
        super()._validate(data)
        g = self.geometry
        rng = np.random.default_rng(20261202)
        u = rng.normal(size=(32, 3))
        x = u / np.linalg.norm(u, axis=1)[:, None] * np.exp(rng.uniform(*np.log(self.radii), 32))[:, None]
        reflections = [lambda p, r=r: geometries.s2xr.antipodal_reflection(p, r) for r in self.radii]
        for r in self.radii:  # each pulls the metric back onto itself
            p, e = x[:4], np.eye(3)
            J = np.stack([geometries.s2xr.antipodal_reflection_tangent(p, np.broadcast_to(v, p.shape), r) for v in e], -1)
            image = geometries.s2xr.antipodal_reflection(p, r)
            pulled = np.einsum("nki,nkl,nlj->nij", J, g.metric(image), J)
            want = g.metric(p)
            if not np.allclose(pulled, want, rtol=0, atol=1e-9 * np.abs(want).max()):
                raise SpaceError(f"{self.source}: the antipodal reflection in |x| = {r:g} is not an isometry of {g.name}")
        for _ in range(6):  # words in the reflections reduce to the point itself
            y = x.copy()
            for k in rng.integers(0, 2, 5):
                y = reflections[k](y)
            back, _ = self.unfolded(g.to_chart(self.move_inside(g.to_model(y))[0]))
            if not np.allclose(back, x, rtol=1e-8, atol=1e-8):
                raise SpaceError(f"{self.source}: points and their images under the reflections reduce to different "
                                 "points of the shell: the faces do not bound its fundamental domain")


def from_data(data: dict, source: str) -> Space:
    """The space a file's fields describe: a coordinate domain where the generators name their
    faces (a shell where the geometry's faces are spheres), else the Dirichlet domain of the
    chart origin."""
    _check_keys(data, source)
    gens = data.get("generator")
    given = isinstance(gens, list) and any(isinstance(g, dict) and "face" in g for g in gens)
    if not given:
        return DirichletSpace(data, source)
    if _geometry(data, source).chart_plane_faces:
        return CoordinateSpace(data, source)
    folded = any(isinstance(g, dict) and "antipodal" in g for g in gens)
    return (FoldedShellSpace if folded else ShellSpace)(data, source)


def preset_dirs() -> list[Path]:
    """Where presets are found: the folders of $THURSTON_SPACE_PATH in order, then the built-in ones."""
    extra = [Path(p) for p in os.environ.get(SPACE_PATH_VARIABLE, "").split(os.pathsep) if p]
    return [*extra, PRESET_DIR]


def preset_path(space_id: str) -> Path | None:
    """The file of a preset id (the first folder of preset_dirs() that has it), None if there is none."""
    for folder in preset_dirs():
        path = folder / f"{space_id}.toml"
        if path.is_file():
            return path
    return None


def load(path_or_id: str | Path) -> Space:
    """A preset by id, or a space file by path."""
    path = Path(path_or_id)
    if not path.suffix and not path.exists():
        path = preset_path(str(path_or_id))
        if path is None:
            raise SpaceError(f"unknown space {str(path_or_id)!r}: not a preset ({', '.join(preset_ids())}) and not a file")
    text = read_text(path, "space file", SpaceError, "space file")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpaceError(f"space file {str(path)!r} is not valid TOML: {exc}") from None
    return from_data(data, str(path))


def preset_ids() -> list[str]:
    """Every preset id, the user's and the built-in ones, sorted."""
    return sorted({p.stem for folder in preset_dirs() if folder.is_dir() for p in folder.glob("*.toml")})
