"""S2xR: the round sphere times the line, authored in the chart R^3 minus the origin with the metric
    g = |dx|^2 / |x|^2,
that is x = e^w u with u on the unit sphere and w = log|x| the line's coordinate.

The chart is the model (points (x, 1), tangent vectors (v, 0), as for Nil and Sol): the isometries
used here, rotations times dilations x -> e^c R x (R in O(3)), are then the linear maps
diag(e^c R, 1), words are matrix products and chart-affine. The inversions x -> -x / |x|^2 (the
reflections w -> -w) are isometries too, but no 4-dimensional model makes them linear together with
the dilations: the line's isometry group R x| Z2 is not abelian, and commuting with O(3) (acting
irreducibly on three slots) leaves it one slot (it needs two, as (e^w, e^-w)). The antipodal ones
(antipodal_reflection) are applied to chart points directly, for the folded shells (faces.Spheres).
Faces are spheres |x| = e^w0: `plane_coordinates` gives (0, 0, w, 1), in which they are the planes
w = w0, and w is linear in arclength along every geodesic.
Geodesics (log-spirals in a plane through the origin), connecting geodesics and the falloff are
closed forms of the product.
"""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np

from . import faces
from .affine import AffineGeometry, homogeneous
from .shared import floats


def antipodal_reflection(x, radius):
    """x -> -R^2 x / |x|^2: u -> -u, w -> 2 log R - w, an isometry that preserves orientation (the
    antipodal map and the inversion each reverse it) and fixes no point (the sphere |x| = R goes to
    itself antipodally)."""
    x = floats(x)
    return -(radius**2) * x / np.sum(x * x, axis=-1)[..., None]


def antipodal_reflection_tangent(x, v, radius):
    """Its differential at x: -R^2 (v - 2 x (x . v) / |x|^2) / |x|^2, conformal (normals stay normal)."""
    x, v = floats(x), floats(v)
    r2 = np.sum(x * x, axis=-1)[..., None]
    return -(radius**2) * (v - 2 * x * np.sum(x * v, axis=-1)[..., None] / r2) / r2


def _sin_over(a, t):
    """sin(a t) / a, the form stable as a -> 0."""
    return np.where(a > 0, np.sin(a * t) / np.where(a > 0, a, 1.0), t)


class S2xR(AffineGeometry):
    name = "S2xR"
    copy_rings = 1  # a shell's neighbours are its two dilated copies
    light_reach_circumradii = 2.0  # the copies within R grow like R, their geodesics like R^2
    chord_scale = 4.0  # its chords stray far less than K h^2 / 8 (docs/front.md, "The chord rule")

    @cached_property
    def face_shape(self):
        """Faces are spheres |x| = const, glued to themselves by the antipodal reflections."""
        return faces.Spheres(self, antipodal_reflection, antipodal_reflection_tangent)

    # --- charts -------------------------------------------------------------------------------
    def in_chart(self, x):
        """Finite points other than the origin."""
        x = np.asarray(x, float)
        return np.all(np.isfinite(x), axis=-1) & np.any(x != 0, axis=-1)  # (|x|^2 may underflow far in)

    def plane_coordinates(self, X):
        """(0, 0, w, 1), w = log|x|: the spheres |x| = e^w0 are the planes w = w0."""
        x = self.to_chart(X)
        w = 0.5 * np.log(np.sum(x * x, axis=-1))
        zero = np.zeros_like(w)
        return np.stack([zero, zero, w, np.ones_like(w)], axis=-1)

    # --- metric ---------------------------------------------------------------------------------
    def metric(self, x):
        x = floats(x)
        return np.eye(3) / np.sum(x * x, axis=-1)[..., None, None]

    def christoffel(self, x):
        """[..., k, i, j] = Gamma^k_ij of the conformal metric e^{2 phi} delta, phi = -log|x|:
        delta_ki d_j phi + delta_kj d_i phi - delta_ij d_k phi, with d phi = -x / |x|^2."""
        x = floats(x)
        d = -x / np.sum(x * x, axis=-1)[..., None]
        I = np.eye(3)
        return (
            np.einsum("ki,...j->...kij", I, d) + np.einsum("kj,...i->...kij", I, d) - np.einsum("ij,...k->...kij", I, d)
        )

    def volume_density(self, x):
        """sqrt(det g) = |x|^-3."""
        return np.sum(floats(x) ** 2, axis=-1) ** -1.5

    # --- geodesics --------------------------------------------------------------------------------
    def geodesic(self, P, V, t):
        """Position and unit velocity at arclength t from P with unit tangent V: with b = <v, x> /
        |x|^2 (the speed of w) and p = v - b x (|p| = a |x|, a the speed on the sphere),
        x(t) = e^{b t} (cos(a t) x + sin(a t) / a . p), a log-spiral in the plane of x and v."""
        P, V, t = floats(P), floats(V), floats(t)
        x, v = self.to_chart(P), V[..., :3]
        r2 = np.sum(x * x, axis=-1)
        b = np.sum(v * x, axis=-1) / r2
        p = v - b[..., None] * x
        a = np.sqrt(np.sum(p * p, axis=-1) / r2)
        grow, cos, sin_over = np.exp(b * t), np.cos(a * t), _sin_over(a, t)
        spiral = cos[..., None] * x + sin_over[..., None] * p
        turning = (-a * a * sin_over)[..., None] * x + cos[..., None] * p  # d spiral / dt
        xt = grow[..., None] * spiral
        ut = grow[..., None] * (b[..., None] * spiral + turning)
        return homogeneous(xt, 1.0), homogeneous(ut, 0.0)

    # --- distances and light ----------------------------------------------------------------------
    def _split(self, A, B):
        """(theta, dw, e, radius): the sphere angle between the points' directions, the difference
        of w, the unit chart vector at A towards B's direction orthogonal to A (0 where none), |a|."""
        a, c = np.broadcast_arrays(self.to_chart(floats(A)), self.to_chart(floats(B)))
        ra, rc = np.linalg.norm(a, axis=-1), np.linalg.norm(c, axis=-1)
        ua, uc = a / ra[..., None], c / rc[..., None]
        cos = np.sum(ua * uc, axis=-1)
        e = uc - cos[..., None] * ua
        sin = np.linalg.norm(e, axis=-1)
        theta = np.arctan2(sin, cos)
        e = e / np.where(sin > 0, sin, 1.0)[..., None]
        return theta, np.log(rc / ra), e, ra

    def distance(self, A, B):
        theta, dw, _, _ = self._split(A, B)
        return np.hypot(theta, dw)

    def connect(self, A, B):
        """(V, r, ok): the unit tangent at A and length of the shortest geodesic to B in closed
        form: the great-circle arc of the directions (angle theta <= pi) and the straight w part.
        Where A = B, r = 0 and V is the chart x direction; antipodal directions take any arc."""
        theta, dw, e, ra = self._split(A, B)
        a = self.to_chart(floats(A))
        r = np.hypot(theta, dw)
        u = a / ra[..., None]
        towards = dw[..., None] * u + theta[..., None] * e  # times |a| / r: unit in the metric
        x_axis = np.broadcast_to([1.0, 0.0, 0.0], u.shape)
        direction = np.where((r > 0)[..., None], towards / np.where(r > 0, r, 1.0)[..., None], x_axis)
        V = homogeneous(ra[..., None] * direction, 0.0)
        return V, r, np.ones(np.shape(r), bool)

    def plane_distances(self, X, C):
        """Signed distances from model points X to the face spheres of the covectors C (rows, on
        (0, 0, w, 1); positive on the side c . (0, 0, w, 1) > 0): (c2 w + c3) / |c2|."""
        C = np.asarray(C, float)
        return (self.plane_coordinates(X) @ C.T) / np.abs(C[:, 2])

    def domain_distance(self, X, domain):
        """Distances from model points X to a shell domain: of w beyond its spheres."""
        return np.maximum(np.max(self.plane_distances(X, domain.covectors()), axis=-1), 0.0)

    def falloff_along(self, P, V, r):
        """1 / (r^2 |det d exp_P(r V)|): the exponential map is the sphere's times the identity,
        whose determinant at sphere length a r is sin(a r) / (a r) (a the speed on the sphere)."""
        P, V, r = floats(P), floats(V), floats(r)
        x, v = self.to_chart(P), V[..., :3]
        r2 = np.sum(x * x, axis=-1)
        b = np.sum(v * x, axis=-1) / r2
        a = np.sqrt(np.maximum(np.sum(v * v, axis=-1) / r2 - b * b, 0.0))
        ar = a * r
        stretch = np.where(ar > 0, np.sin(ar) / np.where(ar > 0, ar, 1.0), 1.0)
        return 1.0 / (r * r * np.abs(stretch))

    # --- isometries -------------------------------------------------------------------------------
    def similarity(self, R, c=0.0):
        """The isometry x -> e^c R x for R in O(3)."""
        M = np.eye(4)
        M[:3, :3] = math.exp(c) * np.asarray(R, float)
        return M

    def _scale(self, M):
        """(e^c, R) of M's linear part e^c R."""
        A = np.asarray(M, float)[:3, :3]
        s = float(np.cbrt(abs(np.linalg.det(A))))
        return s, A / s if s > 0 else A

    def is_isometry(self, M, tol=1e-9):
        """Whether M is diag(e^c R, 1): a finite 4x4 matrix with no translation, last row
        (0, 0, 0, 1) and a linear part that is a positive multiple of an orthogonal matrix."""
        M = np.asarray(M, float)
        if M.shape != (4, 4) or not np.all(np.isfinite(M)):
            return False
        if not (np.allclose(M[3], [0, 0, 0, 1], rtol=0, atol=tol) and np.allclose(M[:3, 3], 0, rtol=0, atol=tol)):
            return False
        s, R = self._scale(M)
        return bool(s > 0 and np.allclose(R.T @ R, np.eye(3), rtol=0, atol=tol))

    def reorthonormalize(self, M):
        """The nearest e^c R: the orthogonal factor of the polar decomposition, the scale kept."""
        s, R = self._scale(M)
        U, _, Wt = np.linalg.svd(R)
        return self.similarity(U @ Wt, math.log(s))

    def point_coordinates(self, X):
        """The point of the sphere and w: the model's chart point e^w u has the copies a period
        below it crowded about the origin, where its direction and length no longer part them."""
        x = floats(X)[..., :3] / floats(X)[..., 3:4]
        r = np.linalg.norm(x, axis=-1, keepdims=True)
        return np.concatenate([x / r, np.log(r)], axis=-1)

    def element_key(self, M):
        """The rotation part and the dilation exponent c."""
        s, R = self._scale(M)
        return tuple(np.round(R.ravel(), 7)) + (round(math.log(s), 7),)

    def pull_back_plane(self, c, M):
        """Faces are spheres w = w0, covectors (0, 0, c2, c3) on (0, 0, w, 1): M = e^c R moves w by c."""
        c = np.asarray(c, float)
        if c[0] != 0.0 or c[1] != 0.0:
            raise ValueError(
                f"the face {c.tolist()} is not a sphere |x| = const: S2xR faces are "
                "[0, 0, c, d], the sphere c log|x| + d = 0"
            )
        s, _ = self._scale(M)
        return c + np.array([0.0, 0.0, 0.0, c[2] * math.log(s)])
