"""Spaces (presets and user files) against independent truth: isometry and metric checks written
here, edge classes and dihedral angles computed here from the face covectors, group orders and
holonomy groups from closing the generators here, volumes from a quadrature written here and from
published invariants (Poincare 2 pi^2 / 120, Seifert-Weber 11.199064740...)."""

import math
import os
import subprocess
import sys
import time
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from support.presets import BUILT_IN, presets
from support.truth import AMBIENT, chart_metric

from thurston_addon import spaces

PRESETS = presets(lambda space: space.geometry.projective)  # Dirichlet domains
FLAT = presets(lambda space: space.geometry.name == "E3")
COORDINATE = presets(lambda space: space.geometry.name in ("Nil", "Sol"))  # their lattices written here
ORIGIN = np.array([0.0, 0.0, 0.0, 1.0])
SIGN = {"E3": 0, "S3": 1, "H3": -1}
PHI = (1 + math.sqrt(5)) / 2
REPO = Path(__file__).resolve().parents[2]


@cache
def load(pid):
    return spaces.load(pid)


@pytest.fixture(params=PRESETS)
def space(request):
    return load(request.param)


# --- independent helpers ---------------------------------------------------------------------------


def volume_density(name, x):
    """sqrt(det g) of the chart metric, for points (..., 3); checked against det below."""
    r2 = np.sum(x * x, axis=-1)
    return (1.0 + SIGN[name] * r2) ** -2


def to_model(name, x):
    Y = np.append(np.asarray(x, float), 1.0)
    if name == "E3":
        return Y
    return Y / math.sqrt(abs(Y @ AMBIENT[name] @ Y))


def to_chart(X):
    return X[:3] / X[3]


def act(M, x, name):
    return to_chart(M @ to_model(name, x))


def is_ambient_isometry(name, M, tol=1e-9):
    if name == "E3":
        R = M[:3, :3]
        return np.allclose(M[3], [0, 0, 0, 1], atol=tol) and np.allclose(R.T @ R, np.eye(3), atol=tol)
    J = AMBIENT[name]
    ok = np.allclose(M.T @ J @ M, J, atol=tol * max(1.0, np.abs(M).max() ** 2))
    return ok and (name == "S3" or M[3, 3] > 0)


def distance(name, A, B):
    if name == "E3":
        return float(np.linalg.norm(A[:3] / A[3] - B[:3] / B[3]))
    D = A - B
    if name == "S3":
        return float(2 * np.arcsin(min(1.0, np.linalg.norm(D) / 2)))
    return float(2 * np.arcsinh(math.sqrt(max(0.0, D[:3] @ D[:3] - D[3] ** 2)) / 2))


def covectors(space):
    return np.array([f.covector for f in space.domain.faces])


def faces_at(space, tol=1e-9):
    """For each vertex, the set of faces whose plane passes through it (computed from covectors)."""
    C = covectors(space)
    C = C / np.linalg.norm(C[:, :3], axis=1)[:, None]
    Y = np.hstack([space.domain.vertices, np.ones((len(space.domain.vertices), 1))])
    on = np.abs(Y @ C.T) < tol
    return [set(np.nonzero(row)[0]) for row in on]


def vertex_index(space, p, tol=1e-7):
    d = np.linalg.norm(space.domain.vertices - p, axis=1)
    k = int(np.argmin(d))
    assert d[k] < tol * (1 + np.linalg.norm(p)), f"{p} is not a vertex of the domain"
    return k


def edges_of(space):
    """Edges of the convex domain: vertex pairs sharing two face planes; -> (a, b, i, j)."""
    fa = faces_at(space)
    out = []
    n = len(fa)
    for a in range(n):
        for b in range(a + 1, n):
            common = sorted(fa[a] & fa[b])
            if len(common) >= 2:
                assert len(common) == 2
                out.append((a, b, common[0], common[1]))
    return out


def chart_dihedral(name, c1, c2, p):
    """Interior angle between the half-spaces c.(x,1) <= 0 at chart point p of both planes."""
    gi = np.linalg.inv(chart_metric(name, p))
    a1, a2 = c1[:3], c2[:3]
    cos = (a1 @ gi @ a2) / math.sqrt((a1 @ gi @ a1) * (a2 @ gi @ a2))
    return math.pi - math.acos(max(-1.0, min(1.0, cos)))


def edge_classes(space):
    """Union-find of the edges under all face pairings; -> list of classes (lists of edge tuples)."""
    name = space.geometry.name
    edges = edges_of(space)
    index = {(a, b): e for e, (a, b, _, _) in enumerate(edges)}
    parent = list(range(len(edges)))

    def find(e):
        while parent[e] != e:
            parent[e] = parent[parent[e]]
            e = parent[e]
        return e

    fa = faces_at(space)
    V = space.domain.vertices
    for i, face in enumerate(space.domain.faces):
        P = np.linalg.inv(face.element)
        image = {v: vertex_index(space, act(P, V[v], name)) for v in range(len(V)) if i in fa[v]}
        for e, (a, b, fi, fj) in enumerate(edges):
            if i in (fi, fj):
                e2 = index[tuple(sorted((image[a], image[b])))]
                parent[find(e)] = find(e2)
    classes = {}
    for e in range(len(edges)):
        classes.setdefault(find(e), []).append(edges[e])
    return list(classes.values())


def edge_angle(space, edge):
    a, b, i, j = edge
    V = space.domain.vertices
    C = covectors(space)
    return chart_dihedral(space.geometry.name, C[i], C[j], (V[a] + V[b]) / 2)


def random_points_in_domain(space, rng, n):
    V = space.domain.vertices
    lo, hi = V.min(axis=0), V.max(axis=0)
    C = covectors(space)
    pts = []
    while len(pts) < n:
        p = rng.uniform(lo, hi)
        if np.all(C @ np.append(p, 1.0) < 0):
            pts.append(p)
    return np.array(pts)


def jacobian(f, x, h=1e-6):
    return np.stack([(f(x + e) - f(x - e)) / (2 * h) for e in h * np.eye(3)], axis=-1)


def close_group(gens, key_digits=6, limit=5000, keep=lambda M: True):
    """Products of the generators by breadth-first closure (all of a finite group, or those that
    `keep` accepts)."""
    key = lambda M: tuple(np.round(M, key_digits).ravel() + 0.0)
    found = {key(np.eye(len(gens[0]))): np.eye(len(gens[0]))}
    frontier = list(found.values())
    while frontier:
        nxt = []
        for M in frontier:
            for s in gens:
                N = s @ M
                k = key(N)
                if k not in found and keep(N):
                    found[k] = N
                    nxt.append(N)
        assert len(found) < limit
        frontier = nxt
    return list(found.values())


def order(M, maxn=200):
    P = M.copy()
    for n in range(1, maxn):
        if np.allclose(P, np.eye(len(M)), atol=1e-8):
            return n
        P = P @ M
    raise AssertionError("infinite order")


def tetra_volume_integral(space, n=16):
    """Integral of the volume density over the domain: the domain is cut into tetrahedra (origin,
    face centre, two consecutive face vertices), each integrated with an n^3 collapsed
    Gauss-Legendre rule (x = u a + u v b + u v w c, Jacobian u^2 v |det(a, b, c)|)."""
    name = space.geometry.name
    t, w = np.polynomial.legendre.leggauss(n)
    t, w = 0.5 * (t + 1), 0.5 * w
    U, Vv, W = np.meshgrid(t, t, t, indexing="ij")
    WW = w[:, None, None] * w[None, :, None] * w[None, None, :]
    V = space.domain.vertices
    fa = faces_at(space)
    total = 0.0
    for i, face in enumerate(space.domain.faces):
        ring = [v for v in range(len(V)) if i in fa[v]]
        P = V[ring]
        centre = P.mean(axis=0)
        nrm = face.covector[:3]
        e1 = P[0] - centre
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(nrm / np.linalg.norm(nrm), e1)
        order_ = np.argsort(np.arctan2((P - centre) @ e2, (P - centre) @ e1))
        P = P[order_]
        for p, q in zip(P, np.roll(P, -1, axis=0)):
            a, b, c = centre, p - centre, q - p
            det = abs(np.linalg.det(np.array([a, b, c])))
            X = U[..., None] * a + (U * Vv)[..., None] * b + (U * Vv * W)[..., None] * c
            total += det * np.sum(WW * U * U * Vv * volume_density(name, X))
    return total


def s3_translation(n, d):
    n = np.asarray(n, float) / np.linalg.norm(n)
    N, E = np.append(n, 0.0), np.array([0, 0, 0, 1.0])
    return (
        np.eye(4)
        + (math.cos(d) - 1) * (np.outer(N, N) + np.outer(E, E))
        + math.sin(d) * (np.outer(N, E) - np.outer(E, N))
    )


def rotation4(n, angle):
    n = np.asarray(n, float) / np.linalg.norm(n)
    K = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
    M = np.eye(4)
    M[:3, :3] = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
    return M


def dodecahedron_normals():
    out = []
    for s1 in (1, -1):
        for s2 in (1, -1):
            v = np.array([0.0, s1, s2 * PHI])
            out += [np.roll(v, k) / np.linalg.norm(v) for k in range(3)]
    return out


def poincare_toml(twist):
    """A space file for the dodecahedron with inradius pi/10 whose opposite faces are glued by
    the translation to the opposite face composed with a `twist` about the face normal."""
    lines = ['geometry = "S3"', 'name = "dodecahedron test"']
    seen = []
    for n in dodecahedron_normals():
        if any(np.allclose(n, -m) for m in seen):
            continue
        seen.append(n)
        M = s3_translation(n, math.pi / 5) @ rotation4(n, twist)
        rows = ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in M)
        lines += ["[[generator]]", f"matrix = [{rows}]"]
    return "\n".join(lines) + "\n"


# --- every preset -----------------------------------------------------------------------------------


def test_preset_ids():
    assert sorted(spaces.preset_ids()) == sorted(BUILT_IN)
    assert {sid: load(sid).geometry.name for sid in BUILT_IN} == BUILT_IN


def test_density_helper_is_sqrt_det():
    rng = np.random.default_rng(0)
    for name in ("S3", "H3"):
        for x in rng.uniform(-0.5, 0.5, (4, 3)):
            assert volume_density(name, x) == pytest.approx(math.sqrt(np.linalg.det(chart_metric(name, x))), rel=1e-13)


def test_face_pairings_are_isometries(space):
    name = space.geometry.name
    for face in space.domain.faces:
        assert is_ambient_isometry(name, face.pairing)
        assert is_ambient_isometry(name, face.element)
        np.testing.assert_allclose(face.pairing @ face.element, np.eye(4), atol=1e-10)


def test_face_pairings_preserve_the_metric(space):
    name = space.geometry.name
    rng = np.random.default_rng(11)
    pts = random_points_in_domain(space, rng, 3)
    for face in space.domain.faces:
        P = face.pairing
        for x in pts:
            D = jacobian(lambda p: act(P, p, name), x)
            y = act(P, x, name)
            np.testing.assert_allclose(D.T @ chart_metric(name, y) @ D, chart_metric(name, x), rtol=1e-6, atol=1e-7)


def test_face_pairings_map_faces_onto_partner_faces(space):
    name = space.geometry.name
    fa = faces_at(space)
    V = space.domain.vertices
    for i, face in enumerate(space.domain.faces):
        j = face.partner
        assert j != i
        assert space.domain.faces[j].partner == i
        mine = [v for v in range(len(V)) if i in fa[v]]
        theirs = {v for v in range(len(V)) if j in fa[v]}
        assert set(face.vertices) == set(mine)
        images = [vertex_index(space, act(face.pairing, V[v], name)) for v in mine]
        assert len(set(images)) == len(mine)
        assert set(images) == theirs
        assert all(face.vertex_map[v] == w for v, w in zip(mine, images))


def test_partner_covector_pulls_back_to_flipped_face_covector(space):
    faces = space.domain.faces
    for face in faces:
        cj = faces[face.partner].covector
        pulled = cj @ face.pairing
        ci = face.covector
        lam = -(pulled @ ci) / (ci @ ci)
        assert lam > 0
        np.testing.assert_allclose(pulled, -lam * ci, atol=1e-9 * np.linalg.norm(pulled))


def test_face_is_bisector_of_origin_and_its_element(space):
    name = space.geometry.name
    rng = np.random.default_rng(5)
    V = space.domain.vertices
    fa = faces_at(space)
    for i, face in enumerate(space.domain.faces):
        Q = face.element @ ORIGIN
        ring = V[[v for v in range(len(V)) if i in fa[v]]]
        for _ in range(3):
            wts = rng.dirichlet(np.ones(len(ring)))
            X = to_model(name, wts @ ring)
            assert distance(name, ORIGIN, X) == pytest.approx(distance(name, Q, X), abs=1e-9)


def test_edge_cycles_sum_to_two_pi(space):
    classes = edge_classes(space)
    for cls in classes:
        total = sum(edge_angle(space, e) for e in cls)
        assert total == pytest.approx(2 * math.pi, abs=1e-9)
    # the kernel's cycles are the same partition
    assert sorted(len(c) for c in space.edge_cycles) == sorted(len(c) for c in classes)
    theirs = sorted(sorted(tuple(space.domain.edges[e][:2]) for e, _ in c) for c in space.edge_cycles)
    mine = sorted(sorted((a, b) for a, b, _, _ in c) for c in classes)
    assert theirs == mine


def test_dihedral_angles_agree_with_kernel(space):
    mine = {(a, b): edge_angle(space, (a, b, i, j)) for a, b, i, j in edges_of(space)}
    for e, (a, b, _, _) in enumerate(space.domain.edges):
        assert space.dihedral_angle(e) == pytest.approx(mine[(a, b)], abs=1e-10)
    assert len(space.domain.edges) == len(mine)


def test_euler_characteristic_of_the_domain(space):
    assert len(space.domain.vertices) - len(edges_of(space)) + len(space.domain.faces) == 2


def test_origin_is_inside_and_is_the_centroid(space):
    C = covectors(space)
    assert np.all(C @ ORIGIN < -1e-6)
    np.testing.assert_allclose(space.domain.vertices.mean(axis=0), 0.0, atol=1e-9)


def test_domain_volume_by_quadrature(space):
    expected = {
        "torus": 1.0,
        "half_turn": 1.0,
        "quarter_turn": 1.0,
        "third_turn": math.sqrt(3) / 2,
        "sixth_turn": math.sqrt(3) / 2,
        "hantzsche_wendt": 2.0,
        "poincare": 2 * math.pi**2 / 120,
        "seifert_weber": 11.199064740,
    }[space.id]
    n = 48 if space.id == "seifert_weber" else 12
    assert tetra_volume_integral(space, n) == pytest.approx(expected, abs=1e-6)
    assert space.volume == pytest.approx(expected, abs=1e-6)


# --- spherical and hyperbolic invariants ------------------------------------------------------------


def test_poincare_group_closure_has_order_120_and_binary_icosahedral_structure():
    s = load("poincare")
    group = close_group(s.generators)
    assert len(group) == 120
    assert s.group_order == 120
    orders = {}
    for M in group:
        o = order(M)
        orders[o] = orders.get(o, 0) + 1
    # the binary icosahedral group 2I: one central involution (-I), element orders 1,2,3,4,5,6,10
    assert orders == {1: 1, 2: 1, 3: 20, 4: 30, 5: 24, 6: 20, 10: 24}
    assert any(np.allclose(M, -np.eye(4)) for M in group)


def test_poincare_elements_within_pi():
    s = load("poincare")
    els = s.elements_within(math.pi + 1e-6)
    assert len(els) == 120
    mine = {tuple(np.round(M, 6).ravel() + 0.0) for M in close_group(s.generators)}
    assert {tuple(np.round(M, 6).ravel() + 0.0) for M in els} == mine
    np.testing.assert_allclose(els[0], np.eye(4), atol=1e-12)


def test_poincare_invariants():
    s = load("poincare")
    assert len(s.domain.faces) == 12 and len(s.domain.vertices) == 20
    face_distances = [math.asin(abs(c @ ORIGIN) / np.linalg.norm(c)) for c in covectors(s)]
    np.testing.assert_allclose(face_distances, math.pi / 10, atol=1e-12)
    assert s.inradius == pytest.approx(math.pi / 10, abs=1e-12)
    assert s.volume == pytest.approx(2 * math.pi**2 / 120, abs=1e-10)
    classes = edge_classes(s)
    assert len(classes) == 10 and all(len(c) == 3 for c in classes)
    assert all(len(c) == 3 for c in s.edge_cycles)
    for a, b, i, j in edges_of(s):
        assert edge_angle(s, (a, b, i, j)) == pytest.approx(2 * math.pi / 3, abs=1e-10)


def test_seifert_weber_invariants():
    s = load("seifert_weber")
    assert len(s.domain.faces) == 12 and len(s.domain.vertices) == 20
    classes = edge_classes(s)
    assert len(classes) == 6 and all(len(c) == 5 for c in classes)
    assert all(len(c) == 5 for c in s.edge_cycles)
    for a, b, i, j in edges_of(s):
        assert edge_angle(s, (a, b, i, j)) == pytest.approx(2 * math.pi / 5, abs=1e-10)
    assert s.volume == pytest.approx(11.199064740, abs=1e-6)
    assert s.group_order is None
    # all faces at the same distance: a regular dodecahedron
    J = AMBIENT["H3"]
    d = [math.asinh(abs(c @ ORIGIN) / math.sqrt(c @ J @ c)) for c in covectors(s)]
    np.testing.assert_allclose(d, s.inradius, atol=1e-12)


def test_poincare_from_an_independent_construction():
    """The dodecahedron with 1/10-turn gluings built here (not from the preset file) loads as a
    space with the same invariants; the opposite twist gives the mirror image, also a manifold."""
    for twist in (math.pi / 5, -math.pi / 5):
        s = spaces.from_data(__import__("tomllib").loads(poincare_toml(twist)), "dodecahedron.toml")
        assert len(s.domain.faces) == 12
        assert s.group_order == 120
        assert s.volume == pytest.approx(2 * math.pi**2 / 120, abs=1e-9)


# --- flat presets -----------------------------------------------------------------------------------

HOLONOMY = {"torus": 1, "half_turn": 2, "quarter_turn": 4, "third_turn": 3, "sixth_turn": 6, "hantzsche_wendt": 4}


@pytest.mark.parametrize("pid", FLAT)
def test_holonomy_group_structure(pid):
    s = load(pid)
    hol = close_group([g[:3, :3] for g in s.generators])
    orders = sorted(order(R) for R in hol)
    expected = {
        "torus": [1],
        "half_turn": [1, 2],
        "quarter_turn": [1, 2, 4, 4],  # Z4
        "third_turn": [1, 3, 3],
        "sixth_turn": [1, 2, 3, 3, 6, 6],  # Z6
        "hantzsche_wendt": [1, 2, 2, 2],  # Z2 x Z2
    }[pid]
    assert orders == expected
    # abelian, and the same set as the kernel's holonomy
    for A in hol:
        for B in hol:
            np.testing.assert_allclose(A @ B, B @ A, atol=1e-12)
    key = lambda R: tuple(np.round(R, 6).ravel() + 0.0)
    assert {key(R) for R in s.holonomy} == {key(R) for R in hol}
    assert all(abs(np.linalg.det(R) - 1) < 1e-12 for R in hol)  # orientable


def lattice_of(space, reach=6.0):
    """Translations of the group (elements with trivial linear part), from words of generators."""
    gens = [*space.generators, *(np.linalg.inv(g) for g in space.generators)]
    near = close_group(gens, limit=100000, keep=lambda N: np.linalg.norm(N[:3, 3]) <= reach)
    return [M[:3, 3] for M in near if np.allclose(M[:3, :3], np.eye(3), atol=1e-9)]


@pytest.mark.parametrize("pid", FLAT)
def test_flat_domain_volume_is_covolume(pid):
    s = load(pid)
    T = [t for t in lattice_of(s) if np.linalg.norm(t) > 1e-9]
    T.sort(key=np.linalg.norm)
    basis = []
    for t in T:
        if np.linalg.matrix_rank(np.array(basis + [t]), tol=1e-9) > len(basis):
            basis.append(t)
        if len(basis) == 3:
            break
    B = np.array(basis).T
    for t in T:  # the successive minima generate every translation found
        coeffs = np.linalg.solve(B, t)
        np.testing.assert_allclose(coeffs, np.round(coeffs), atol=1e-9)
    covolume = abs(np.linalg.det(B)) / HOLONOMY[pid]
    expected = {
        "torus": 1.0,
        "half_turn": 1.0,
        "quarter_turn": 1.0,
        "third_turn": math.sqrt(3) / 2,
        "sixth_turn": math.sqrt(3) / 2,
        "hantzsche_wendt": 2.0,
    }[pid]
    assert covolume == pytest.approx(expected, rel=1e-12)
    assert s.volume == pytest.approx(covolume, rel=1e-9)
    assert tetra_volume_integral(s, 4) == pytest.approx(covolume, rel=1e-9)


def test_torus_domain_is_the_unit_cube():
    s = load("torus")
    corners = {tuple(c) for c in np.array(np.meshgrid(*[[-0.5, 0.5]] * 3)).reshape(3, -1).T}
    assert {tuple(np.round(v, 12) + 0.0) for v in s.domain.vertices} == corners
    assert len(s.domain.faces) == 6


@pytest.mark.parametrize("pid", ["third_turn", "sixth_turn"])
def test_hexagonal_prism_domains(pid):
    s = load(pid)
    assert len(s.domain.faces) == 8 and len(s.domain.vertices) == 12
    sizes = sorted(len(f.vertices) for f in s.domain.faces)
    assert sizes == [4] * 6 + [6] * 2
    V = s.domain.vertices
    # two regular hexagons of circumradius 1/sqrt(3) (inradius 1/2) at z = +-1/2
    np.testing.assert_allclose(np.abs(V[:, 2]), 0.5, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(V[:, :2], axis=1), 1 / math.sqrt(3), atol=1e-12)


@pytest.mark.parametrize("pid", ["torus", "half_turn", "quarter_turn"])
def test_cube_domains(pid):
    s = load(pid)
    np.testing.assert_allclose(np.abs(s.domain.vertices), 0.5, atol=1e-12)
    assert len(s.domain.faces) == 6


# --- group elements ---------------------------------------------------------------------------------


@pytest.mark.parametrize("r", [0.5, 1.0, 1.5, 2.3])
def test_torus_elements_within_are_lattice_translations(r):
    s = load("torus")
    k = int(math.ceil(r))
    grid = np.array(np.meshgrid(*[range(-k, k + 1)] * 3)).reshape(3, -1).T
    expected = {tuple(v) for v in grid if np.linalg.norm(v) <= r + 1e-12}
    els = s.elements_within(r)
    got = set()
    for M in els:
        np.testing.assert_allclose(M[:3, :3], np.eye(3), atol=1e-12)
        got.add(tuple(int(round(c)) for c in M[:3, 3]))
        np.testing.assert_allclose(M[:3, 3], np.round(M[:3, 3]), atol=1e-12)
    assert len(els) == len(got) == len(expected)
    assert got == expected
    np.testing.assert_allclose(els[0], np.eye(4))


def test_torus_neighbourhood():
    s = load("torus")
    nb = s.neighbourhood(1)
    np.testing.assert_allclose(nb[0], np.eye(4))
    got = {tuple(int(round(c)) for c in M[:3, 3]) for M in nb}
    assert len(nb) == 27
    assert got == {(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)}
    assert all(np.allclose(M[:3, :3], np.eye(3)) for M in nb)


# --- bring_inside -------------------------------------------------------------------------------------


def test_bring_inside_torus():
    s = load("torus")
    X0 = np.array([2.3, -1.7, 0.4, 1.0])
    V0 = np.array([0.3, 0.4, 1.2, 0.0])
    X, V, M = s.bring_inside(X0, V0)
    np.testing.assert_allclose(X, [0.3, 0.3, 0.4, 1.0], atol=1e-12)
    np.testing.assert_allclose(M @ X0, X, atol=1e-12)
    np.testing.assert_allclose(V[:3], V0[:3] / np.linalg.norm(V0[:3]), atol=1e-12)


def check_bring_inside(s, rng, word_length, trials=5, tol=1e-8):
    name = s.geometry.name
    C = covectors(s)
    for _ in range(trials):
        # a point a few domains away: a random word of face elements applied to a domain point
        x = random_points_in_domain(s, rng, 1)[0]
        W = np.eye(4)
        for _ in range(word_length):
            W = W @ s.domain.faces[rng.integers(len(s.domain.faces))].element
        X0 = W @ to_model(name, x)
        X, _, M = s.bring_inside(X0)
        assert np.all(C @ X <= 1e-9 * np.linalg.norm(X))
        assert is_ambient_isometry(name, M)
        # x was inside, so the representative is x itself
        np.testing.assert_allclose(to_chart(X), x, atol=tol)
        # and the accumulated matrix maps the original point onto it
        np.testing.assert_allclose(to_chart(M @ X0), x, atol=tol)


@pytest.mark.parametrize("pid", PRESETS)
def test_bring_inside_result_is_in_domain_and_an_image(pid):
    check_bring_inside(load(pid), np.random.default_rng(3), word_length=2)


def test_bring_inside_seifert_weber_far_point_matrix_is_accurate():
    check_bring_inside(load("seifert_weber"), np.random.default_rng(3), word_length=4)


@pytest.mark.parametrize("pid", ["torus", "hantzsche_wendt", "poincare"])
def test_bring_inside_far_points_flat_and_spherical(pid):
    check_bring_inside(load(pid), np.random.default_rng(4), word_length=6, tol=1e-9)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize(
    "X",
    [
        [1.5, 0.0, 0.0, 1.0],  # Klein point outside the ball
        [1.0, 0.0, 0.0, 1.0],  # on the sphere at infinity
        [0.6, 0.8, 0.0, 1.0],
        [np.nan, 0.0, 0.0, 1.0],
        [np.inf, 0.0, 0.0, 1.0],
    ],
)
def test_bring_inside_h3_rejects_points_outside_the_model(X):
    s = load("seifert_weber")
    t0 = time.perf_counter()
    with pytest.raises(spaces.SpaceError):
        s.bring_inside(np.array(X))
    assert time.perf_counter() - t0 < 5


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("pid", ["torus", "poincare"])
def test_bring_inside_rejects_non_finite_points(pid):
    s = load(pid)
    for X in ([np.nan, 0, 0, 1], [0, np.inf, 0, 1]):
        with pytest.raises(spaces.SpaceError):
            s.bring_inside(np.array(X, float))


# --- user space files -------------------------------------------------------------------------------

BOX_TORUS = """
name = "Long torus"
geometry = "E3"
[[generator]]
matrix = [[1, 0, 0, 2], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
[[generator]]
matrix = [[1, 0, 0, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]]
[[generator]]
matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, "sqrt(4)/2"], [0, 0, 0, 1]]
"""


def test_user_space_file(tmp_path):
    path = tmp_path / "long_torus.toml"
    path.write_text(BOX_TORUS)
    s = spaces.load(path)
    assert s.id == "long_torus" and s.name == "Long torus"
    corners = {(x, y, z) for x in (-1.0, 1.0) for y in (-0.5, 0.5) for z in (-0.5, 0.5)}
    assert {tuple(np.round(v, 12) + 0.0) for v in s.domain.vertices} == corners
    assert s.volume == pytest.approx(2.0, rel=1e-12)
    assert len(s.domain.faces) == 6
    s2 = spaces.load(str(path))
    np.testing.assert_allclose(np.sort(s2.domain.vertices, axis=0), np.sort(s.domain.vertices, axis=0))


def test_user_preset_folders_come_first(tmp_path, monkeypatch):
    """$THURSTON_SPACE_PATH folders add presets (listed with the built-in ones) and shadow a built-in
    id of the same name."""
    mine, more = tmp_path / "mine", tmp_path / "more"
    mine.mkdir()
    more.mkdir()
    (mine / "aaa_long_torus.toml").write_text(BOX_TORUS)
    (more / "torus.toml").write_text(BOX_TORUS)
    monkeypatch.setenv(spaces.SPACE_PATH_VARIABLE, f"{mine}{os.pathsep}{more}")
    ids = spaces.preset_ids()
    assert ids[0] == "aaa_long_torus" and "poincare" in ids and ids.count("torus") == 1
    assert spaces.load("aaa_long_torus").volume == pytest.approx(2.0, rel=1e-12)
    assert spaces.load("torus").volume == pytest.approx(2.0, rel=1e-12)  # the user's, not the unit cube
    monkeypatch.delenv(spaces.SPACE_PATH_VARIABLE)
    assert "aaa_long_torus" not in spaces.preset_ids()
    assert spaces.load("torus").volume == pytest.approx(1.0, rel=1e-12)


def write(tmp_path, text, name="bad.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def expect_error(path, *words):
    with pytest.raises(spaces.SpaceError) as info:
        spaces.load(path)
    msg = str(info.value)
    assert str(path) in msg
    for w in words:
        assert w.lower() in msg.lower(), msg
    return msg


def test_missing_file(tmp_path):
    expect_error(tmp_path / "nowhere.toml", "does not exist")


def test_invalid_toml(tmp_path):
    expect_error(write(tmp_path, 'geometry = "E3\n[[generator]\n'), "TOML")


def test_unknown_geometry(tmp_path):
    expect_error(write(tmp_path, BOX_TORUS.replace('"E3"', '"Q7"')), "Q7")


def test_missing_geometry_and_generators(tmp_path):
    expect_error(write(tmp_path, 'name = "x"\n', "nogeom.toml"), "geometry")
    expect_error(write(tmp_path, 'geometry = "E3"\n', "nogen.toml"), "generator")


def test_matrix_that_is_not_an_isometry(tmp_path):
    expect_error(write(tmp_path, BOX_TORUS.replace("[1, 0, 0, 2]", "[2, 0, 0, 2]")), "not an isometry")


def test_matrix_with_wrong_shape(tmp_path):
    expect_error(
        write(
            tmp_path,
            BOX_TORUS.replace(
                ", [0, 0, 0, 1]]\n[[generator]]\nmatrix = [[1, 0, 0, 0], [0, 1, 0, 1]",
                "]\n[[generator]]\nmatrix = [[1, 0, 0, 0], [0, 1, 0, 1]",
                1,
            ),
        ),
        "matrix",
    )


@pytest.mark.parametrize("entry", ['"sqrt("', '"1/0"', '"nan"', '"exp(1000)"', "true"])
def test_bad_matrix_entries(tmp_path, entry):
    expect_error(write(tmp_path, BOX_TORUS.replace('"sqrt(4)/2"', entry)), "generator")


def test_matrix_entries_are_not_executed(tmp_path):
    sentinel = tmp_path / "pwned"
    for i, code in enumerate(
        [f"open('{sentinel}', 'w')", f"__import__('pathlib').Path('{sentinel}').touch()", "__import__('os')"]
    ):
        text = BOX_TORUS.replace('"sqrt(4)/2"', '"' + code.replace('"', '\\"') + '"')
        expect_error(write(tmp_path, text, f"evil{i}.toml"), "cannot evaluate")
        assert not sentinel.exists()


def test_unknown_preset_id():
    with pytest.raises(spaces.SpaceError, match="no_such_space"):
        spaces.load("no_such_space")


def test_redundant_identity_generator_is_harmless(tmp_path):
    text = BOX_TORUS + "[[generator]]\nmatrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n"
    s = spaces.load(write(tmp_path, text, "redundant.toml"))
    assert len(s.domain.faces) == 6 and s.volume == pytest.approx(2.0)


def test_generator_fixing_the_centre_is_rejected(tmp_path):
    # a quarter turn about the z axis through the origin: the action is not free (an orbifold)
    text = BOX_TORUS + "[[generator]]\nmatrix = [[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n"
    expect_error(write(tmp_path, text), "fixes the domain centre")


def test_non_compact_domain_is_rejected(tmp_path):
    text = 'geometry = "E3"\n[[generator]]\nmatrix = [[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n'
    expect_error(write(tmp_path, text), "domain")


@pytest.mark.parametrize("twist,problem", [(3 * math.pi / 5, "2 pi"), (math.pi, "2 pi")])
def test_dodecahedron_with_wrong_twist_is_not_a_manifold(tmp_path, twist, problem):
    path = write(tmp_path, poincare_toml(twist), "twisted.toml")
    t0 = time.perf_counter()
    expect_error(path, problem)
    assert time.perf_counter() - t0 < 10


def test_dodecahedron_glued_by_pure_translations_fails_quickly(tmp_path):
    """Twist 0: the group is not discrete; loading must raise SpaceError, not hang (subprocess
    with a timeout, so that a hang fails the test instead of the suite)."""
    path = write(tmp_path, poincare_toml(0.0), "untwisted.toml")
    code = (
        "import sys\nfrom thurston_addon import spaces\n"
        "try:\n    spaces.load(sys.argv[1])\nexcept spaces.SpaceError as e:\n    print('SpaceError:', e)\n    sys.exit(3)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code, str(path)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"},
    )
    assert proc.returncode == 3, proc.stdout + proc.stderr
    assert str(path) in proc.stdout


@pytest.mark.parametrize(
    "entry",
    [
        '"(-1)**0.5"',
        '"' + "+".join(["1"] * 5000) + '"',
    ],
)
def test_pathological_matrix_entries_raise_space_error(tmp_path, entry):
    expect_error(write(tmp_path, BOX_TORUS.replace('"sqrt(4)/2"', entry)), "cannot evaluate")


QUATERNION_SPACE = """
name = "Quaternionic space S3/Q8"
geometry = "S3"
# left multiplications by the unit quaternions i and j, coordinates (x, y, z, w) of w + x i + y j + z k
[[generator]]
matrix = [[0, 0, 0, 1], [0, 0, -1, 0], [0, 1, 0, 0], [-1, 0, 0, 0]]
[[generator]]
matrix = [[0, 0, 1, 0], [0, 0, 0, 1], [-1, 0, 0, 0], [0, -1, 0, 0]]
"""


def test_quaternion_generators_are_orthogonal_and_generate_q8():
    gens = [
        np.array(m, float)
        for m in (
            [[0, 0, 0, 1], [0, 0, -1, 0], [0, 1, 0, 0], [-1, 0, 0, 0]],
            [[0, 0, 1, 0], [0, 0, 0, 1], [-1, 0, 0, 0], [0, -1, 0, 0]],
        )
    ]
    for g in gens:
        np.testing.assert_allclose(g.T @ g, np.eye(4))
    group = close_group(gens)
    assert sorted(order(M) for M in group) == [1, 2, 4, 4, 4, 4, 4, 4]


def test_quaternionic_space_loads(tmp_path):
    s = spaces.load(write(tmp_path, QUATERNION_SPACE, "quaternionic.toml"))
    assert s.group_order == 8
    corners = {(x, y, z) for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)}
    assert {tuple(np.round(v, 12) + 0.0) for v in s.domain.vertices} == corners
    assert s.volume == pytest.approx(2 * math.pi**2 / 8, abs=1e-9)
    assert tetra_volume_integral(s, 16) == pytest.approx(2 * math.pi**2 / 8, abs=1e-6)


# --- fields of the wrong type or out of range: SpaceError naming the file and the field -------------
BAD_FIELDS = [
    ("generator = [1, 2]\n", "generator"),
    ("camera = 5\n", "camera"),
    ('max_crossings = "many"\n', "max_crossings"),
    ("max_crossings = 2.7\n", "max_crossings"),
    ("max_crossings = -5\n", "max_crossings"),
    ("max_crossings = true\n", "max_crossings"),
    ("max_crossings = 3000000000\n", "max_crossings"),
    ("max_distance = -3\n", "max_distance"),
    ("max_distance = 0\n", "max_distance"),
    ('max_distance = "inf"\n', "max_distance"),
    ("geometry = 5\n", "geometry"),
    ("[camera]\nforward = [0, 1, 0]\nup = [0, 2, 0]\n", "parallel"),
    ("[camera]\nforward = [0, 0, 0]\n", "camera.forward"),
    ("[camera]\nup = [0, 0, 0]\n", "camera.up"),
    ('[camera]\nforward = [1, "nan", 0]\n', "camera.forward"),
    ("[camera]\nfov = 0\n", "camera.fov"),
    ("[camera]\nfov = 180\n", "camera.fov"),
    ("[camera]\nfov = -30\n", "camera.fov"),
    ('[camera]\nposition = [0, 0, "1/0"]\n', "camera.position"),
]


@pytest.mark.parametrize("field,word", BAD_FIELDS)
def test_bad_fields_raise_space_error(tmp_path, field, word):
    # top-level keys before the [[generator]] tables; a replaced generator list or geometry goes first
    # (TOML: a key defined twice is an error, so the box torus' own keys are dropped where replaced)
    body = BOX_TORUS
    if field.startswith("generator"):
        body = 'geometry = "E3"\n'
    elif field.startswith("geometry"):
        body = BOX_TORUS.replace('geometry = "E3"\n', "")
    text = field + body if not field.startswith("[camera]") else body + field
    expect_error(write(tmp_path, text), word)


def test_camera_outside_the_h3_chart_is_rejected(tmp_path):
    text = (spaces.PRESET_DIR / "seifert_weber.toml").read_text()
    assert "position = [0.05, -0.08, 0.03]" in text
    text = text.replace("position = [0.05, -0.08, 0.03]", "position = [1.5, 0, 0]")
    expect_error(write(tmp_path, text, "far.toml"), "camera.position", "chart")


def test_whole_float_max_crossings_is_accepted(tmp_path):
    s = spaces.load(write(tmp_path, "max_crossings = 12.0\nmax_distance = 7\n" + BOX_TORUS, "ok.toml"))
    assert s.max_crossings == 12 and isinstance(s.max_crossings, int) and s.max_distance == 7.0


def test_move_inside_many_points_at_once():
    """Torus: the representative of x in the unit cube centred at 0 is x - round(x), tangents unchanged;
    extended precision goes in and comes out."""
    s = load("torus")
    g = s.geometry
    rng = np.random.default_rng(9)
    x = rng.uniform(-7.3, 7.3, size=(500, 3))
    v = rng.normal(size=(500, 3))
    X, V, _ = s.move_inside(g.to_model(x).astype(np.longdouble), np.hstack([v, np.zeros((500, 1))]))
    assert X.dtype == np.longdouble
    np.testing.assert_allclose(np.asarray(g.to_chart(X), float), x - np.round(x), atol=1e-12)
    np.testing.assert_allclose(np.asarray(V[:, :3], float), v / np.linalg.norm(v, axis=1)[:, None], atol=1e-12)
    with pytest.raises(spaces.SpaceError, match="point 1 "):
        s.move_inside(np.array([[0, 0, 0, 1.0], [np.nan, 0, 0, 1.0]]))


# --- coordinate domains: Nil and Sol ---------------------------------------------------------------------
from support.truth import CURVED_METRICS  # noqa: E402

SQ = math.sqrt(1 + PHI**2)
U1, U2 = np.array([1, PHI]) / SQ, np.array([-PHI, 1]) / SQ  # the monodromy's eigenvectors, orthonormal


def heisenberg(a, b, c):
    """The left multiplication by (a, b, c): (x, y, z) -> (x + a, y + b, z + c + a y)."""
    return np.array([[1, 0, 0, a], [0, 1, 0, b], [0, a, 1, c], [0, 0, 0, 1.0]])


def sol_map(a, b, c):
    """(x, y, z) -> (e^-c x + a, e^c y + b, z + c)."""
    return np.array([[math.exp(-c), 0, 0, a], [0, math.exp(c), 0, b], [0, 0, 1, c], [0, 0, 0, 1.0]])


@pytest.fixture
def rng():
    return np.random.default_rng(20261201)


def pulls_back_the_metric(name, M, rng, n=20, tol=1e-9):
    """A^T g(M x) A == g(x) at random points, A the linear part (the maps here are affine)."""
    g = CURVED_METRICS[name]
    A = M[:3, :3]
    for x in rng.uniform(-2, 2, (n, 3)):
        y = A @ x + M[:3, 3]
        if not np.allclose(A.T @ g(y) @ A, g(x), atol=tol * (1 + np.abs(g(x)).max())):
            return False
    return True


@pytest.mark.parametrize("sid", COORDINATE)
def test_coordinate_presets_are_coordinate_spaces(sid):
    s = load(sid)
    assert isinstance(s, spaces.CoordinateSpace) and s.geometry.name == {"nil": "Nil", "sol": "Sol"}[sid]
    assert len(s.domain.faces) == 6 and len(s.domain.vertices) == 8 and len(s.domain.edges) == 12
    # each face's partner is the face its pairing's inverse belongs to, and face and partner share a class
    for i, face in enumerate(s.domain.faces):
        partner = s.domain.faces[face.partner]
        np.testing.assert_allclose(partner.element @ face.element, np.eye(4), atol=1e-12)
        assert s.face_classes[i] == s.face_classes[face.partner]


def test_nil_domain_is_the_unit_cube_and_its_pairings_are_left_multiplications(rng):
    s = load("nil")
    corners = {(x, y, z) for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)}
    assert {tuple(np.round(v, 12) + 0.0) for v in s.domain.vertices} == corners
    lattice = [heisenberg(1, 0, 0), heisenberg(0, 1, 0), heisenberg(0, 0, 1)]
    for face in s.domain.faces:
        assert pulls_back_the_metric("Nil", face.pairing, rng)
        assert any(
            np.allclose(face.element, L, atol=1e-12) or np.allclose(face.element, np.linalg.inv(L), atol=1e-12)
            for L in lattice
        )
    assert s.volume == pytest.approx(1.0, abs=1e-12)  # the covolume of the integer Heisenberg group


def test_sol_domain_is_the_parallelogram_prism(rng):
    s = load("sol")
    ell = math.log(PHI)
    corners = {
        tuple(np.round(np.append(a * U1 + b * U2, c), 10) + 0.0)
        for a in (-0.5, 0.5)
        for b in (-0.5, 0.5)
        for c in (-ell, ell)
    }
    assert {tuple(np.round(v, 10) + 0.0) for v in s.domain.vertices} == corners
    for face in s.domain.faces:
        assert pulls_back_the_metric("Sol", face.pairing, rng)
    assert s.volume == pytest.approx(2 * ell, abs=1e-12)  # 2 log phi = 0.9624


def test_sol_monodromy_maps_the_lattice_to_itself():
    """The third generator conjugates the translation by u1 to the translation by 2 u1 + u2, and u2
    to u1 + u2 (the matrix [[2, 1], [1, 1]]): the group is discrete."""
    s = load("sol")
    t1, t2, t3 = s.generators
    np.testing.assert_allclose(t3 @ t1 @ np.linalg.inv(t3), sol_map(*(2 * U1 + U2), 0), atol=1e-12)
    np.testing.assert_allclose(t3 @ t2 @ np.linalg.inv(t3), sol_map(*(U1 + U2), 0), atol=1e-12)


@pytest.mark.parametrize("sid", COORDINATE)
def test_points_and_their_images_reduce_to_one_point(sid, rng):
    """p and g(p) reduce to the same point of the domain, for random points and random words g in
    the lattice written here (not the space's own generators)."""
    s = load(sid)
    if sid == "nil":
        words = [heisenberg(*rng.integers(-3, 4, 3)) for _ in range(20)]
    else:
        ell = 2 * math.log(PHI)
        words = [sol_map(*(i * U1 + j * U2), k * ell) for i, j, k in rng.integers(-3, 4, (20, 3))]
    g = s.geometry
    p = g.to_model(random_points_in_domain(s, rng, 50))
    base, _, _ = s.move_inside(p)
    np.testing.assert_allclose(base, p, atol=1e-12)
    for W in words:
        X, _, M = s.move_inside(p @ W.T)
        np.testing.assert_allclose(X, p, atol=1e-9)
        np.testing.assert_allclose(M @ W, np.broadcast_to(np.eye(4), M.shape), atol=1e-8)


def test_paper_nil_generator_is_not_an_isometry(tmp_path):
    """Errata: the paper's (x, y, z) -> (x + 1, y, z) is not an isometry of its own metric."""
    text = (
        (spaces.PRESET_DIR / "nil.toml")
        .read_text()
        .replace(
            "matrix = [[1, 0, 0, 1], [0, 1, 0, 0], [0, 1, 1, 0], [0, 0, 0, 1]]",
            "matrix = [[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]",
        )
    )
    expect_error(write(tmp_path, text, "paper_nil.toml"), "generator 'x'", "not an isometry of Nil")


def test_paper_sol_square_is_not_a_fundamental_domain(tmp_path):
    """Errata: with the unit translations and the paper's third map the group is not discrete."""
    text = """
geometry = "Sol"
[[generator]]
matrix = [[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
face = [1, 0, 0, -0.5]
[[generator]]
matrix = [[1, 0, 0, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]]
face = [0, 1, 0, -0.5]
[[generator]]
matrix = [["phi**-2", 0, 0, 0], [0, "phi**2", 0, 0], [0, 0, 1, "2 * log(phi)"], [0, 0, 0, 1]]
face = [0, 0, 1, "-log(phi)"]
"""
    expect_error(write(tmp_path, text, "paper_sol.toml"), "not discrete")


def test_coordinate_space_file_errors(tmp_path):
    text = (spaces.PRESET_DIR / "nil.toml").read_text()
    expect_error(write(tmp_path, text.replace("covolume = 1", "covolume = 2"), "a.toml"), "volume", "covolume")
    no_face = text.replace("face = [0, 0, 1, -0.5]\n", "", 1)
    expect_error(write(tmp_path, no_face, "b.toml"), "generator 'z' has no 'face'")
    outside = text.replace("face = [0, 0, 1, -0.5]", "face = [0, 0, 1, 0.5]")
    expect_error(write(tmp_path, outside, "c.toml"), "origin", "inside")
    dirichlet = text.replace('geometry = "Nil"', 'geometry = "Nil"\n')
    dirichlet = "\n".join(line for line in dirichlet.splitlines() if not line.startswith("face"))
    expect_error(write(tmp_path, dirichlet, "d.toml"), "Nil has no Dirichlet domains")
