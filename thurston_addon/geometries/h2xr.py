"""H2xR: the hyperbolic plane times the line, authored in the chart Klein disk x R with the product
metric
    g = (dx^2 + dy^2) / (1 - r^2) + (x dx + y dy)^2 / (1 - r^2)^2 + dz^2,   r^2 = x^2 + y^2 < 1.

Model vectors X = (X1, X2, E, X0): (X1, X2, X0) on the upper sheet of the hyperboloid
X0^2 - X1^2 - X2^2 = 1 over the Klein point (x, y) = (X1, X2) / X0, and E = e^z. The isometries
used, H^2 isometries times translations of z, are then linear: M = A (+) e^c, A in SO+(2,1) on
the slots (0, 1, 3) and e^c on slot 2, so that words are matrix products and the space code applies
them to points as it does for the other geometries. The disk part is H3's hyperboloid in its plane
X[2] = 0, so its metric, Christoffel symbols, geodesics and repairs are H3's restricted there.
Face planes are chart planes (the sides of a polygon in the disk are chords, the lids z = const),
so `plane_coordinates` gives chart homogeneous points (x, y, z, 1).
Geodesics, connecting geodesics and the falloff are closed forms of the product.
"""

from __future__ import annotations

import math

import numpy as np

from .hyperbolic import Hyperbolic
from .projective import repaired_lorentz
from .shared import SharedGeometry, floats

DISK = [0, 1, 3]  # the model slots of the hyperboloid
LINE = 2  # the model slot of e^z
_H2 = Hyperbolic()  # H^2 is H3's plane X[2] = 0


def _disk(X):
    """The H3 model vector of the H^2 part (slot 2 set to 0)."""
    D = np.array(floats(X), copy=True)
    D[..., LINE] = 0.0
    return D


def _with_line(D, value):
    D[..., LINE] = value
    return D


def _in_plane(x):
    """Chart points (..., 3) moved to z = 0, where H3's Klein formulas are H^2's."""
    x = np.array(floats(x), copy=True)
    x[..., 2] = 0.0
    return x


def polygon_distance(Y, covectors, ends):
    """H^2 distances from hyperboloid points Y (..., 3) = (X1, X2, X0) to the convex polygon of the
    Klein disk {k : c . (k, 1) <= 0} (covectors c, rows), whose sides run between the Klein points
    ends[i] (each (2+, 2): a side's vertices): 0 inside, else to the nearest side, to its line
    where the foot of the perpendicular lies on the side, else to the nearer end."""
    Y = floats(Y)
    inside = np.all(Y @ np.asarray(covectors, float).T <= 0, axis=-1)
    J = np.array([1.0, 1.0, -1.0])  # the Lorentz form on (X1, X2, X0)
    to_side = np.inf
    for side in ends:
        a, b = np.unique(np.round(np.asarray(side, float), 12), axis=0)
        A, B = (np.r_[p, 1.0] / math.sqrt(1.0 - p @ p) for p in (a, b))
        n = J * np.cross(A, B)
        n /= math.sqrt(n @ (J * n))
        s = Y @ (J * n)  # <Y, n>: sinh of the distance to the side's line
        foot = Y - s[..., None] * n
        t = ((foot[..., :2] / foot[..., 2:3] - a) @ (b - a)) / ((b - a) @ (b - a))
        ends_distance = np.minimum(*(np.arccosh(np.maximum(-(Y @ (J * E)), 1.0)) for E in (A, B)))
        to_side = np.minimum(to_side, np.where((t >= 0) & (t <= 1), np.arcsinh(np.abs(s)), ends_distance))
    return np.where(inside, 0.0, to_side)


class H2xR(SharedGeometry):
    name = "H2xR"
    projective = False
    diameter = math.inf
    copy_rings = 1  # hyperbolic rings of copies grow too fast for more
    light_reach_circumradii = 1.0  # the copies within R grow like exp(R)
    chord_scale = 4.0  # its chords stray far less than K h^2 / 8 (docs/front.md, "The chord rule")
    # Far in the cover the disk coordinates grow like e^t, as in H3 (see Hyperbolic).
    reference_depth = Hyperbolic.reference_depth
    # the volume density (1 - r^2)^(-3/2) peaks at the octagon's vertices (r = 0.985): 32 points
    # per axis reach 4e-8 relative there, 16 only 2e-4
    volume_order = 32

    # --- charts -------------------------------------------------------------------------------
    def to_chart(self, X):
        X = floats(X)
        return np.concatenate([X[..., :2] / X[..., 3:4], np.log(X[..., LINE : LINE + 1])], axis=-1)

    def to_model(self, x):
        x = floats(x)
        return _with_line(_H2.to_model(_in_plane(x)), np.exp(x[..., 2]))

    def in_chart(self, x):
        """Finite points over the open unit disk."""
        x = np.asarray(x, float)
        return np.all(np.isfinite(x), axis=-1) & (np.sum(x[..., :2] ** 2, axis=-1) < 1.0)

    def tangent_to_model(self, x, u):
        x, u = np.broadcast_arrays(floats(x), floats(u))
        return _with_line(_H2.tangent_to_model(_in_plane(x), _in_plane(u)), np.exp(x[..., 2]) * u[..., 2])

    def tangent_to_chart(self, X, V):
        X, V = floats(X), floats(V)
        disk = (V[..., :2] - X[..., :2] * (V[..., 3:4] / X[..., 3:4])) / X[..., 3:4]
        return np.concatenate([disk, V[..., LINE : LINE + 1] / X[..., LINE : LINE + 1]], axis=-1)

    def normalize_point(self, X):
        X = floats(X)
        return _with_line(_H2.normalize_point(_disk(X)), X[..., LINE])

    def normalize_tangent(self, X, V):
        """V projected onto the tangent space at X, scaled to unit length in the metric."""
        X, V = np.broadcast_arrays(floats(X), floats(V))
        D, W = _disk(X), _disk(V)
        W = _with_line(W + _H2.inner(D, W)[..., None] * D, V[..., LINE])
        return W / np.sqrt(self.dot(X, W, W))[..., None]

    def plane_coordinates(self, X):
        x = self.to_chart(X)
        return np.concatenate([x, np.ones(x.shape[:-1] + (1,), x.dtype)], axis=-1)

    # --- metric ---------------------------------------------------------------------------------
    def dot(self, X, A, B):
        """The Lorentz form on the hyperboloid slots plus dz^2 = (dE / E)^2."""
        X, A, B = floats(X), floats(A), floats(B)
        return _H2.inner(_disk(A), _disk(B)) + A[..., LINE] * B[..., LINE] / X[..., LINE] ** 2

    def metric(self, x):
        """Chart metric (..., 3, 3): the Klein metric on (x, y) (H3's at z = 0), 1 on z."""
        g = _H2.metric(_in_plane(x))
        g[..., 2, :] = g[..., :, 2] = 0.0
        g[..., 2, 2] = 1.0
        return g

    def christoffel(self, x):
        """[..., k, i, j] = Gamma^k_ij: the Klein disk's (x_i delta_jk + x_j delta_ik) / (1 - r^2)
        for i, j, k in {x, y}; every symbol with a z index vanishes (a product with a line)."""
        G = _H2.christoffel(_in_plane(x))
        G[..., 2, :, :] = G[..., :, 2, :] = G[..., :, :, 2] = 0.0
        return G

    def volume_density(self, x):
        """sqrt(det g) = (1 - r^2)^(-3/2)."""
        x = np.asarray(x, float)
        return (1.0 - np.sum(x[..., :2] ** 2, axis=-1)) ** -1.5

    # --- geodesics --------------------------------------------------------------------------------
    def geodesic(self, P, V, t):
        """Position and unit velocity at arclength t from P with unit tangent V: on the hyperboloid
        cosh(a t) p + sinh(a t) / a . v (a the horizontal speed, the form stable as a -> 0),
        E = E0 e^{b t} (b the vertical speed)."""
        P, V, t = floats(P), floats(V), floats(t)
        D, W = _disk(P), _disk(V)
        a = np.sqrt(np.maximum(_H2.inner(W, W), 0.0))
        at = a * t
        sinh_over = np.where(a > 0, np.sinh(at) / np.where(a > 0, a, 1.0), t)  # sinh(a t) / a
        cosh = np.cosh(at)
        b = V[..., LINE] / P[..., LINE]
        E = P[..., LINE] * np.exp(b * t)
        X = _with_line(cosh[..., None] * D + sinh_over[..., None] * W, E)
        U = _with_line((a * a * sinh_over)[..., None] * D + cosh[..., None] * W, b * E)
        return X, U

    # --- distances and light ----------------------------------------------------------------------
    def _horizontal(self, A, B):
        """(d, W): the H^2 distance of the disk parts and the unit tangent at A towards B (0 where
        they coincide)."""
        D, F = _disk(A), _disk(B)
        W = F + _H2.inner(D, F)[..., None] * D  # the part of F orthogonal to D: |W| = sinh d
        s = np.sqrt(np.maximum(_H2.inner(W, W), 0.0))
        return np.arcsinh(s), W / np.where(s > 0, s, 1.0)[..., None]

    def distance(self, A, B):
        d, _ = self._horizontal(A, B)
        dz = np.log(floats(B)[..., LINE] / floats(A)[..., LINE])
        return np.hypot(d, dz)

    def connect(self, A, B):
        """(V, r, ok): the unit tangent at A and length of the geodesic to B in closed form: the H^2
        geodesic of the disk parts and the straight z part (the shortest, and the only one in the
        cover). Where A = B, r = 0 and V is the chart x direction."""
        A, B = np.broadcast_arrays(floats(A), floats(B))
        d, W = self._horizontal(A, B)
        dz = np.log(B[..., LINE] / A[..., LINE])
        r = np.hypot(d, dz)
        T = _with_line(d[..., None] * W, A[..., LINE] * dz)
        x_axis = self.tangent_to_model(self.to_chart(A), np.broadcast_to([1.0, 0.0, 0.0], A.shape[:-1] + (3,)))
        V = self.normalize_tangent(A, np.where((r > 0)[..., None], T, x_axis))
        return V, r, np.ones(np.shape(r), bool)

    def plane_distances(self, X, C):
        """Signed distances from model points X to the chart planes of the covectors C (rows, on
        (x, y, z, 1); positive on the side c . x > 0): a vertical plane a x + b y + d = 0 is a
        geodesic of the disk times R, at H^2 distance asinh((a X1 + b X2 + d X0) / sqrt(a^2 + b^2 - d^2));
        a horizontal one c z + d = 0 at distance (c z + d) / |c|."""
        X, C = floats(X), np.asarray(C, float)
        vertical = C[:, 2] == 0
        if not np.all(vertical | ((C[:, 0] == 0) & (C[:, 1] == 0))):
            raise ValueError("H2xR face planes are vertical (a x + b y + d = 0) or horizontal (c z + d = 0)")
        disk = X[..., DISK] @ C[:, [0, 1, 3]].T / np.sqrt(np.abs(C[:, 0] ** 2 + C[:, 1] ** 2 - C[:, 3] ** 2))
        z = np.log(X[..., LINE : LINE + 1])
        lids = (C[:, 2] * z + C[:, 3]) / np.abs(np.where(vertical, 1.0, C[:, 2]))
        return np.where(vertical, np.arcsinh(disk), lids)

    def domain_distance(self, X, domain):
        """Distances from model points X (..., 4) to a domain polygon x [z0, z1] (vertical faces and
        two lids): the hypot of the H^2 distance to the polygon (polygon_distance) and the distance
        of z beyond the lids."""
        C = domain.covectors()
        d = self.plane_distances(X, C)
        vertical = C[:, 2] == 0
        beyond_lids = np.maximum(np.max(np.where(vertical, -np.inf, d), axis=-1), 0.0)
        ends = [domain.vertices[f.vertices, :2] for f, v in zip(domain.faces, vertical) if v]
        return np.hypot(polygon_distance(floats(X)[..., DISK], C[vertical][:, DISK], ends), beyond_lids)

    def falloff_along(self, P, V, r):
        """1 / (r^2 |det d exp_P(r V)|): the exponential map is H^2's times the identity, whose
        determinant at horizontal length a r is sinh(a r) / (a r) (a the horizontal speed)."""
        r = floats(r)
        W = _disk(V)
        ar = np.sqrt(np.maximum(_H2.inner(W, W), 0.0)) * r
        stretch = np.where(ar > 0, np.sinh(ar) / np.where(ar > 0, ar, 1.0), 1.0)
        return 1.0 / (r * r * stretch)

    # --- isometries -------------------------------------------------------------------------------
    def product(self, A, c=0.0):
        """The isometry (p, z) -> (A p, z + c) for A in SO+(2,1) (acting on (X1, X2, X0))."""
        M = np.zeros((4, 4))
        M[np.ix_(DISK, DISK)] = A
        M[LINE, LINE] = math.exp(c)
        return M

    def _split(self, M):
        """(H, lam): the H3 matrix of M's disk part (slot 2 the identity) and e^c."""
        H = np.array(M, float, copy=True)
        lam = H[LINE, LINE]
        H[LINE, LINE] = 1.0
        return H, lam

    def is_isometry(self, M, tol=1e-9):
        """Whether M is A (+) e^c: no coupling of slot 2 with the hyperboloid slots, A in
        SO+(2,1) (H3's test on its plane) and e^c > 0."""
        M = np.asarray(M, float)
        if M.shape != (4, 4) or not np.all(np.isfinite(M)):
            return False
        H, lam = self._split(M)
        size = max(1.0, np.abs(M).max())
        coupled = max(np.abs(M[LINE, DISK]).max(), np.abs(M[DISK, LINE]).max())
        return bool(coupled <= tol * size and lam > 0 and _H2.is_isometry(H, tol))

    def reorthonormalize(self, M):
        """The exact isometries nearest M (..., 4, 4): H3's repair of the disk part (through its
        spinor, each entry to its own rounding), the translation kept."""
        H = np.array(M, float, copy=True)
        lam = H[..., LINE, LINE].copy()
        H[..., LINE, :] = H[..., :, LINE] = 0.0
        H[..., LINE, LINE] = 1.0
        R = repaired_lorentz(H)
        R[..., LINE, :] = R[..., :, LINE] = 0.0
        R[..., LINE, LINE] = lam
        return R

    def repair_products(self, M):
        """Repaired (reorthonormalize): a product of SO+(2,1) matrices errs by up to |s| ~ e^(2 r_in)
        times its factors' relative rounding in the directions s stretches, so a walk sideways
        around the cover gains about that factor a step (10^-6 after ten steps in genus 3)."""
        return self.reorthonormalize(M)

    def element_key(self, M):
        """The image of the origin's disk point (the H^2 action is free) and the translation."""
        M = np.asarray(M, float)
        return tuple(np.round(M[DISK, 3], 7)) + (round(math.log(M[LINE, LINE]), 7),)

    def pull_back_plane(self, c, M):
        """Vertical planes (chords of the disk times R) pull back by the disk part, horizontal
        ones (z = const) by the translation; M maps no other plane onto a plane unless it is a
        pure translation."""
        c, M = np.asarray(c, float), np.asarray(M, float)
        H, lam = self._split(M)
        if c[2] == 0.0:
            out = np.zeros(4)
            out[DISK] = c[DISK] @ H[np.ix_(DISK, DISK)]
            return out
        if not np.allclose(H, np.eye(4), rtol=0.0, atol=1e-12):
            raise ValueError(f"the plane {c.tolist()} is not mapped onto a plane by an isometry that moves the disk")
        return c + np.array([0.0, 0.0, 0.0, c[2] * math.log(lam)])
