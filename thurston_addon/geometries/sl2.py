"""SL2~: the universal cover of SL(2,R), in the model D x R of chart points (x, y, phi): w = x + iy in
the Poincare disk, phi the angle of a unit tangent vector of H^2 lifted to R, with the lifted Sasaki
metric of T^1 H^2 (one metric of SL2~'s one-parameter family; 3DS's, HyperRogue's at stretch 0 with
lengths halved)
    g = lam^2 (dx^2 + dy^2) + (dphi + lam (x dy - y dx))^2,   lam = 2 / (1 - |w|^2).
Fibres are unit-speed geodesics and phi -> phi + 2 pi is the centre.

The isometries used are not linear on chart points: an element (alpha, beta, phi_g), (alpha, beta) in
SU(1,1), acts by
    (w, phi) -> ((alpha w + beta) / (conj(beta) w + conj(alpha)), phi + phi_g - 2 Arg(1 + zeta w)),
zeta = conj(beta) / conj(alpha), Arg principal (1 + zeta w has positive real part on D, so this is
continuous); phi_g = -2 Arg(conj(alpha)) + 2 pi k are the lifts of SU(1,1), other phi_g add the fibre
translations. Geodesics are states (element g, body velocity b): the point g(origin) with velocity
g's differential of b, b orthonormal at the origin (where g = diag(4, 4, 1)); the closed form from
the origin composes on the left. These functions (Element) are the universal cover's own.

The Geometry's model is SU(1,1) itself, SL2~ modulo the fibre translation by 4 pi (which every
compact quotient over a genus-2 surface contains: the lifted relator is T_-4pi): the point (w, phi)
is the first row (alpha, beta) = (e^{i phi/2}, w e^{-i phi/2}) / sqrt(1 - |w|^2) of its SU(1,1)
matrix, a model vector (Re alpha, Im alpha, Re beta, Im beta) on the quadric |alpha|^2 - |beta|^2 = 1.
Left multiplication by h in SU(1,1) and the fibre translations (right multiplication by
diag(e^{is/2}, e^{-is/2})) are then linear maps of R^4, so words are matrix products as in the
other geometries. The chart's phi is read back in (-2 pi, 2 pi]. Face planes are planes of
`plane_coordinates` (Klein(w), phi, 1): the sides of the octagon are chords of the Klein disk,
the lids phi = const.
"""

from __future__ import annotations

import math
from functools import cached_property
from typing import NamedTuple

import numpy as np

from . import faces
from .h2xr import polygon_distance
from .hyperbolic import Hyperbolic
from .shared import SharedGeometry, floats


class Element(NamedTuple):
    """Isometries (w, phi) -> (...) of the module docstring; arrays of one leading shape."""

    alpha: np.ndarray  # complex
    beta: np.ndarray  # complex
    phi: np.ndarray  # real


def _w(x):
    x = floats(x)
    return x[..., 0] + 1j * x[..., 1]


def _chart(w, phi):
    return np.stack([w.real, w.imag, phi], -1)


def _zeta(g):
    return np.conj(g.beta) / np.conj(g.alpha)


def multiply(g, h):
    """The element g h (h acts first): SU(1,1) product, phi_g + phi_h - 2 Arg(1 + zeta_g h(0))."""
    alpha = g.alpha * h.alpha + g.beta * np.conj(h.beta)
    beta = g.alpha * h.beta + g.beta * np.conj(h.alpha)
    return Element(alpha, beta, g.phi + h.phi - 2 * np.angle(1 + _zeta(g) * h.beta / np.conj(h.alpha)))


def inverse(g):
    """(conj(alpha), -beta, -phi_g): the phase term of g^-1 g is Arg(1 - |beta / alpha|^2) = 0."""
    return Element(np.conj(g.alpha), -g.beta, -g.phi)


def fibre_translation(s):
    """T_s: (w, phi) -> (w, phi + s)."""
    s = floats(s)
    return Element(np.ones_like(s) + 0j, np.zeros_like(s) + 0j, s)


def act(g, x):
    """g applied to chart points x (..., 3)."""
    w = _w(x)
    image = (g.alpha * w + g.beta) / (np.conj(g.beta) * w + np.conj(g.alpha))
    return _chart(image, floats(x)[..., 2] + g.phi - 2 * np.angle(1 + _zeta(g) * w))


def act_tangent(g, x, u):
    """g's differential at chart points x on chart vectors u: dw -> dw / (conj(beta) w + conj(alpha))^2
    (|alpha|^2 - |beta|^2 = 1), dphi -> dphi - 2 Im(zeta dw / (1 + zeta w))."""
    w, dw = _w(x), _w(u)
    zeta = _zeta(g)
    image = dw / (np.conj(g.beta) * w + np.conj(g.alpha)) ** 2
    return _chart(image, floats(u)[..., 2] - 2 * np.imag(zeta * dw / (1 + zeta * w)))


def from_origin(x):
    """The element taking the origin to chart points x: (1, w) / sqrt(1 - |w|^2), phi_g = phi."""
    w = _w(x)
    n = np.sqrt(1 - np.abs(w) ** 2)
    return Element(1 / n + 0j, w / n, floats(x)[..., 2].copy())


def point(g):
    """g(origin) as a chart point: (beta / conj(alpha), phi_g)."""
    return _chart(g.beta / np.conj(g.alpha), g.phi)


def _sinhc(s):
    """sinh(s) / s for complex s, 1 at s = 0 (the quotient is accurate elsewhere)."""
    zero = s == 0
    return np.where(zero, 1.0, np.sinh(s) / np.where(zero, 1.0, s))


def flow_from_origin(b, t):
    """Element g(t) and body velocity b(t) at arclength t along the geodesic from the origin with
    unit body velocity b = (a cos a0, a sin a0, c). With q = (a^2 - c^2) t^2 / 4, C = cosh sqrt q and
    S = (t/2) sinh(sqrt q) / sqrt q (entire in q: one formula whether a is above, at or below |c|):
        alpha = e^{ict} (C - i c S), beta = S a e^{i(a0 - ct)}, phi = 2 Arg(alpha) unwrapped,
    b(t) = (a e^{i(a0 - 2ct)}, c)."""
    b, t = floats(b), floats(t)
    shape = np.broadcast_shapes(b.shape[:-1], t.shape)
    b, t = np.broadcast_to(b, shape + (3,)), np.broadcast_to(t, shape)
    horizontal, c = b[..., 0] + 1j * b[..., 1], b[..., 2]
    a2 = np.abs(horizontal) ** 2
    s = np.sqrt((a2 - c * c) * t * t / 4 + 0j)
    C = np.cosh(s).real
    S = 0.5 * t * _sinhc(s).real
    turn = np.exp(1j * c * t)
    alpha = turn * (C - 1j * c * S)
    beta = S * horizontal / turn
    # Arg(alpha) turns monotonically (at rate -c / (2 |alpha|^2) past ct) without bound when a < |c|;
    # sigma = (c - sign(c) sqrt(c^2 - a^2) / 2) t leaves e^{-i sigma} alpha with real part >= 1, so
    # its principal Arg unwraps alpha's
    sigma = (c - 0.5 * np.sign(c) * np.sqrt(c * c - a2 + 0j).real) * t
    phi = 2 * sigma + 2 * np.angle(alpha * np.exp(-1j * sigma))
    out = horizontal / turn**2
    return Element(alpha, beta, phi), np.stack([out.real, out.imag, c], -1)


def flow(g, b, t):
    """The state (element, body velocity) at arclength t from the state (g, b): g g_b(t), b(t)."""
    h, out = flow_from_origin(b, t)
    return multiply(g, h), out


def body_to_chart(b):
    """Chart vectors at the origin of body vectors (orthonormal there: g(0) = diag(4, 4, 1))."""
    b = floats(b)
    return np.stack([b[..., 0] / 2, b[..., 1] / 2, b[..., 2]], -1)


def chart_to_body(u):
    u = floats(u)
    return np.stack([2 * u[..., 0], 2 * u[..., 1], u[..., 2]], -1)


# --- the model SU(1,1) in R^4 -------------------------------------------------------------------------
def _pair(X):
    """(alpha, beta) of model vectors (..., 4)."""
    X = floats(X)
    return X[..., 0] + 1j * X[..., 1], X[..., 2] + 1j * X[..., 3]


def _model(alpha, beta):
    return np.stack([alpha.real, alpha.imag, beta.real, beta.imag], -1)


def _quadric(X):
    """|alpha|^2 - |beta|^2 (1 on the model's points)."""
    alpha, beta = _pair(X)
    return np.abs(alpha) ** 2 - np.abs(beta) ** 2


def _body(X, V):
    """Body velocity (..., 3) of the model tangent V at X: the left-trivialised xi = X^-1 V in
    su(1,1), whose entries (i c / 2, (b1 + i b2) / 2) give b = (b1, b2, c)."""
    alpha, beta = _pair(X)
    va, vb = _pair(V)
    q = _quadric(X)
    xi11 = (np.conj(alpha) * va - beta * np.conj(vb)) / q
    xi12 = (np.conj(alpha) * vb - beta * np.conj(va)) / q
    return np.stack([2 * xi12.real, 2 * xi12.imag, 2 * xi11.imag], -1)


def _from_body(X, b):
    """The model tangent at X of body velocity b: X xi."""
    alpha, beta = _pair(X)
    b = floats(b)
    horizontal, c = 0.5 * (b[..., 0] + 1j * b[..., 1]), 0.5j * b[..., 2]
    return _model(alpha * c + beta * np.conj(horizontal), alpha * horizontal - beta * c)


def _times(X, h):
    """The model points X h (right multiplication by the SU(1,1) part of the element h)."""
    alpha, beta = _pair(X)
    return _model(alpha * h.alpha + beta * np.conj(h.beta), alpha * h.beta + beta * np.conj(h.alpha))


def _klein(w):
    return 2 * w / (1 + np.abs(w) ** 2)


def _poincare(k):
    return k / (1 + np.sqrt(np.maximum(1 - np.abs(k) ** 2, 0.0)))


def _hyperboloid(w):
    """The hyperboloid points (X1, X2, X0) of Poincare points w."""
    q = 1 - np.abs(w) ** 2
    return np.stack([2 * w.real / q, 2 * w.imag / q, (2 - q) / q], -1)


def decompose(M):
    """(alpha, beta, s) with M = (left multiplication by (alpha, beta)) (fibre translation by s),
    (alpha, beta) up to a common sign and s in (-pi, pi]: M's images of (1, 0) and of (0, 1), which
    are (alpha e^{is/2}, beta e^{-is/2}) and (beta e^{is/2}, alpha e^{-is/2}) (linear extension)."""
    M = np.asarray(M, float)
    p, q = M[0, 0] + 1j * M[1, 0], M[2, 0] + 1j * M[3, 0]
    q2 = M[2, 2] + 1j * M[3, 2]
    s = float(np.angle(p * np.conj(q2)))
    half = np.exp(0.5j * s)
    return p / half, q * half, s


def matrix(alpha, beta, s=0.0):
    """The model matrix of left multiplication by (alpha, beta) in SU(1,1) composed with the fibre
    translation by s (right multiplication by diag(e^{is/2}, e^{-is/2}); the two commute)."""
    half = np.exp(0.5j * s)
    columns = []
    for a, b in ((1, 0), (1j, 0), (0, 1), (0, 1j)):
        # (a, b) is the first row of [[a, b], [conj b, conj a]]: h (a, b) then the translation
        image_a = (alpha * a + beta * np.conj(b)) * half
        image_b = (alpha * b + beta * np.conj(a)) / half
        columns.append([image_a.real, image_a.imag, image_b.real, image_b.imag])
    return np.array(columns).T


def lorentz(alpha, beta):
    """The SO+(2,1) matrix on hyperboloid points (X1, X2, X0) of the Mobius map of (alpha, beta),
    from three points and their images."""
    w = np.array([0.0, 0.5, 0.5j])
    image = (alpha * w + beta) / (np.conj(beta) * w + np.conj(alpha))
    return np.linalg.solve(_hyperboloid(w), _hyperboloid(image)).T


def _disk_distance(w, v):
    """The H^2 distance between Poincare points w and v: 2 atanh |(v - w) / (1 - conj(w) v)|."""
    return 2 * np.arctanh(np.minimum(np.abs((v - w) / (1 - np.conj(w) * v)), 1 - 1e-16))


class SL2(SharedGeometry):
    name = "SL2"
    projective = False
    diameter = math.inf
    # 1.5 times the circumradius, which is H^2's (farthest_distance: the octagon's, 2.45): 3.7, past
    # the pi a point may lie from its light's fibre copies; the copies within R grow like e^R, each
    # reached along one geodesic below 2 pi (sl2.hpp's connections)
    light_reach_circumradii = 1.5
    copy_rings = 1  # hyperbolic rings of copies grow too fast for more
    chord_scale = 4.0  # its chords stray far less than K h^2 / 8 (docs/front.md, "The chord rule")
    # far in the cover the model's SU(1,1) entries grow like e^(t/2), half H3's rate (cosh of half
    # the horizontal distance), so its words agree to H3's accuracy at twice H3's depth
    reference_depth = 2 * Hyperbolic.reference_depth
    # the volume density in (Klein(w), phi) peaks at the octagon's vertices, as H2xR's
    volume_order = 32

    @cached_property
    def face_shape(self):
        """Face planes are planes of (Klein(w), phi): curved in the Poincare chart."""
        return faces.PlanesOfChart(self)

    # --- charts -------------------------------------------------------------------------------
    def in_chart(self, x):
        """Finite points over the open unit disk."""
        x = np.asarray(x, float)
        return np.all(np.isfinite(x), axis=-1) & (np.sum(x[..., :2] ** 2, axis=-1) < 1.0)

    def to_model(self, x):
        w, phi = _w(x), floats(x)[..., 2]
        half = np.exp(0.5j * phi) / np.sqrt(1 - np.abs(w) ** 2)
        return _model(half, w * np.conj(half))

    def to_chart(self, X):
        alpha, beta = _pair(X)
        return _chart(beta / np.conj(alpha), 2 * np.angle(alpha))

    def tangent_to_model(self, x, u):
        x, u = np.broadcast_arrays(floats(x), floats(u))
        w, dw, dphi = _w(x), _w(u), u[..., 2]
        alpha, beta = _pair(self.to_model(x))
        radial = np.real(np.conj(w) * dw) / (1 - np.abs(w) ** 2)  # d(-log sqrt(1 - |w|^2))
        return _model(alpha * (radial + 0.5j * dphi), beta * (radial - 0.5j * dphi) + dw * np.conj(alpha))

    def tangent_to_chart(self, X, V):
        alpha, beta = _pair(X)
        da, db = _pair(V)
        a = np.conj(alpha)
        return _chart(db / a - beta * np.conj(da) / a**2, 2 * np.imag(da / alpha))

    def normalize_point(self, X):
        X = floats(X)
        return X / np.sqrt(_quadric(X))[..., None]

    def normalize_tangent(self, X, V):
        """V made tangent at X (the trace of X^-1 V removed) and of unit length."""
        X, V = np.broadcast_arrays(floats(X), floats(V))
        alpha, beta = _pair(X)
        va, vb = _pair(V)
        trace = np.real(np.conj(alpha) * va - beta * np.conj(vb)) / _quadric(X)
        V = V - trace[..., None] * X
        return V / np.sqrt(self.dot(X, V, V))[..., None]

    def mesh_to_chart(self, Y):
        """phi on the branch of the first vertex's: a copy that the cut phi = 2 pi of to_chart
        crosses stays whole (beyond the domain's lids) instead of spanning the chart."""
        x = self.to_chart(Y)
        if len(x):
            x[:, 2] += 4 * np.pi * np.round((x[0, 2] - x[:, 2]) / (4 * np.pi))
        return x

    def charted(self, Y):
        """Every model vector on the quadric's inside (|alpha| > |beta|) is a chart point."""
        return _quadric(Y) > 0

    def plane_coordinates(self, X):
        """(Klein(w), phi, 1): the octagon's sides are chords of the Klein disk, the lids phi = c."""
        x = self.to_chart(X)
        k = _klein(_w(x))
        return np.stack([k.real, k.imag, x[..., 2], np.ones_like(k.real)], -1)

    def from_plane_chart(self, y):
        y = floats(y)
        return _chart(_poincare(y[..., 0] + 1j * y[..., 1]), y[..., 2])

    def plane_chart_density(self, y):
        """The volume density in (Klein(w), phi): lam^2 |det dw/dk| = (1 - |k|^2)^(-3/2), the Klein
        disk's area density times the unit-speed fibre."""
        y = np.asarray(y, float)
        return (1.0 - np.sum(y[..., :2] ** 2, axis=-1)) ** -1.5

    # --- metric ---------------------------------------------------------------------------------
    def metric(self, x):
        """lam^2 on the disk plus the square of the connection form dphi + lam (x dy - y dx)."""
        x = floats(x)
        lam = 2 / (1 - x[..., 0] ** 2 - x[..., 1] ** 2)
        form = np.stack([-lam * x[..., 1], lam * x[..., 0], np.ones_like(lam)], -1)
        disk = np.zeros(x.shape[:-1] + (3, 3), dtype=x.dtype)
        disk[..., 0, 0] = disk[..., 1, 1] = lam * lam
        return disk + form[..., :, None] * form[..., None, :]

    def christoffel(self, x):
        """[..., k, i, j] = Gamma^k_ij, with q = 1 - |w|^2 (derived symbolically from the metric)."""
        x = floats(x)
        X, Y = x[..., 0], x[..., 1]
        q = 1 - X * X - Y * Y
        G = np.zeros(x.shape[:-1] + (3, 3, 3), dtype=x.dtype)
        G[..., 0, 0, 0] = 2 * X / q
        G[..., 0, 0, 1] = G[..., 0, 1, 0] = 3 * Y / q
        G[..., 0, 1, 1] = -4 * X / q
        G[..., 0, 1, 2] = G[..., 0, 2, 1] = -0.5
        G[..., 1, 0, 0] = -4 * Y / q
        G[..., 1, 0, 1] = G[..., 1, 1, 0] = 3 * X / q
        G[..., 1, 1, 1] = 2 * Y / q
        G[..., 1, 0, 2] = G[..., 1, 2, 0] = 0.5
        G[..., 2, 0, 0] = 8 * X * Y / q**2
        G[..., 2, 0, 1] = G[..., 2, 1, 0] = 4 * (Y * Y - X * X) / q**2
        G[..., 2, 1, 1] = -8 * X * Y / q**2
        G[..., 2, 0, 2] = G[..., 2, 2, 0] = -X / q
        G[..., 2, 1, 2] = G[..., 2, 2, 1] = -Y / q
        return G

    def dot(self, X, A, B):
        """The metric on model tangents: the body velocities' Euclidean product (left invariance)."""
        return np.sum(_body(X, A) * _body(X, B), axis=-1)

    # --- geodesics --------------------------------------------------------------------------------
    def chart_geodesic(self, x, u, t):
        """Chart position and velocity at arclength t from chart point x with unit chart velocity u,
        by elements of the universal cover (phi continuous, not read back modulo 4 pi)."""
        g = from_origin(x)
        g_t, b_t = flow(g, chart_to_body(act_tangent(inverse(g), x, u)), t)
        p = point(g_t)
        return p, act_tangent(g_t, np.zeros_like(p), body_to_chart(b_t))

    def geodesic(self, P, V, t):
        """Model position and unit velocity at arclength t from P with unit tangent V: P h(t) for the
        geodesic h from the origin with P's body velocity (the closed form of flow_from_origin)."""
        P, V, t = floats(P), floats(V), floats(t)
        h, b = flow_from_origin(_body(P, V), t)
        X = _times(P, h)
        return X, _from_body(X, b)

    def volume_density(self, x):
        """sqrt(det g) = lam^2 (the connection form adds a unit fibre)."""
        x = np.asarray(x, float)
        return 4.0 / (1.0 - np.sum(x[..., :2] ** 2, axis=-1)) ** 2

    def falloff_along(self, P, V, r):
        """1 / (r^2 |det d exp_P(r V)|) in orthonormal frames at both ends, by central differences of
        the closed form from the origin in the body frame (left invariance: at P as at the origin);
        sqrt det g at the end turns the chart's volume into the orthonormal frame's."""
        P, V, r = floats(P), floats(V), floats(r)
        b = _body(P, V)
        step = 1e-6

        def end(w):
            n = np.linalg.norm(w, axis=-1)
            return point(flow_from_origin(w / n[..., None], n)[0])

        w = r[..., None] * b
        J = np.stack([(end(w + step * e) - end(w - step * e)) / (2 * step) for e in np.eye(3)], -1)
        return 1.0 / (r * r * np.abs(np.linalg.det(J)) * self.volume_density(end(w)))

    # --- bounds of distances, for the light's copies -----------------------------------------------
    # The projection (w, phi) -> w to H^2 shortens every curve, and the group's copies of the domain
    # project to the octagon tiling: render.cover_copies' walk, which needs a lower bound of the
    # distance to the domain (domain_distance) and the largest distance from the light to it
    # (farthest_distance), works in that projection as it does in H2xR's disk, taking both in H^2;
    # the copies along each fibre (two in the model, which is SL2~ modulo the fibre translation by
    # 4 pi) it passes through its lids' element.
    def distance_bound(self, A, B):
        """The length of a curve from A to B: the horizontal geodesic over the H^2 geodesic (along
        which phi, seen from A moved to the origin, stays 0), then the fibre by the fibre angle left
        (modulo 4 pi, into [-2 pi, 2 pi])."""
        a, b = self.to_chart(A), self.to_chart(B)
        w, v = _w(a), _w(b)
        turn = b[..., 2] - a[..., 2] - 2 * np.angle(1 - np.conj(w) * v)
        return _disk_distance(w, v) + np.abs(np.remainder(turn + 2 * np.pi, 4 * np.pi) - 2 * np.pi)

    def farthest_distance(self, X, domain):
        """The largest H^2 distance from X's point of the disk to the octagon's (at a vertex)."""
        return float(np.max(_disk_distance(_w(self.to_chart(X)), _w(domain.vertices))))

    def domain_distance(self, X, domain):
        """The H^2 distance from model points' disk points to the octagon (a lower bound of the
        distance to the domain)."""
        C = domain.covectors()
        vertical = C[:, 2] == 0  # the octagon's sides (the others are the lids)
        ends = [_klein(_w(domain.vertices[f.vertices])) for f, v in zip(domain.faces, vertical) if v]
        return polygon_distance(
            _hyperboloid(_w(self.to_chart(X))),
            C[vertical][:, [0, 1, 3]],
            [np.stack([k.real, k.imag], -1) for k in ends],
        )

    # --- isometries -------------------------------------------------------------------------------
    def is_isometry(self, M, tol=1e-9):
        """Whether M is left multiplication by an element of SU(1,1) composed with a fibre
        translation: rebuilt from its decomposition, it is M again."""
        M = np.asarray(M, float)
        if M.shape != (4, 4) or not np.all(np.isfinite(M)):
            return False
        alpha, beta, s = decompose(M)
        unit = abs(abs(alpha) ** 2 - abs(beta) ** 2 - 1) <= tol * abs(alpha) ** 2
        return bool(unit and np.allclose(matrix(alpha, beta, s), M, rtol=0.0, atol=tol * max(1.0, np.abs(M).max())))

    def reorthonormalize(self, M):
        """The exact isometry nearest M: its SU(1,1) part scaled back onto the quadric."""
        alpha, beta, s = decompose(M)
        n = math.sqrt(abs(alpha) ** 2 - abs(beta) ** 2)
        return matrix(alpha / n, beta / n, s)

    def element_key(self, M):
        """M's images of (1, 0) and (0, 1) determine it (decompose)."""
        M = np.asarray(M, float)
        return tuple(np.round(M[:, [0, 2]].ravel(), 7))

    def fibre_shift(self, M):
        """s in (-2 pi, 2 pi] where M is the fibre translation by s (mod 4 pi), else None."""
        alpha, beta, s = decompose(M)
        if abs(beta) > 1e-9 * abs(alpha) or abs(abs(alpha) - 1) > 1e-9:
            return None
        return float(2 * np.angle(alpha * np.exp(0.5j * s)))

    def generator_problem(self, M):
        """Why the model cannot take M as a generator, or None. A fibre translation T_tau must
        have tau = 4 pi / n, n >= 2: the octagon's lifted relator is T_-4pi, so T_4pi is in the
        group, and with T_tau it generates T_gcd(tau, 4 pi), which would not be the file's space
        for any other tau; n = 1 (T_4pi itself) is the identity of this model."""
        shift = self.fibre_shift(M)
        if shift is None:
            return None
        if abs(shift) < 1e-9:
            return (
                "is the identity of this model: a fibre translation by a multiple of 4 pi (SL(2,R) identifies "
                "phi with phi + 4 pi); the fibre period tau must be 4 pi / n with n >= 2"
            )
        n = 4 * math.pi / abs(shift)
        if abs(n - round(n)) > 1e-9 * n:
            return (
                f"translates the fibre by {abs(shift):.9g}, which is not 4 pi / n for an integer n: the lifted relator "
                "of the octagon group is the fibre translation by -4 pi, so only tau = 4 pi / n give a manifold"
            )
        return None

    def pull_back_plane(self, c, M):
        """Octagon sides (c[2] = 0: chords of the Klein disk, covectors of (X1, X2, X0)) pull back
        by the Lorentz matrix of M's disk part; lids (phi = const) by a fibre translation only."""
        c = np.asarray(c, float)
        if c[2] == 0.0:
            alpha, beta, _ = decompose(M)
            out = np.zeros(4)
            out[[0, 1, 3]] = c[[0, 1, 3]] @ lorentz(alpha, beta)
            return out
        shift = self.fibre_shift(M)
        if shift is None or c[0] != 0.0 or c[1] != 0.0:
            raise ValueError(f"the plane {c.tolist()} is not mapped onto a plane by an isometry that moves the disk")
        return c + np.array([0.0, 0.0, 0.0, c[2] * shift])
