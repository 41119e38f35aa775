"""Nil: the Heisenberg group R^3 with product (x, y, z)(x', y', z') = (x + x', y + y', z + z' + x y')
and the left-invariant metric dx^2 + dy^2 + (dz - x dy)^2 (the paper's coordinates).

Left multiplications are the isometries used; geodesics have a closed form from the origin,
written here in a form that stays accurate as the vertical component w of the velocity goes to 0.
"""

from __future__ import annotations

import math

import numpy as np

from .affine import AffineGeometry, affine_matrix
from .shared import floats

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


def shortest_for_height(lift):
    """A lower bound of the length of any curve whose end lies |Z_s| = lift above its start in the
    symmetric model z_s = z - x y / 2 (seen from the start): dz_s = w dt + (x dy - y dx) / 2, so
    lift <= L + L^2 / pi (the vertical part at most L, the area the shadow encloses with the chord
    at most L^2 / pi, isoperimetric): L >= (pi / 2)(sqrt(1 + 4 lift / pi) - 1)."""
    return 0.5 * math.pi * (np.sqrt(1.0 + 4.0 * np.asarray(lift, float) / math.pi) - 1.0)


def _box_corners(domain):
    """The 8 corners (8, 3) of the chart box around a domain's vertices."""
    lo, hi = domain.vertices.min(axis=0), domain.vertices.max(axis=0)
    return np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for c in (lo[2], hi[2])])


def _seen_from(a, q):
    """(rho, h): the horizontal distance and the symmetric height of q seen from a (a^-1 q in the
    symmetric model), chart points broadcasting: h = q_z - a_z - (q_y - a_y)(q_x + a_x) / 2."""
    a, q = floats(a), floats(q)
    rho = np.hypot(q[..., 0] - a[..., 0], q[..., 1] - a[..., 1])
    return rho, q[..., 2] - a[..., 2] - 0.5 * (q[..., 1] - a[..., 1]) * (q[..., 0] + a[..., 0])


def multiply(p, q):
    """Group product p . q of chart points (..., 3)."""
    p, q = np.broadcast_arrays(floats(p), floats(q))
    return np.stack(
        [p[..., 0] + q[..., 0], p[..., 1] + q[..., 1], p[..., 2] + q[..., 2] + p[..., 0] * q[..., 1]], axis=-1
    )


def inverse(p):
    """Group inverse of chart points: (-x, -y, -z + x y)."""
    p = floats(p)
    return np.stack([-p[..., 0], -p[..., 1], -p[..., 2] + p[..., 0] * p[..., 1]], axis=-1)


class Nil(AffineGeometry):
    name = "Nil"
    # the circumradius bound (farthest_distance: 1.33 for the unit cube, whose corners lie 0.94 from
    # its centre), as the copies within R grow like R^4; below 2 pi each copy is reached along one
    # geodesic, the shortest (nil.hpp's connections)
    light_reach_circumradii = 1.0

    def metric(self, x):
        x = floats(x)
        a = x[..., 0]
        one, zero = np.ones_like(a), np.zeros_like(a)
        return np.stack(
            [np.stack([one, zero, zero], -1), np.stack([zero, 1.0 + a * a, -a], -1), np.stack([zero, -a, one], -1)], -2
        )

    def christoffel(self, x):
        x = floats(x)
        a = x[..., 0]
        G = np.zeros(x.shape[:-1] + (3, 3, 3), dtype=x.dtype)
        G[..., 0, 1, 1] = -a
        G[..., 0, 1, 2] = G[..., 0, 2, 1] = 0.5
        G[..., 1, 0, 1] = G[..., 1, 1, 0] = 0.5 * a
        G[..., 1, 0, 2] = G[..., 1, 2, 0] = -0.5
        G[..., 2, 0, 1] = G[..., 2, 1, 0] = 0.5 * (a * a - 1.0)
        G[..., 2, 0, 2] = G[..., 2, 2, 0] = -0.5 * a
        return G

    # --- bounds of distances, for the light's copies -----------------------------------------------
    def distance_bound(self, A, B):
        """The length of a curve from A to B: the straight horizontal geodesic of the symmetric
        model seen from A (length rho), then the vertical one (|Z_s|)."""
        rho, h = _seen_from(self.to_chart(A), self.to_chart(B))
        return rho + np.abs(h)

    def farthest_distance(self, X, domain):
        """An upper bound of the distance from X to the domain's points: distance_bound's rho and
        |Z_s| each at their largest over the box around the domain, which they reach at its corners
        (rho is convex, Z_s bilinear in the corner's x and y and linear in its z)."""
        rho, h = _seen_from(self.to_chart(X), _box_corners(domain))
        return float(np.max(rho) + np.max(np.abs(h)))

    def domain_distance(self, X, domain):
        """A lower bound of the distances from model points X (..., 4) to the domain: the larger of
        the horizontal distance to the box around it (the projection to the xy plane shortens no
        curve less) and shortest_for_height of the smallest |Z_s| of X seen from the box's points
        (Z_s bilinear in their x and y, linear in z: its range is its corners')."""
        x = self.to_chart(X)
        corners = _box_corners(domain)
        lo, hi = corners[0], corners[-1]
        outside = np.maximum(np.maximum(lo[:2] - x[..., :2], x[..., :2] - hi[:2]), 0.0)
        _, h = _seen_from(corners, x[..., None, :])  # (..., 8): X seen from each corner
        low, high = np.min(h, axis=-1), np.max(h, axis=-1)
        lift = np.where((low <= 0) & (high >= 0), 0.0, np.minimum(np.abs(low), np.abs(high)))
        return np.maximum(np.linalg.norm(outside, axis=-1), shortest_for_height(lift))

    # --- isometries -------------------------------------------------------------------------------
    def left_multiplication(self, p):
        """Matrices (..., 4, 4) of q -> p . q: (x, y, z) -> (x + a, y + b, z + c + a y)."""
        p = floats(p)
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
        v, t = floats(v), floats(t)
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
