"""Nil: the Heisenberg group R^3 with product (x, y, z)(x', y', z') = (x + x', y + y', z + z' + x y')
and the left-invariant metric dx^2 + dy^2 + (dz - x dy)^2 (the paper's coordinates).

Left multiplications are the isometries used; geodesics have a closed form from the origin,
written here in a form that stays accurate as the vertical component w of the velocity goes to 0.
"""
from __future__ import annotations

import math

import numpy as np

from .affine import AffineGeometry, affine_matrix
from .base import _floats

# |theta| below which F(theta) = (theta - sin theta) / theta^2 is summed as a series: the direct
# formula loses digits to cancellation up to theta ~ 1, and 9 terms reach 1e-17 there.
SERIES_BELOW = 1.0
SERIES_TERMS = 9


def sin_over(u):
    """sin(u) / u, 1 at u = 0 (the quotient is accurate everywhere else: sin is relatively exact)."""
    zero = u == 0
    return np.where(zero, 1.0, np.sin(u) / np.where(zero, 1.0, u))


def theta_minus_sin_over_square(theta):
    """F(theta) = (theta - sin theta) / theta^2 = sum_k>=1 (-1)^(k+1) theta^(2k-1) / (2k+1)!."""
    small = np.abs(theta) < SERIES_BELOW
    s = np.where(small, theta, 0.0)
    # Horner in theta^2 from the highest term down
    series = np.zeros_like(s)
    for k in range(SERIES_TERMS, 0, -1):
        series = 1.0 / math.factorial(2 * k + 1) - s * s * series
    safe = np.where(small, 1.0, theta)
    return np.where(small, s * series, (safe - np.sin(safe)) / (safe * safe))


def multiply(p, q):
    """Group product p . q of chart points (..., 3)."""
    p, q = np.broadcast_arrays(_floats(p), _floats(q))
    return np.stack([p[..., 0] + q[..., 0], p[..., 1] + q[..., 1],
                     p[..., 2] + q[..., 2] + p[..., 0] * q[..., 1]], axis=-1)


def inverse(p):
    """Group inverse of chart points: (-x, -y, -z + x y)."""
    p = _floats(p)
    return np.stack([-p[..., 0], -p[..., 1], -p[..., 2] + p[..., 0] * p[..., 1]], axis=-1)


class Nil(AffineGeometry):
    name = "Nil"
    kernel = "nil"

    def metric(self, x):
        x = _floats(x)
        a = x[..., 0]
        one, zero = np.ones_like(a), np.zeros_like(a)
        return np.stack([np.stack([one, zero, zero], -1),
                         np.stack([zero, 1.0 + a * a, -a], -1),
                         np.stack([zero, -a, one], -1)], -2)

    def christoffel(self, x):
        x = _floats(x)
        a = x[..., 0]
        G = np.zeros(x.shape[:-1] + (3, 3, 3), dtype=x.dtype)
        G[..., 0, 1, 1] = -a
        G[..., 0, 1, 2] = G[..., 0, 2, 1] = 0.5
        G[..., 1, 0, 1] = G[..., 1, 1, 0] = 0.5 * a
        G[..., 1, 0, 2] = G[..., 1, 2, 0] = -0.5
        G[..., 2, 0, 1] = G[..., 2, 1, 0] = 0.5 * (a * a - 1.0)
        G[..., 2, 0, 2] = G[..., 2, 2, 0] = -0.5 * a
        return G

    # --- isometries -------------------------------------------------------------------------------
    def left_multiplication(self, p):
        """Matrices (..., 4, 4) of q -> p . q: (x, y, z) -> (x + a, y + b, z + c + a y)."""
        p = _floats(p)
        linear = np.broadcast_to(np.eye(3, dtype=p.dtype), p.shape[:-1] + (3, 3)).copy()
        linear[..., 2, 1] = p[..., 0]
        return affine_matrix(linear, p)

    def from_origin(self, x):
        return self.left_multiplication(x)

    def to_origin(self, x):
        return self.left_multiplication(inverse(x))

    def reorthonormalize(self, M, tol=1e-6):
        """The left multiplication rebuilt from M's translation column (a, b, c), when M is one
        up to tol (relative to max(1, |M|)); any other M (e.g. the isometry (-x, -y, z), which is
        not a left multiplication) is returned unchanged."""
        M = np.asarray(M, float)
        L = self.left_multiplication(M[:3, 3])
        if np.abs(M - L).max() <= tol * max(1.0, np.abs(M).max()):
            return L
        return M

    # --- geodesics --------------------------------------------------------------------------------
    def flow_from_origin(self, v, t):
        """Closed form from the origin with unit velocity v = (c cos a, c sin a, w): the horizontal
        velocity turns at rate w, and (theta = w t, S = sin u / u, F = (theta - sin theta) / theta^2)
            x + i y = c t e^{i(a + theta/2)} S(theta/2),
            z = w t + (c^2 t^2 / 2) [F(theta) + S(theta/2)^2 sin(theta + 2a) / 2],
        which has no division by w (the paper's form cancels catastrophically for small w t).
        c cos a, c sin a enter directly, so no angle is computed."""
        v, t = _floats(v), _floats(t)
        vx, vy, w = v[..., 0], v[..., 1], v[..., 2]
        theta = w * t
        cos, sin = np.cos(theta), np.sin(theta)
        half_cos, half_sin = np.cos(theta / 2), np.sin(theta / 2)
        St = t * sin_over(theta / 2)
        x = St * (vx * half_cos - vy * half_sin)
        y = St * (vy * half_cos + vx * half_sin)
        c2 = vx * vx + vy * vy
        c2_sin = sin * (vx * vx - vy * vy) + 2.0 * cos * vx * vy  # c^2 sin(theta + 2a)
        z = w * t + 0.5 * t * t * (c2 * theta_minus_sin_over_square(theta) + 0.5 * sin_over(theta / 2) ** 2 * c2_sin)
        ux = vx * cos - vy * sin
        uy = vy * cos + vx * sin
        # w = z' - x y' is the conserved vertical component
        return np.stack([x, y, z], -1), np.stack([ux, uy, w + x * uy], -1)
