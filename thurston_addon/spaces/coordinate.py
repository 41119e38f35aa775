"""Coordinate spaces: the domain is given by the file, each generator naming the face beyond which
its copy of the domain lies; validated by discreteness, unique reduction and the covolume."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from .domains import Domain, halfspace_domain
from .space import Space, is_identity
from .values import SpaceError, evaluate, vector

# the coordinate domain's volume: Gauss-Legendre points per axis of a piece's two integrals (not
# its integral against its halves': where a piece is halved along the fibre, those agree however
# coarse), their relative agreement that settles it, the most halvings of any piece
VOLUME_ORDERS = (6, 10)
VOLUME_TOLERANCE = 3e-6
VOLUME_ROUNDS = 60
WORD_SIZE = 1e3  # the largest entry of the random words the validation reduces (past it the next letter)


def _rounding(M) -> float:
    """How far a reduction by M may miss: float64 generators hold the group's relations only to
    about eps |M| |M^-1| (the conjugates of the genus-4 polygon's side translations in SO(2,1)
    reach 10^5, so 10^-4 there)."""
    return max(1e-8, 100 * np.finfo(float).eps * np.abs(M).max() * np.abs(np.linalg.inv(M)).max())


def _halved(tetrahedra, density) -> np.ndarray:
    """Each tetrahedron (rows of 4 vertices) cut in two across the midpoint of the edge along which
    the log of the density changes most (the longest where it changes along none): H2xR's and SL2~'s
    peaks run along the fibre, over the polygon's corners, so their pieces are cut across it."""
    pairs = [(i, j) for i in range(4) for j in range(i + 1, 4)]
    log_density = np.log(density(tetrahedra))
    scores = np.stack(
        [
            np.abs(log_density[:, i] - log_density[:, j])
            + 1e-3 * np.linalg.norm(tetrahedra[:, i] - tetrahedra[:, j], axis=1)
            for i, j in pairs
        ],
        axis=1,
    )
    i, j = np.array(pairs).T[:, np.argmax(scores, axis=1)]
    n = np.arange(len(tetrahedra))
    middle = 0.5 * (tetrahedra[n, i] + tetrahedra[n, j])
    first, second = tetrahedra.copy(), tetrahedra.copy()
    first[n, i] = middle
    second[n, j] = middle
    return np.stack([first, second], axis=1).reshape(-1, 4, 3)


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
                raise SpaceError(
                    f"{where}: generator {name!r} has no 'face', but others do: "
                    "give every generator of a coordinate domain its face"
                )
            c = vector(gen["face"], 4, f"{where}: generator {name!r} face")
            if not np.linalg.norm(c[:3]) > 0:
                raise SpaceError(f"{where}: generator {name!r} face {c.tolist()} is not a plane")
            if not c[3] < 0:
                raise SpaceError(
                    f"{where}: generator {name!r} face {c.tolist()} must have the chart origin "
                    "strictly inside (its last entry < 0)"
                )
            if is_identity(M):
                raise SpaceError(f"{where}: generator {name!r} is the identity: it pairs its face with no other")
            try:
                image = -self.geometry.pull_back_plane(c, M)
            except ValueError as exc:
                raise SpaceError(f"{where}: generator {name!r}: {exc}") from None
            covectors += [c, image]
            elements += [M, np.linalg.inv(M)]
        self.domain = self._face_domain(covectors, elements)
        if len(self.domain.faces) != len(covectors):
            raise SpaceError(
                f"{where}: {len(covectors) - len(self.domain.faces)} of the generators' faces "
                "do not bound the domain (each face and its image must be faces of it)"
            )
        keys = {self.geometry.element_key(f.element): i for i, f in enumerate(self.domain.faces)}
        for face in self.domain.faces:
            face.partner = keys[self.geometry.element_key(np.linalg.inv(face.element))]
        self._validate(data)

    def _face_domain(self, covectors, elements) -> Domain:
        """The polyhedron of the faces (each generator's, then its image), around the chart origin."""
        for k, image in enumerate(covectors[1::2]):
            if not image[3] < 0:
                raise SpaceError(
                    f"{self.source}: generator {self.generator_names[k]!r} carries its face "
                    f"{np.round(covectors[2 * k], 12).tolist()} to {np.round(image, 12).tolist()}, which does "
                    "not have the chart origin inside: the face must lie between the domain and the "
                    "generator's copy of it"
                )
        return halfspace_domain(covectors, elements, self.source, self.geometry)

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
            groups[c] += [
                piece
                for i in range(k)
                for piece in self.geometry.face_shape.chart_segments(corners[i], corners[(i + 1) % k])
            ]
        return groups

    @cached_property
    def volume(self) -> float:
        """Riemannian volume of the domain: the volume density integrated over the cones from the
        origin over the face triangles in the plane chart, adaptively: each tetrahedron is halved
        across its longest edge until its collapsed Gauss-Legendre integrals of two orders agree
        to VOLUME_TOLERANCE (the density peaks sharply at corners near the rim of H2xR's and SL2~'s
        disk: the genus-4 polygon's reach Klein radius 0.998, where it is 10^4 times the centre's).
        The Dirichlet domains' radial closed form needs a projective chart."""
        V = self.plane_vertices
        tetrahedra = []
        for face in self.domain.faces:
            ring = V[face.vertices]
            centre = ring.mean(axis=0)
            tetrahedra += [(np.zeros(3), centre, p, q) for p, q in zip(ring, np.roll(ring, -1, axis=0))]
        pieces = np.array(tetrahedra)
        coarse, fine = (self._cone_integrals(pieces, order) for order in VOLUME_ORDERS)
        for _ in range(VOLUME_ROUNDS):
            error = np.abs(fine - coarse)  # (far more than fine's own error)
            allowed = VOLUME_TOLERANCE * abs(fine.sum())
            if error.sum() <= allowed:
                return float(fine.sum())
            cut = error > allowed / (2 * len(pieces))  # the rest sum to half the allowance at most
            halves = _halved(pieces[cut], self.geometry.plane_chart_density)
            pieces = np.concatenate([pieces[~cut], halves])
            coarse, fine = (
                np.concatenate([v[~cut], self._cone_integrals(halves, order)])
                for v, order in zip((coarse, fine), VOLUME_ORDERS)
            )
        raise SpaceError(
            f"{self.source}: the domain's volume integral does not settle to {VOLUME_TOLERANCE:g} in "
            f"{VOLUME_ROUNDS} rounds of halving its pieces ({len(pieces)} pieces): is the domain near the "
            "edge of the chart?"
        )

    def _cone_integrals(self, tetrahedra, order) -> np.ndarray:
        """The volume density integrated over each tetrahedron (v0, v1, v2, v3) of the plane chart,
        by the collapsed Gauss-Legendre rule: x = v0 + a (v1 - v0 + b (v2 - v1 + c (v3 - v2)))."""
        u, w = np.polynomial.legendre.leggauss(order)
        u, w = 0.5 * (u + 1), 0.5 * w
        A, B, C = (x.ravel()[:, None] for x in np.meshgrid(u, u, u, indexing="ij"))
        W = (np.einsum("i,j,k->ijk", w, w, w).ravel()[:, None] * A**2 * B)[:, 0]
        v0, v1, v2, v3 = (tetrahedra[:, k] for k in range(4))
        e1, e2, e3 = v1 - v0, v2 - v1, v3 - v2
        jac = np.abs(np.linalg.det(np.stack([e1, e2, e3], axis=1)))
        out = np.empty(len(tetrahedra))
        for s in range(0, len(tetrahedra), 256):  # (bounded memory: 256 x order^3 points at a time)
            k = slice(s, s + 256)
            X = v0[None, k] + A[..., None] * (e1[None, k] + B[..., None] * (e2[None, k] + C[..., None] * e3[None, k]))
            out[k] = W @ self.geometry.plane_chart_density(X) * jac[k]
        return out

    def reduces_to_identity(self, M, probes) -> bool:
        """Whether the isometry M is an element of the group, to the rounding of M's size (_rounding)."""
        tol = _rounding(M)
        g = self.geometry
        Y, _, R = self.move_inside(np.asarray(probes, float) @ np.asarray(M).T)
        return bool(
            np.allclose(g.to_chart(Y), g.to_chart(probes), atol=tol) and np.allclose(R @ M, np.eye(4), atol=tol)
        )

    def _validate(self, data: dict):
        where = self.source
        g = self.geometry
        rng = np.random.default_rng(20261201)
        probes = g.to_model(self._interior_points(rng, 8))
        words = [*self.generators, *(np.linalg.inv(M) for M in self.generators)]
        for (i, a), b in ((p, b) for p in enumerate(self.generators) for b in words):
            if not self.reduces_to_identity(b @ a @ np.linalg.inv(b), probes):
                raise SpaceError(
                    f"{where}: the conjugate of generator {self.generator_names[i]!r} by another generator "
                    "is not in the group the domain tiles by: the group is not discrete with this domain"
                )
        # p and w(p) reduce to one point for random words w (of 6 letters, fewer where the entries
        # pass WORD_SIZE: far out, H2xR's hyperboloid points round onto the disk's rim)
        points = g.to_model(self._interior_points(rng, 64))
        for _ in range(8):
            W = np.eye(4)
            for k in rng.integers(0, len(words), 6):
                if np.abs(W).max() > WORD_SIZE:
                    break
                W = W @ words[k]
            Y, _, _ = self.move_inside(points @ W.T)
            if not np.allclose(g.to_chart(Y), g.to_chart(points), atol=_rounding(W)):
                raise SpaceError(
                    f"{where}: points and their images under the group reduce to different points of "
                    "the domain: the faces do not bound a fundamental domain of the group"
                )
        if "covolume" in data:
            covolume = evaluate(data["covolume"], f"{where}: covolume")
            if abs(self.volume - covolume) > 1e-6 * max(1.0, covolume):
                raise SpaceError(
                    f"{where}: the domain's volume {self.volume:.9g} is not the covolume {covolume:.9g} the file states"
                )
