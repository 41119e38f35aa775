"""SL2~: the universal cover of SL(2,R), in the model D x R of chart points (x, y, phi): w = x + iy in
the Poincare disk, phi the angle of a unit tangent vector of H^2 lifted to R, with the lifted Sasaki
metric of T^1 H^2 (one metric of SL2~'s one-parameter family; 3DS's, HyperRogue's at stretch 0 with
lengths halved)
    g = lam^2 (dx^2 + dy^2) + (dphi + lam (x dy - y dx))^2,   lam = 2 / (1 - |w|^2).
Fibres are unit-speed geodesics and phi -> phi + 2 pi is the centre.

The isometries used are not linear on 4-vectors: an element (alpha, beta, phi_g), (alpha, beta) in
SU(1,1), acts by
    (w, phi) -> ((alpha w + beta) / (conj(beta) w + conj(alpha)), phi + phi_g - 2 Arg(1 + zeta w)),
zeta = conj(beta) / conj(alpha), Arg principal (1 + zeta w has positive real part on D, so this is
continuous); phi_g = -2 Arg(conj(alpha)) + 2 pi k are the lifts of SU(1,1), other phi_g add the fibre
translations. Geodesics are states (element g, body velocity b): the point g(origin) with velocity
g's differential of b, b orthonormal at the origin (where g = diag(4, 4, 1)); the closed form from
the origin composes on the left.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .base import Geometry, _floats


class Element(NamedTuple):
    """Isometries (w, phi) -> (...) of the module docstring; arrays of one leading shape."""
    alpha: np.ndarray  # complex
    beta: np.ndarray  # complex
    phi: np.ndarray  # real


def _w(x):
    x = _floats(x)
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
    s = _floats(s)
    return Element(np.ones_like(s) + 0j, np.zeros_like(s) + 0j, s)


def act(g, x):
    """g applied to chart points x (..., 3)."""
    w = _w(x)
    image = (g.alpha * w + g.beta) / (np.conj(g.beta) * w + np.conj(g.alpha))
    return _chart(image, _floats(x)[..., 2] + g.phi - 2 * np.angle(1 + _zeta(g) * w))


def act_tangent(g, x, u):
    """g's differential at chart points x on chart vectors u: dw -> dw / (conj(beta) w + conj(alpha))^2
    (|alpha|^2 - |beta|^2 = 1), dphi -> dphi - 2 Im(zeta dw / (1 + zeta w))."""
    w, dw = _w(x), _w(u)
    zeta = _zeta(g)
    image = dw / (np.conj(g.beta) * w + np.conj(g.alpha)) ** 2
    return _chart(image, _floats(u)[..., 2] - 2 * np.imag(zeta * dw / (1 + zeta * w)))


def from_origin(x):
    """The element taking the origin to chart points x: (1, w) / sqrt(1 - |w|^2), phi_g = phi."""
    w = _w(x)
    n = np.sqrt(1 - np.abs(w) ** 2)
    return Element(1 / n + 0j, w / n, _floats(x)[..., 2].copy())


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
    b, t = _floats(b), _floats(t)
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


def body_to_chart(b):
    """Chart vectors at the origin of body vectors (orthonormal there: g(0) = diag(4, 4, 1))."""
    b = _floats(b)
    return np.stack([b[..., 0] / 2, b[..., 1] / 2, b[..., 2]], -1)


def chart_to_body(u):
    u = _floats(u)
    return np.stack([2 * u[..., 0], 2 * u[..., 1], u[..., 2]], -1)


class SL2(Geometry):
    name = "SL2"
    projective = False
    diameter = np.inf

    def in_chart(self, x):
        """Finite points over the open unit disk."""
        x = np.asarray(x, float)
        return np.all(np.isfinite(x), axis=-1) & (np.sum(x[..., :2] ** 2, axis=-1) < 1.0)

    # --- metric ---------------------------------------------------------------------------------
    def metric(self, x):
        """lam^2 on the disk plus the square of the connection form dphi + lam (x dy - y dx)."""
        x = _floats(x)
        lam = 2 / (1 - x[..., 0] ** 2 - x[..., 1] ** 2)
        form = np.stack([-lam * x[..., 1], lam * x[..., 0], np.ones_like(lam)], -1)
        disk = np.zeros(x.shape[:-1] + (3, 3), dtype=x.dtype)
        disk[..., 0, 0] = disk[..., 1, 1] = lam * lam
        return disk + form[..., :, None] * form[..., None, :]

    def christoffel(self, x):
        """[..., k, i, j] = Gamma^k_ij, with q = 1 - |w|^2 (derived symbolically from the metric)."""
        x = _floats(x)
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

    def dot(self, x, u, v):
        return np.einsum("...i,...ij,...j->...", _floats(u), self.metric(x), _floats(v))

    # --- geodesics --------------------------------------------------------------------------------
    def geodesic(self, g, b, t):
        """The state (element, body velocity) at arclength t from the state (g, b): g g_b(t), b(t)."""
        h, out = flow_from_origin(b, t)
        return multiply(g, h), out

    def chart_geodesic(self, x, u, t):
        """Chart position and velocity at arclength t from chart point x with unit chart velocity u."""
        g = from_origin(x)
        g_t, b_t = self.geodesic(g, chart_to_body(act_tangent(inverse(g), x, u)), t)
        p = point(g_t)
        return p, act_tangent(g_t, np.zeros_like(p), body_to_chart(b_t))
