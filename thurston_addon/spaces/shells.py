"""Shell spaces: coordinate domains whose faces are spheres |x| = const (S2xR's), the shell
between two of them, and the folded shells whose spheres are glued to themselves."""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np

from .coordinate import CoordinateSpace
from .domains import Domain, Face, Fold
from .space import read_geometry
from .values import SpaceError, vector

# The largest |log|x|| of a shell's sphere, and the widest shell (log R_out - log R_in): the tracer
# keeps chart points in float32 (to 3.4e38 = e^88.7), so the shell's neighbouring copies must lie
# within e^80; and the domain test squares points that words of a few face maps reach in float64.
MAX_SPHERE_LOG = 40.0
MAX_SHELL_WIDTH = 40.0
# The thinnest shell (log R_out - log R_in) a folded shell may be: its face maps are the
# dilations by e^(2 width), which float64 must tell from the identity with room to spare.
MIN_SHELL_WIDTH = 1e-6


def _sphere_face(c, where, geometry) -> tuple[float, bool]:
    """(w0, whether the shell lies inside it) of a shell's face covector (0, 0, c, d): the sphere
    c log|x| + d = 0, the domain on the side <= 0, within e^-MAX_SPHERE_LOG < |x| < e^MAX_SPHERE_LOG."""
    try:
        w0, outside = geometry.face_shape.sphere(c)
    except ValueError as exc:
        raise SpaceError(f"{where}: {exc}") from None
    if not abs(w0) <= MAX_SPHERE_LOG:
        raise SpaceError(
            f"{where}: its face is the sphere |x| = e^{w0:.6g}, beyond the chart's range: a shell's spheres "
            f"must lie between |x| = e^-{MAX_SPHERE_LOG:g} and e^{MAX_SPHERE_LOG:g} (the tracer keeps chart "
            "points and their copies in float32); move the face nearer |x| = 1"
        )
    return w0, outside


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
            raise SpaceError(
                f"{where}: a face sphere does not bound the shell between |x| = e^{inner:g} and e^{outer:g}"
            )
        if outer - inner > MAX_SHELL_WIDTH:
            raise SpaceError(
                f"{where}: the shell between |x| = e^{inner:.6g} and e^{outer:.6g} is {outer - inner:.6g} wide in "
                f"log|x|, more than the {MAX_SHELL_WIDTH:g} whose neighbouring copies the tracer's float32 chart "
                "holds; bring its spheres nearer each other"
            )
        axes = np.vstack([np.eye(3), -np.eye(3)])
        vertices = np.vstack([math.exp(inner) * axes, math.exp(outer) * axes])
        faces = [
            Face(covector=np.asarray(c, float) / np.linalg.norm(c[:3]), element=M, vertices=[])
            for c, M in zip(covectors, elements)
        ]
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

    @property
    def centre(self) -> np.ndarray:
        """The centre of the largest chart ball inside the shell: a point of the middle of the
        shell, on the -y axis (the chart origin is no point of the space)."""
        return np.array([0.0, -0.5 * (self.radii[0] + self.radii[1]), 0.0])

    def size_ratio(self, vertices) -> float:
        """How many times the shell's size an object of these chart vertices is, measured where it
        lies: the metric is |dx| / |x| (dilations are isometries), so the shell's chart size there
        is its metric extent times the chart distance from the origin to the object's box; an
        object whose box holds the origin (no point of the space) is infinitely larger."""
        V = np.asarray(vertices, float)
        lo, hi = V.min(axis=0), V.max(axis=0)
        near = float(np.linalg.norm(np.maximum(0.0, np.maximum(lo, -hi))))  # the box's point nearest 0
        size = float(np.linalg.norm(hi - lo))
        return math.inf if near == 0 else size / (self.metric_extent * near)

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
        g = read_geometry(data, source)
        faces = []
        for i, gen in enumerate(data.get("generator") or []):
            name = gen.get("name", f"g{i}") if isinstance(gen, dict) else f"g{i}"
            where = f"{source}: generator {name!r}"
            if not isinstance(gen, dict) or gen.get("antipodal") is not True:
                raise SpaceError(
                    f"{where}: in a shell whose spheres are glued to themselves every generator is "
                    "'antipodal = true' with its sphere as the face"
                )
            if "matrix" in gen:
                raise SpaceError(
                    f"{where}: an antipodal reflection has no matrix (no 4x4 linear map is one); give only its face"
                )
            faces.append(_sphere_face(vector(gen.get("face"), 4, f"{where} face"), where, g))
        if len(faces) != 2:
            raise SpaceError(
                f"{source}: a shell glued to itself has two antipodal reflections, one in each sphere; got {len(faces)}"
            )
        (a, a_outer), (b, b_outer) = sorted(faces)
        if not (b > a and b_outer and not a_outer):
            raise SpaceError(
                f"{source}: the two reflections' faces do not bound a shell (the inner sphere's face is "
                "[0, 0, -1, log R_in], the outer's [0, 0, 1, -log R_out], R_in < R_out)"
            )
        if 2 * (b - a) > MAX_SHELL_WIDTH:  # (its double cover, which is traced, is twice as wide)
            raise SpaceError(
                f"{source}: the shell between the two reflections' spheres, |x| = e^{a:.6g} and e^{b:.6g}, is "
                f"{b - a:.6g} wide in log|x|, more than the {MAX_SHELL_WIDTH / 2:g} whose double cover's copies the "
                "tracer's float32 chart holds; bring its spheres nearer each other"
            )
        if b - a < MIN_SHELL_WIDTH:  # (else the dilation the reflections compose to rounds to the identity)
            raise SpaceError(
                f"{source}: the shell between the two reflections' spheres, |x| = e^{a:.6g} and e^{b:.6g}, is "
                f"{b - a:.3g} thick, thinner than the {MIN_SHELL_WIDTH:g} a domain in float64 needs; move the spheres apart"
            )
        self.folded_radii = (math.exp(a), math.exp(b))
        shape = g.face_shape
        self.fold = Fold(
            points=lambda x: shape.reflection(x, self.folded_radii[0]),
            vectors=lambda x, v: shape.reflection_tangent(x, v, self.folded_radii[0]),
            mirrored=lambda x: np.sum(np.asarray(x) ** 2, axis=-1) < self.folded_radii[0] ** 2,
        )
        period = 2 * (b - a)
        cover = dict(
            data,
            generator=[
                {
                    "name": "reflections",  # the outer reflection after the inner: the dilation by e^period
                    "matrix": np.diag([math.exp(period)] * 3 + [1.0]).tolist(),
                    "face": [0, 0, 1, -b],
                }
            ],
        )
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
        reflections = [lambda p, r=r: g.face_shape.reflection(p, r) for r in self.radii]
        for r in self.radii:  # each pulls the metric back onto itself
            p, e = x[:4], np.eye(3)
            J = np.stack([g.face_shape.reflection_tangent(p, np.broadcast_to(v, p.shape), r) for v in e], -1)
            image = g.face_shape.reflection(p, r)
            pulled = np.einsum("nki,nkl,nlj->nij", J, g.metric(image), J)
            want = g.metric(p)
            if not np.allclose(pulled, want, rtol=0, atol=1e-9 * np.abs(want).max()):
                raise SpaceError(
                    f"{self.source}: the antipodal reflection in |x| = {r:g} is not an isometry of {g.name}"
                )
        for _ in range(6):  # words in the reflections reduce to the point itself
            y = x.copy()
            for k in rng.integers(0, 2, 5):
                y = reflections[k](y)
            back, _ = self.unfolded(g.to_chart(self.move_inside(g.to_model(y))[0]))
            if not np.allclose(back, x, rtol=1e-8, atol=1e-8):
                raise SpaceError(
                    f"{self.source}: points and their images under the reflections reduce to different "
                    "points of the shell: the faces do not bound its fundamental domain"
                )
