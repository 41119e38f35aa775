"""Sol: R^3 with the metric e^{2z} dx^2 + e^{-2z} dy^2 + dz^2 (the paper's; 3DS uses the mirror
z -> -z).

Isometries: (x, y, z) -> (s1 e^{-c} x + a, s2 e^{c} y + b, z + c) with signs s1, s2, and those
composed with the swap (x, y, z) -> (y, x, -z). Along a unit-speed geodesic p_x = e^{2z} x' and
p_y = e^{-2z} y' are constant, so only z needs integrating:
    z'' = p_x^2 e^{-2z} - p_y^2 e^{2z},   x' = p_x e^{-2z},   y' = p_y e^{2z}.
`geodesic` integrates this reduced system with a Taylor series method (p_x, p_y held exactly,
error control from the decay of the series, ~1e-15 relative over lengths 10); `geodesic_elliptic` is the closed form in
Jacobi elliptic functions (Troyanov's; derived for this metric below).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ellipeinc, ellipj, ellipkinc

from .affine import AffineGeometry, affine_matrix
from .shared import floats

# Taylor series method: the series of z(t), z'(t), e^{+-2z(t)} to this order at each step; the step
# is where the last two terms fall below the rounding level (Jorba & Zou's rule), capped so that
# polynomial solutions (the vertical and the horizontal diagonal geodesics) still take steps.
TAYLOR_ORDER = 24
MAX_STEP = 2.0

# The elliptic form degenerates at p_x p_y = 0 (modulus 1: one of x, y becomes a difference of
# nearly equal elliptic integrals) and at |p_x p_y| = 1/2 (modulus 0: the horizontal diagonal
# geodesic, where sn^2 at the start is 0/0); within these margins geodesic_elliptic integrates.
ELLIPTIC_MIN_PRODUCT = 1e-3
ELLIPTIC_MIN_MODULUS_GAP = 1e-4  # on sqrt(1 - 4 (p_x p_y)^2)


def taylor_flow(v, t):
    """Position and velocity (..., 3) at arclength t (...) from the origin with unit velocity v
    (..., 3), each ray stepped on its own (t may be negative)."""
    v, t = floats(v), floats(t)
    dtype = np.result_type(v, t)
    shape = t.shape
    px, py = v[..., 0].astype(dtype).ravel(), v[..., 1].astype(dtype).ravel()
    zeta = v[..., 2].astype(dtype).ravel().copy()
    T = t.astype(dtype).ravel()
    z, x, y, s = (np.zeros(T.size, dtype) for _ in range(4))
    N = TAYLOR_ORDER
    tolerance = np.finfo(dtype).eps
    divisors = np.arange(1, N + 1, dtype=dtype)[:, None]
    valid = np.isfinite(T) & np.isfinite(px) & np.isfinite(py) & np.isfinite(zeta)
    z[~valid] = np.nan
    live = np.flatnonzero(valid & (T != 0))
    while live.size:
        Ez, Uz = np.exp(2 * z[live]), np.exp(-2 * z[live])
        a, b = px[live] ** 2 * Uz, py[live] ** 2 * Ez  # a + b + z'^2 = 1
        # series of z', and of e^{2z}, e^{-2z} divided by their values at the step's start
        Q, E, U = (np.zeros((N + 1, live.size), dtype) for _ in range(3))
        Q[0], E[0], U[0] = zeta[live], 1.0, 1.0
        for k in range(N):
            Q[k + 1] = (a * U[k] - b * E[k]) / (k + 1)
            E[k + 1] = 2.0 * np.einsum("jm,jm->m", Q[: k + 1], E[k::-1]) / (k + 1)
            U[k + 1] = -2.0 * np.einsum("jm,jm->m", Q[: k + 1], U[k::-1]) / (k + 1)
        size = np.maximum(np.maximum(np.abs(Q), np.abs(E)), np.abs(U))
        with np.errstate(divide="ignore"):
            h = np.minimum((tolerance / size[N - 1]) ** (1.0 / (N - 1)), (tolerance / size[N]) ** (1.0 / N))
        stuck = ~(h > 0)  # the series overflowed (a velocity far from unit): give the ray up
        z[live[stuck]] = np.nan
        remaining = T[live] - s[live]
        last = (np.abs(remaining) <= np.minimum(h, MAX_STEP)) | stuck
        h = np.where(last, remaining, np.sign(remaining) * np.minimum(h, MAX_STEP))
        # Horner: z from z', x from p_x e^{-2z}, y from p_y e^{2z} (one order up)
        dz = dx = dy = np.zeros(live.size, dtype)
        dzeta = Q[N]
        for k in range(N - 1, -1, -1):
            dzeta = dzeta * h + Q[k]
            dz = (dz + Q[k] / divisors[k]) * h
            dx = (dx + U[k] / divisors[k]) * h
            dy = (dy + E[k] / divisors[k]) * h
        z[live] += dz
        zeta[live] = dzeta
        x[live] += px[live] * Uz * dx
        y[live] += py[live] * Ez * dy
        s[live] = np.where(last, T[live], s[live] + h)
        live = live[~last]
    lost = np.isnan(z)
    x[lost] = y[lost] = zeta[lost] = np.nan
    velocity = np.stack([px * np.exp(-2 * z), py * np.exp(2 * z), zeta], -1)
    return np.stack([x, y, z], -1).reshape(shape + (3,)), velocity.reshape(shape + (3,))


def elliptic_flow(v, t):
    """Closed form from the origin with unit velocity v = (p_x, p_y, z'(0)). With q = p_x p_y,
    s = sqrt(1 - 4 q^2), e^{2z} oscillates between the roots E_-, E_+ = (1 -+ s) / (2 p_y^2) of
    (e^{2z})'^2 = 4 p_y^2 e^{2z} (E_+ - e^{2z}) (e^{2z} - E_-):
        e^{2z} = E_+ dn^2(u, m),  u = u0 + lam t,  lam = sqrt((1 + s) / 2),  m = 2 s / (1 + s),
        y = (lam / p_y) [eps(u)]_{u0}^{u},   x = (lam / p_x) [eps(u) - m sn(u) cd(u)]_{u0}^{u},
    eps(u) = E(am u, m) the incomplete elliptic integral of the second kind, and u0 the point
    where E_+ dn^2 = 1 with the sign of z'(0). Degenerate at q = 0 and |q| = 1/2: within
    ELLIPTIC_MIN_PRODUCT of the first and ELLIPTIC_MIN_MODULUS_GAP (on s) of the second the
    rays are integrated by taylor_flow instead."""
    v, t = np.broadcast_arrays(np.asarray(v, float), np.asarray(t, float)[..., None])
    t = t[..., 0]
    px, py, zeta0 = v[..., 0], v[..., 1], v[..., 2]
    q = px * py
    s = np.sqrt(np.maximum(0.0, (1.0 - 2.0 * np.abs(q)) * (1.0 + 2.0 * np.abs(q))))
    closed = (np.abs(q) >= ELLIPTIC_MIN_PRODUCT) & (s >= ELLIPTIC_MIN_MODULUS_GAP)
    position, velocity = np.empty(v.shape), np.empty(v.shape)
    if (~closed).any():
        position[~closed], velocity[~closed] = taylor_flow(v[~closed], t[~closed])
    if not closed.any():
        return position, velocity
    px, py, zeta0, q, s, t = (a[closed] for a in (px, py, zeta0, q, s, t))
    m = 2.0 * s / (1.0 + s)
    lam = np.sqrt(0.5 * (1.0 + s))
    E_plus = (1.0 + s) / (2.0 * py * py)
    # sn^2(u0) = (E_+ - 1) / (E_+ - E_-), cn^2(u0) = (1 - E_-) / (E_+ - E_-), E_- = 2 p_x^2 / (1 + s)
    sn2 = np.clip((0.5 * (1.0 + s) - py * py) / s, 0.0, 1.0)
    cn2 = np.clip((py * py - 2.0 * q * q / (1.0 + s)) / s, 0.0, 1.0)
    # z' = -m lam sn cn / dn: sn cn <= 0 (u0 in [-K, 0]) where z'(0) > 0
    u0 = np.where(zeta0 > 0, -1.0, 1.0) * ellipkinc(np.arctan2(np.sqrt(sn2), np.sqrt(cn2)), m)
    sn0, cn0, dn0, am0 = ellipj(u0, m)
    sn, cn, dn, am = ellipj(u0 + lam * t, m)
    eps0, eps = ellipeinc(am0, m), ellipeinc(am, m)
    z = 0.5 * np.log(E_plus) + np.log(dn)
    y = lam / py * (eps - eps0)
    x = lam / px * (eps - eps0 - m * (sn * cn / dn - sn0 * cn0 / dn0))
    exp2z = E_plus * dn * dn
    position[closed] = np.stack([x, y, z], -1)
    velocity[closed] = np.stack([px / exp2z, py * exp2z, -m * lam * sn * cn / dn], -1)
    return position, velocity


def drift(L, Z):
    """How far x can get from 0 along a curve of length L from the origin to height Z: |x'| <= e^{-z}
    and z >= max(-s, Z - (L - s)) at arclength s, so |x| <= int_0^L min(e^s, e^{L - s - Z}) ds
    (y likewise with -Z, as |y'| <= e^z). Increasing in L."""
    L, Z = np.broadcast_arrays(floats(L), floats(Z))
    middle = np.clip(0.5 * (L - Z), 0.0, L)
    return np.expm1(middle) + np.exp(-Z) * np.expm1(L - middle)


def _shortest_for_drift(a, Z, longest=200.0, steps=60):
    """The least L with drift(L, Z) >= a (bisection, elementwise; L <= longest)."""
    a, Z = np.broadcast_arrays(floats(a), floats(Z))
    lo, hi = np.zeros(a.shape), np.full(a.shape, longest)
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        short = drift(mid, Z) < a
        lo, hi = np.where(short, mid, lo), np.where(short, hi, mid)
    return lo


class Sol(AffineGeometry):
    name = "Sol"
    # 3/4 of the circumradius bound (farthest_distance, 1.33 for the preset's prism): 1.0, about the
    # distance from the centre to the prism's corners (0.97), as the copies within R grow like e^R
    # and each is shot at (sol.hpp's connections); below pi sqrt 2 each copy is reached along one
    # geodesic, the shortest
    light_reach_circumradii = 0.75

    def metric(self, x):
        x = floats(x)
        z = x[..., 2]
        G = np.zeros(x.shape[:-1] + (3, 3), dtype=x.dtype)
        G[..., 0, 0] = np.exp(2 * z)
        G[..., 1, 1] = np.exp(-2 * z)
        G[..., 2, 2] = 1.0
        return G

    def christoffel(self, x):
        x = floats(x)
        z = x[..., 2]
        G = np.zeros(x.shape[:-1] + (3, 3, 3), dtype=x.dtype)
        G[..., 0, 0, 2] = G[..., 0, 2, 0] = 1.0
        G[..., 1, 1, 2] = G[..., 1, 2, 1] = -1.0
        G[..., 2, 0, 0] = -np.exp(2 * z)
        G[..., 2, 1, 1] = np.exp(-2 * z)
        return G

    # --- isometries -------------------------------------------------------------------------------
    def translation(self, a, b, c):
        """Matrices of (x, y, z) -> (e^{-c} x + a, e^{c} y + b, z + c) (broadcasting)."""
        a, b, c = np.broadcast_arrays(floats(a), floats(b), floats(c))
        linear = np.zeros(c.shape + (3, 3), dtype=c.dtype)
        linear[..., 0, 0] = np.exp(-c)
        linear[..., 1, 1] = np.exp(c)
        linear[..., 2, 2] = 1.0
        return affine_matrix(linear, np.stack([a, b, c], -1))

    def swap(self):
        """(x, y, z) -> (y, x, -z)."""
        return affine_matrix(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), np.zeros(3))

    def flip(self, x_sign, y_sign):
        """(x, y, z) -> (x_sign x, y_sign y, z) with signs +-1."""
        return affine_matrix(np.diag([float(x_sign), float(y_sign), 1.0]), np.zeros(3))

    def from_origin(self, x):
        x = floats(x)
        return self.translation(x[..., 0], x[..., 1], x[..., 2])

    def to_origin(self, x):
        x = floats(x)
        return self.translation(-np.exp(x[..., 2]) * x[..., 0], -np.exp(-x[..., 2]) * x[..., 1], -x[..., 2])

    def reorthonormalize(self, M):
        """The exact isometry nearest M: translation(a, b, c) @ flip(s1, s2), or that @ swap() when
        M's linear block is anti-diagonal in x, y, rebuilt from the translation column (a, b, c)
        and the signs of the x, y entries."""
        M = np.asarray(M, float)
        A = M[:3, :3]
        swapped = abs(A[0, 1]) + abs(A[1, 0]) > abs(A[0, 0]) + abs(A[1, 1])
        x_entry, y_entry = (A[0, 1], A[1, 0]) if swapped else (A[0, 0], A[1, 1])
        sign = lambda value: -1.0 if value < 0 else 1.0
        R = self.translation(*M[:3, 3]) @ self.flip(sign(x_entry), sign(y_entry))
        return R @ self.swap() if swapped else R

    # --- bounds of distances, for the light's copies -----------------------------------------------
    def _path(self, a, q):
        """The length of the curve from chart point a to q that moves x, then y at a's height, then z."""
        e = np.exp(a[..., 2])
        d = np.abs(q - a)
        return e * d[..., 0] + d[..., 1] / e + d[..., 2]

    def distance_bound(self, A, B):
        """The length of a curve from A to B: x and y moved at A's height or at B's, then z (the shorter)."""
        a, b = self.to_chart(A), self.to_chart(B)
        return np.minimum(self._path(a, b), self._path(b, a))

    def farthest_distance(self, X, domain):
        """An upper bound of the distance from X to the domain's points: the curve of distance_bound
        moving at X's height, whose length is convex in the far end, so largest at a vertex."""
        return float(np.max(self._path(self.to_chart(X), domain.vertices)))

    def domain_distance(self, X, domain):
        """A lower bound of the distances from model points X (..., 4) to the domain, from the box
        [lo, hi] around it: a curve from a point q of the box to X is at least as long as z moves
        (|z'| <= 1), and as it takes to move x: z(s) >= lo_z - s and z(s) >= z_X - (L - s), so
        |x_X - x_q| <= e^{-lo_z} drift(L, z_X - lo_z); y likewise with e^{z} and hi_z."""
        x = self.to_chart(X)
        lo, hi = domain.vertices.min(axis=0), domain.vertices.max(axis=0)
        outside = np.maximum(np.maximum(lo - x, x - hi), 0.0)
        along_x = _shortest_for_drift(outside[..., 0] * math.exp(lo[2]), x[..., 2] - lo[2])
        along_y = _shortest_for_drift(outside[..., 1] * math.exp(-hi[2]), hi[2] - x[..., 2])
        return np.maximum(outside[..., 2], np.maximum(along_x, along_y))

    # --- geodesics --------------------------------------------------------------------------------
    def flow_from_origin(self, v, t):
        return taylor_flow(v, t)

    def geodesic_elliptic(self, P, V, t):
        """geodesic() by the elliptic closed form (elliptic_flow), float64; rays with
        |p_x p_y| < ELLIPTIC_MIN_PRODUCT or sqrt(1 - 4 (p_x p_y)^2) < ELLIPTIC_MIN_MODULUS_GAP
        (p = the velocity in the orthonormal frame at P) fall back to the integrator."""
        return self._geodesic(P, V, t, elliptic_flow)
