"""Dirichlet spaces: the domain is the Dirichlet domain of the chart origin, computed from the
generators (the intersection of the half-spaces closer to the origin O than to gO over the group
elements g, which are planes of the chart where geodesics are chart lines) and validated by
Poincaré's polyhedron theorem (pairings are isometries that map faces onto faces, edge cycles sum
to 2 pi)."""

from __future__ import annotations

import itertools
import math
from functools import cached_property

import numpy as np

from .. import geometries
from .domains import Domain, halfspace_domain
from .space import Space, is_identity
from .values import SpaceError, evaluate

_SHORTENING_ROUNDS = 64  # passes over the generator pairs that shorten a generating set (each pass
# shortens every generator as far as single products go; a discrete group's set settles in a few)
MAX_FINITE_ORDER = 10000  # the largest order a generator is looked for up to, where the group must be finite
COVOLUME_TOLERANCE = 1e-8  # relative: a file's covolume and the domain's volume agree this well
CENTRE_RESOLUTION = 1e-6  # elements moving the domain centre by less are not told apart from the identity


class DirichletSpace(Space):
    """The domain is the Dirichlet domain of the chart origin, computed from the generators (the
    projective geometries, where bisectors are planes of the chart)."""

    def _build_domain(self, data: dict):
        if not self.geometry.projective:
            raise SpaceError(
                f"{self.source}: {self.geometry.name} has no Dirichlet domains in its chart: "
                "give each [[generator]] the 'face' its copy of the domain lies beyond"
            )
        self._elements: list[np.ndarray] = [np.eye(4)]
        self._radius = 0.0
        self._dirichlet_domain()
        if "covolume" in data:  # (the volume by quadrature is good to about 1e-12 here)
            covolume = evaluate(data["covolume"], f"{self.source}: covolume")
            if abs(self.volume - covolume) > COVOLUME_TOLERANCE * max(1.0, covolume):
                raise SpaceError(
                    f"{self.source}: the domain's volume {self.volume:.12g} is not the covolume "
                    f"{covolume:.12g} the file states (to {COVOLUME_TOLERANCE:g})"
                )

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
        given = [(name, M) for name, M in zip(self.generator_names, self.generators) if not is_identity(M)]
        for name, M in given:
            self._check_moves_centre(M, f"generator {name!r}", generator=True)
        given = self._distinct(given)
        if math.isfinite(g.diameter):
            for name, M in given:
                self._check_finite_order(name, M)
        self._steps = [M for _, M in given]
        # the generators as given first, then shortened ones where shortening changes them (else
        # theirs is the polyhedron just tried); shortened only when needed: its products of large
        # hyperbolic matrices can leave words that are the identity only to about 1e-12
        for attempt in range(2):
            if attempt:
                shortened, moved = self._shortened(self._steps)
                if not moved:
                    break
            generators = shortened if attempt else self._steps
            distinct = {
                g.element_key(N): N
                for M in generators + [np.linalg.inv(M) for M in generators]
                for N in [g.reorthonormalize(M)]
            }
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
            try:  # (each element passed _check_moves_centre as the enumeration found it)
                self._bisector_domain(self.elements_within(radius)[1:])
            except SpaceError:
                # S3's groups are finite: a ball too small to close the domain grows up to pi
                if not math.isfinite(full) or radius >= full:
                    raise
                radius *= 1.5
                continue
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

    def _check_finite_order(self, name: str, M):
        """In a geometry of finite diameter a discrete group is finite: SpaceError where a
        generator's powers up to MAX_FINITE_ORDER do not return to the identity (a rotation by an
        angle that is no rational multiple of 2 pi generates a group that is not discrete)."""
        P = M
        for k in range(1, MAX_FINITE_ORDER + 1):
            if np.allclose(P, np.eye(4), rtol=0, atol=1e-8):
                return
            P = P @ M if k % 64 else self.geometry.reorthonormalize(P @ M)
        raise SpaceError(
            f"{self.source}: generator {name!r} has no finite order (its first {MAX_FINITE_ORDER} powers do not "
            f"return to the identity): a group of {self.geometry.name} must be finite to be discrete; use "
            "rotations by angles 2 pi k / n"
        )

    def _distinct(self, given: list[tuple[str, np.ndarray]]) -> list[tuple[str, np.ndarray]]:
        """The named generators without repeats: one equal to an earlier one or to its inverse adds
        nothing to the group, and is dropped before the shortening's work over every pair."""
        g = self.geometry
        seen, kept = set(), []
        for name, M in given:
            R = g.reorthonormalize(M)
            key = g.element_key(R)
            if key in seen or g.element_key(np.linalg.inv(R)) in seen:
                continue
            seen.add(key)
            kept.append((name, M))
        return kept

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
                    if is_identity(gens[i]) or is_identity(gens[j]):
                        break
                    shorter = self._shortened_by(gens[i], s, left)
                    if shorter is not gens[i]:
                        gens[i], changed = shorter, True
            moved |= changed
            if not changed:
                break
        kept = [M for M in gens if not is_identity(M)]
        return kept, moved or len(kept) < len(gens)

    def _shortened_by(self, M, s, left: bool):
        """M times powers of s (s^k M where left, else M s^k) while that moves O less, the power
        doubled while the product keeps shortening and back to s where it overshoots; M itself
        where no power shortens it, the identity where one cancels it."""
        g = self.geometry
        O = geometries.projective.ORIGIN
        length = lambda N: g.distance(O, N[:, 3])
        step = s
        while not is_identity(M):
            shorter = g.reorthonormalize(step @ M if left else M @ step)
            if not length(shorter) < length(M) * (1 - 1e-9):
                if step is s:
                    break
                step = s  # the doubled power overshot: go on from single steps
                continue
            if not is_identity(shorter):
                self._check_moves_centre(shorter, "a word in the generators")
            M, step = shorter, g.reorthonormalize(step @ step)
        return M

    def _bisector_domain(self, elements):
        """self.domain: the polyhedron of the bisectors of O and the elements' images of it."""
        g = self.geometry
        self.domain = halfspace_domain([g.bisector(M[:, 3]) for M in elements], elements, self.source, g)
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
            raise SpaceError(
                f"{self.source}: {what} fixes the domain centre (the chart origin) without being the "
                "identity: the group does not act freely, so the space is not a manifold"
            )
        if generator:
            raise SpaceError(
                f"{self.source}: {what} moves the domain centre by only {moved:.3g}, less than the "
                f"{CENTRE_RESOLUTION:g} the domain's computation resolves (a flat space can be written "
                "in larger chart units, with `scale` set to match)"
            )
        raise SpaceError(
            f"{self.source}: {what} moves the domain centre by only {moved:.3g}, less than the "
            f"{CENTRE_RESOLUTION:g} the domain's computation resolves: a word in the generators that "
            "should be the identity is not (their entries disagree at that level: give them exactly, "
            "e.g. 'sqrt(3)/2'), or the group is not discrete"
        )

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
                    raise SpaceError(
                        f"{where}: the pairing of face {i} does not map its vertex {v} onto a vertex of face {j}"
                    )
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
