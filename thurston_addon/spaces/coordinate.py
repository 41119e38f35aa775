"""Coordinate spaces: the domain is given by the file, each generator naming the face beyond which
its copy of the domain lies; validated by discreteness, unique reduction and the covolume."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from .domains import Domain, halfspace_domain
from .space import Space, is_identity
from .values import SpaceError, evaluate, vector


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
                raise SpaceError(
                    f"{where}: the conjugate of generator {self.generator_names[i]!r} by another generator "
                    "is not in the group the domain tiles by: the group is not discrete with this domain"
                )
        # p and w(p) reduce to one point for random words w
        points = g.to_model(self._interior_points(rng, 64))
        for _ in range(8):
            W = np.eye(4)
            for k in rng.integers(0, len(words), 6):
                W = W @ words[k]
            Y, _, _ = self.move_inside(points @ W.T)
            # the float64 generators satisfy the group's relations to rounding of the word's size
            if not np.allclose(g.to_chart(Y), g.to_chart(points), atol=1e-8 * max(1.0, np.abs(W).max())):
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
