"""Families of spaces with parameters, named as mathematicians name them: `lens(7,2)` (the lens
space L(7, 2)), `prism(3)`, `binary(icosahedral)`, `flat(amphicosm1)`, `nil(3)`. A member is a
space file the family writes (to the cache folder, where users can keep and edit it; loading
validates it like any other, its volume against the family's closed form), so nothing else in the
program knows the families. FAMILIES is the one list of them (`thurston spaces` shows it)."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .values import SpaceError
from .writing import cache_dir, file_name, write_space

S3_CAMERA = {"position": [0.005, -0.008, 0.003], "forward": [0.2, 1.0, 0.1], "up": [0, 0, 1], "fov": 90}
FLAT_CAMERA = {"position": [0.02, -0.04, 0.01], "forward": [0.35, 1.0, 0.15], "up": [0, 0, 1], "fov": 90}


@dataclass(frozen=True)
class Family:
    key: str  # the name's head: key(parameters)
    geometry: str
    parameters: str  # what the parameters are, for the listing
    summary: str
    example: str
    build: Callable[..., dict]  # the parameters -> a space file's fields


def _affine(R, t) -> list:
    """The 4x4 matrix of x -> R x + t (E3)."""
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, t
    return M.tolist()


def _space(member: str, name: str, geometry: str, description: str, covolume: float, generators, camera, **limits):
    return {
        "id": member,
        "name": name,
        "geometry": geometry,
        "description": description,
        "covolume": covolume,
        **limits,
        "camera": camera,
        "generator": [{"name": n, "matrix": np.asarray(M, float).tolist()} for n, M in generators],
    }


# --- S3: quotients of the 3-sphere by finite groups ----------------------------------------------
# A point of S3 is a unit quaternion w + x i + y j + z k, the model vector (x, y, z, w): the chart
# origin is 1. A group acting by left multiplication has every point as a good domain centre.


def _quaternion_product(a, b):
    (x1, y1, z1, w1), (x2, y2, z2, w2) = a, b
    return np.array(
        [
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        ]
    )


def _left(u) -> np.ndarray:
    """Left multiplication by the unit quaternion u (x, y, z, w) as a matrix on model vectors."""
    u = np.asarray(u, float) / np.linalg.norm(u)
    return np.column_stack([_quaternion_product(u, e) for e in np.eye(4)])


def _spherical(member, name, description, order, generators):
    return _space(
        member,
        name,
        "S3",
        f"{description}; group order {order}, volume 2π²/{order}",
        2 * math.pi**2 / order,
        generators,
        S3_CAMERA,
        max_distance=18.85,  # three times around the 3-sphere
        max_crossings=96,
    )


def lens(member, p: int, q: int) -> dict:
    """L(p, q) = S3 / Z/p, (z1, z2) -> (ζ z1, ζ^q z2), ζ = e^(2πi/p), z1 = X0 + i X1, z2 = X2 + i X3;
    seen from a point of the Clifford torus |z1| = |z2|, whose orbit spans R^4 when q ≠ ±1 (mod p):
    its Dirichlet domain then lies within distance π/2, inside the gnomonic chart."""
    if p < 2 or math.gcd(p, q) != 1:
        raise SpaceError(f"{member}: L(p, q) needs p >= 2 and q prime to p, got p = {p}, q = {q}")
    if q % p in (1, p - 1):
        raise SpaceError(
            f"{member}: L({p}, ±1){' = RP³' if p == 2 else ''} is not supported: its group acts on C² "
            "by scalars (for one of the two complex structures), so for any centre x the circle of the "
            "complex line orthogonal to x is a whole orbit at distance π/2 from x, on the horizon of S3's "
            "gnomonic chart around x; every fundamental domain holds a point of that orbit, so none fits "
            f"in the chart (a Dirichlet domain or any other). A q ≠ ±1 (mod p) works, e.g. lens({max(p, 5)},2)"
        )
    angle = 2 * math.pi / p
    G = np.zeros((4, 4))
    for k, a in ((0, angle), (2, q * angle)):
        G[k : k + 2, k : k + 2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    R = np.eye(4)  # takes the chart origin (0, 0, 0, 1) to the Clifford torus point (1, 0, 0, 1)/√2
    R[np.ix_([0, 3], [0, 3])] = [[math.sqrt(0.5), math.sqrt(0.5)], [-math.sqrt(0.5), math.sqrt(0.5)]]
    return _spherical(member, f"L({p}, {q})", f"Lens space L({p}, {q}) = S3 / Z/{p}", p, [("g", R.T @ G @ R)])


def prism(member, n: int) -> dict:
    """S3 / D*_4n, the binary dihedral group <e^(iπ/n), j> of order 4n (n = 2: the quaternion group)."""
    if n < 2:
        raise SpaceError(f"{member}: the prism manifold S3 / D*_4n needs n >= 2, got {n}")
    a = [math.sin(math.pi / n), 0, 0, math.cos(math.pi / n)]
    return _spherical(
        member,
        f"prism manifold S3 / D*{4 * n}",
        f"Prism manifold: S3 / the binary dihedral group D*{4 * n}",
        4 * n,
        [("a", _left(a)), ("b", _left([0, 1, 0, 0]))],
    )


PHI = (1 + math.sqrt(5)) / 2
BINARY = {  # the binary polyhedral groups: generators (x, y, z, w) and order
    "tetrahedral": ([[1, 0, 0, 0], [1, 1, 1, 1]], 24),
    "octahedral": ([[1, 0, 0, 1], [1, 1, 1, 1]], 48),
    "icosahedral": ([[1, 1, 1, 1], [1 / PHI, 1, 0, PHI]], 120),
}


def binary(member, which: str) -> dict:
    """S3 / the binary tetrahedral, octahedral or icosahedral group (the last: the Poincaré sphere)."""
    if which not in BINARY:
        raise SpaceError(f"{member}: the binary groups are {', '.join(BINARY)}, got {which!r}")
    gens, order = BINARY[which]
    return _spherical(
        member,
        f"S3 / binary {which}",
        f"Spherical: S3 / the binary {which} group",
        order,
        [(f"g{i}", _left(u)) for i, u in enumerate(gens)],
    )


# --- E3: the ten closed flat manifolds (Conway and Rossetti's names) ------------------------------
_I = np.eye(3)
_HALF_X, _HALF_Z = np.diag([1.0, -1, -1]), np.diag([-1.0, -1, 1])
_MIRROR_Z = np.diag([1.0, 1, -1])


def _turn(k):  # the rotation by 2π/k about z
    c, s = math.cos(2 * math.pi / k), math.sin(2 * math.pi / k)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


_HEX = [(1, 0, 0), (0.5, math.sqrt(3) / 2, 0)]
# name: (orientable, lattice translations, further generators (R, t), holonomy order)
FLAT = {
    "torocosm": (True, [(1, 0, 0), (0, 1, 0), (0, 0, 1)], [], 1),
    "dicosm": (True, [(1, 0, 0), (0, 1, 0)], [(_turn(2), (0, 0, 0.5))], 2),
    "tricosm": (True, _HEX, [(_turn(3), (0, 0, 1 / 3))], 3),
    "tetracosm": (True, [(1, 0, 0), (0, 1, 0)], [(_turn(4), (0, 0, 0.25))], 4),
    "hexacosm": (True, _HEX, [(_turn(6), (0, 0, 1 / 6))], 6),
    "didicosm": (
        True,
        [],
        [(_HALF_X, (0.5, 0.5, 0)), (np.diag([-1.0, 1, -1]), (0, 0.5, 0.5)), (_HALF_Z, (0.5, 0, 0.5))],
        4,
    ),
    # the amphicosms: a glide reflection in z = 0 along x, over Z^3 and over the lattice with (0, 1/2, 1/2)
    "amphicosm1": (False, [(0, 1, 0), (0, 0, 1)], [(_MIRROR_Z, (0.5, 0, 0))], 2),
    "amphicosm2": (False, [(0, 1, 0), (0, 0.5, 0.5)], [(_MIRROR_Z, (0.5, 0, 0))], 2),
    # the amphidicosms: a half-turn screw about x and a glide reflection, in z = 0 or in z = 1/4
    "amphidicosm1": (False, [(1, 0, 0), (0, 1, 0), (0, 0, 1)], [(_HALF_X, (0.5, 0, 0)), (_MIRROR_Z, (0, 0.5, 0))], 4),
    "amphidicosm2": (False, [(1, 0, 0), (0, 1, 0), (0, 0, 1)], [(_HALF_X, (0.5, 0, 0)), (_MIRROR_Z, (0, 0.5, 0.5))], 4),
}


def flat(member, which: str) -> dict:
    """One of the ten closed flat 3-manifolds: lattice translations and screws or glide
    reflections (didicosm: the Hantzsche-Wendt manifold, three half-turn screws)."""
    if which not in FLAT:
        raise SpaceError(f"{member}: the closed flat manifolds are {', '.join(FLAT)}, got {which!r}")
    orientable, lattice, others, holonomy = FLAT[which]
    generators = [(f"t{i}", _affine(_I, t)) for i, t in enumerate(lattice)]
    generators += [(f"s{i}", _affine(R, t)) for i, (R, t) in enumerate(others)]
    # the translations of the group: the lattice given, and each other generator's first power
    # that is a translation (its linear part's order divides the holonomy's)
    full = [np.asarray(t, float) for t in lattice]
    for R, t in others:
        A = np.eye(4)
        while True:
            A = np.array(_affine(R, t)) @ A
            if np.allclose(A[:3, :3], _I):
                full.append(A[:3, 3])
                break
    basis = _lattice_basis(full)
    kind = "orientable" if orientable else "non-orientable"
    return _space(
        member,
        which,
        "E3",
        f"Closed flat manifold ({kind}, holonomy of order {holonomy}): the {which}",
        abs(np.linalg.det(basis)) / holonomy,
        generators,
        FLAT_CAMERA,
        max_distance=30.0,
        max_crossings=80,
    )


def _lattice_basis(vectors) -> np.ndarray:
    """A basis of the lattice the vectors span (three of them spanning the least volume among the
    small combinations: the lattices here have small half-integer or hexagonal bases)."""
    cands = [np.asarray(v, float) for v in vectors]
    cands += [a - b for a in cands for b in cands if not np.allclose(a, b)]
    best = None
    for i in range(len(cands)):
        for j in range(i + 1, len(cands)):
            for k in range(j + 1, len(cands)):
                d = abs(np.linalg.det(np.array([cands[i], cands[j], cands[k]])))
                if d > 1e-9 and (best is None or d < best[0] - 1e-12):
                    best = (d, np.array([cands[i], cands[j], cands[k]]))
    return best[1]


# --- Nil: the Heisenberg quotients -----------------------------------------------------------------
def nil(member, n: int) -> dict:
    """The Heisenberg manifold of Euler number n: x, y the left multiplications of the preset
    `nil` and the centre's translation by 1/n ([x, y] = z^n), domain [-1/2, 1/2]^2 x [-1/2n, 1/2n]."""
    if n < 1:
        raise SpaceError(f"{member}: the Euler number of a Nil manifold is a positive integer, got {n}")
    return {
        "id": member,
        "name": f"Heisenberg manifold, Euler number {n}",
        "geometry": "Nil",
        "description": f"Nil: the circle bundle over the torus of Euler number {n}, volume 1/{n}",
        "covolume": 1 / n,
        "max_distance": 12.0,
        "max_crossings": 64 + 8 * n,
        "camera": {"position": [0.0, -0.3, 0.0], "forward": [0, 1, 0], "up": [0, 0, 1], "fov": 90},
        "generator": [
            {"name": "x", "matrix": [[1, 0, 0, 1], [0, 1, 0, 0], [0, 1, 1, 0], [0, 0, 0, 1]], "face": [1, 0, 0, -0.5]},
            {"name": "y", "matrix": [[1, 0, 0, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]], "face": [0, 1, 0, -0.5]},
            {
                "name": "z",
                "matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1 / n], [0, 0, 0, 1]],
                "face": [0, 0, 1, -0.5 / n],
            },
        ],
    }


# --- Sol: torus bundles with hyperbolic monodromy --------------------------------------------------
def sol(member, a: int, b: int, c: int, d: int) -> dict:
    """The torus bundle of monodromy A = [[a, b], [c, d]] in SL(2, Z), |tr A| > 2: Z^2 in the
    coordinates of A's unit eigenvectors (x along the contracting one, y the expanding one, where
    A acts as diag(1/λ, λ), with a half turn where tr A < -2), the lattice translations and the
    monodromy (x, y, z) -> ±(x/λ, λ y) , z + log λ; domain {s u1 + t u2: |s|, |t| <= 1/2} x [-log λ / 2, log λ / 2]."""
    A = np.array([[a, b], [c, d]], float)
    if a * d - b * c != 1 or abs(a + d) <= 2:
        raise SpaceError(
            f"{member}: a Sol torus bundle needs a monodromy in SL(2, Z) (det 1) with |trace| > 2, "
            f"got det {a * d - b * c} and trace {a + d}"
        )
    sign = 1.0 if a + d > 0 else -1.0
    values, vectors = np.linalg.eig(sign * A)
    order = np.argsort(values)  # 1/λ, then λ
    lam = float(values[order[1]])
    P = vectors[:, order] / np.linalg.norm(vectors[:, order], axis=0)
    U = np.linalg.inv(P)  # the lattice Z^2 in the eigen-coordinates: columns u1, u2
    W = np.linalg.inv(U)  # rows: the dual basis (the faces' normals)
    height = math.log(lam)
    generators = []
    for i in range(2):
        M = np.eye(4)
        M[:2, 3] = U[:, i]
        generators.append({"name": f"u{i + 1}", "matrix": M.tolist(), "face": [W[i, 0], W[i, 1], 0.0, -0.5]})
    M = np.diag([sign / lam, sign * lam, 1.0, 1.0])
    M[2, 3] = height
    generators.append({"name": "monodromy", "matrix": M.tolist(), "face": [0.0, 0.0, 1.0, -height / 2]})
    volume = abs(np.linalg.det(U)) * height
    return {
        "id": member,
        "name": f"Sol torus bundle, monodromy [[{a}, {b}], [{c}, {d}]]",
        "geometry": "Sol",
        "description": f"Sol: the torus bundle of monodromy [[{a}, {b}], [{c}, {d}]] (λ = {lam:.6g}), volume {volume:.6g}",
        "covolume": volume,
        "max_distance": 10.0,
        "max_crossings": 64,
        "camera": {"position": [0.0, 0.0, 0.0], "forward": [*U[:, 0], 0.0], "up": [0, 0, 1], "fov": 90},
        "generator": generators,
    }


# --- H2xR and SL2~: the genus-g surface times a circle, and its unit tangent bundle ----------------
def _polygon(member: str, g: int) -> tuple[float, list[float]]:
    """The regular 4g-gon of angles 2π/4g (a genus-g surface, its sides paired opposite): the
    inradius r (cosh r = cot(π/4g)) and the directions of the sides paired by translations by 2r."""
    if g < 2:
        raise SpaceError(f"{member}: a hyperbolic surface has genus g >= 2, not {g}")
    n = 4 * g
    return math.acosh(1 / math.tan(math.pi / n)), [2 * math.pi * k / n for k in range(2 * g)]


def surface_x_circle(member, g: int) -> dict:
    """(genus-g surface) x S^1 (H2xR): the 4g-gon's side translations (an SO+(2,1) block on the
    model slots (0, 1, 3)), times the circle z -> z + 2r (slot 2 scaled by e^2r)."""
    r, angles = _polygon(member, g)
    generators = []
    for k, t in enumerate(angles):
        n = np.array([math.cos(t), math.sin(t)])
        M = np.eye(4)
        M[np.ix_([0, 1], [0, 1])] += (math.cosh(2 * r) - 1) * np.outer(n, n)
        M[[0, 1], 3] = M[3, [0, 1]] = math.sinh(2 * r) * n
        M[3, 3] = math.cosh(2 * r)
        generators.append({"name": f"A{k}", "matrix": M.tolist(), "face": [n[0], n[1], 0.0, -math.tanh(r)]})
    generators.append(
        {"name": "circle", "matrix": np.diag([1, 1, math.exp(2 * r), 1]).tolist(), "face": [0.0, 0.0, 1.0, -r]}
    )
    volume = 4 * math.pi * (g - 1) * 2 * r
    return _bundle(
        member, g, "H2xR", f"(genus-{g} surface) x S¹", f"the circle of length 2 r_in = {2 * r:.6g}", volume, generators
    )


def unit_tangent(member, g: int) -> dict:
    """T¹Σ_g (SL2~): the 4g-gon's side translations lifted to SU(1,1) (left multiplication by
    [[cosh r, sinh r e^(iθ)], ...] on a point's first row (Re α, Im α, Re β, Im β)), and the fibre
    translation by 2π (-1); the lifted relator is the fibre translation by 4π(g - 1)."""
    r, angles = _polygon(member, g)
    generators = []
    for k, t in enumerate(angles):
        a, b1, b2 = math.cosh(r), math.sinh(r) * math.cos(t), math.sinh(r) * math.sin(t)
        M = [[a, 0, b1, b2], [0, a, b2, -b1], [b1, b2, a, 0], [b2, -b1, 0, a]]
        generators.append({"name": f"A{k}", "matrix": M, "face": [math.cos(t), math.sin(t), 0.0, -math.tanh(r)]})
    generators.append({"name": "fibre", "matrix": (-np.eye(4)).tolist(), "face": [0.0, 0.0, 1.0, -math.pi]})
    volume = 4 * math.pi * (g - 1) * 2 * math.pi
    return _bundle(
        member, g, "SL2", f"unit tangent bundle of the genus-{g} surface", "the fibre of length 2π", volume, generators
    )


def _bundle(member, g, geometry, name, fibre, volume, generators):
    return {
        "id": member,
        "name": name.capitalize(),
        "geometry": geometry,
        "description": f"{geometry}: the {name}: the regular {4 * g}-gon of angles 2π/{4 * g} times {fibre}",
        "covolume": volume,
        "max_distance": 12.0,
        "max_crossings": 64,
        "camera": {"position": [0.0, -0.3, 0.0], "forward": [0, 1, 0], "up": [0, 0, 1], "fov": 90},
        "generator": generators,
    }


FAMILIES = (
    Family("lens", "S3", "p, q (q prime to p, q ≠ ±1 mod p)", "lens space L(p, q) = S3 / Z/p", "lens(7,2)", lens),
    Family("prism", "S3", "n >= 2", "prism manifold S3 / D*4n (binary dihedral)", "prism(3)", prism),
    Family(
        "binary",
        "S3",
        "tetrahedral, octahedral, icosahedral",
        "S3 / a binary polyhedral group",
        "binary(octahedral)",
        binary,
    ),
    Family(
        "flat", "E3", ", ".join(FLAT), "the ten closed flat manifolds, four non-orientable", "flat(amphicosm1)", flat
    ),
    Family("nil", "Nil", "Euler number n >= 1", "Heisenberg manifold, circle bundle of Euler number n", "nil(3)", nil),
    Family("sol", "Sol", "a, b, c, d: [[a, b], [c, d]] in SL(2, Z), |a + d| > 2", "torus bundle", "sol(3,1,2,1)", sol),
    Family(
        "surface_x_circle", "H2xR", "genus g >= 2", "(genus-g surface) x S¹", "surface_x_circle(2)", surface_x_circle
    ),
    Family(
        "unit_tangent",
        "SL2",
        "genus g >= 2",
        "unit tangent bundle of the genus-g surface",
        "unit_tangent(3)",
        unit_tangent,
    ),
)
_NAME = re.compile(r"^([a-z_]+)\(([^()]*)\)$")


def family_of(name) -> tuple[Family, list] | None:
    """(the family, its parameters) of a member's name, None if the name is no family's."""
    m = _NAME.match(str(name).replace(" ", ""))
    family = next((f for f in FAMILIES if m and f.key == m.group(1)), None)
    if family is None:
        return None
    args = [int(a) if re.fullmatch(r"[-+]?\d+", a) else a for a in m.group(2).split(",") if a]
    return family, args


def family_file(name: str) -> Path | None:
    """The space file of a family member, written to the cache folder if it is not there yet (an
    existing one, maybe edited by its user, is kept); None if the name is no family's."""
    found = family_of(name)
    if found is None:
        return None
    family, args = found
    member = f"{family.key}({','.join(map(str, args))})"
    try:
        data = family.build(member, *args)
    except TypeError:
        raise SpaceError(f"{name}: {family.key}(...) takes {family.parameters}, e.g. {family.example}") from None
    path = cache_dir("family") / file_name(member)
    if path.is_file():
        return path
    return write_space(path, data, f"Written by Thurston's family {family.key!r}: {family.summary}. Edit freely.")
