"""What Nil and Sol share: R^3 is its own chart, and the isometries used are affine maps of it.

Points are homogeneous 4-vectors X = (x, y, z, 1) ("model" = the chart), tangent vectors are
(vx, vy, vz, 0) in chart components, and an isometry is a 4x4 affine matrix acting linearly on both
(its 3x3 block is the differential). Both metrics are left invariant and equal to the identity at
the origin, so every geodesic is flowed from the origin: a subclass supplies the isometries
`from_origin(x)` (taking the origin to x) and `to_origin(x)` (its inverse), and `flow_from_origin`;
the chart axes at the origin are an orthonormal frame, carried to one at x by `from_origin(x)`.
Everything is numpy and broadcasts over leading axes.
"""

from __future__ import annotations

import math

import numpy as np

from .shared import SharedGeometry, floats

# Fixed points at which is_isometry compares pulled-back metrics (x and z both vary: Nil's metric
# depends on x, Sol's on z).
ISOMETRY_SAMPLE_POINTS = np.array(
    [
        [0.0, 0.0, 0.0],
        [1.0, -0.5, 0.25],
        [-0.75, 1.0, -1.0],
        [0.5, 0.5, 1.0],
        [-1.0, -1.0, 0.5],
    ]
)


def apply(M, X):
    """M @ X over leading axes (M (..., 4, 4), X (..., 4))."""
    return np.einsum("...ij,...j->...i", M, X)


def homogeneous(x, last):
    """Append the homogeneous coordinate `last` (1 for points, 0 for tangent vectors)."""
    x = floats(x)
    return np.concatenate([x, np.full(x.shape[:-1] + (1,), last, dtype=x.dtype)], axis=-1)


def affine_matrix(linear, offset):
    """4x4 affine matrices from 3x3 blocks (..., 3, 3) and translation columns (..., 3)."""
    linear, offset = floats(linear), floats(offset)
    shape = np.broadcast_shapes(linear.shape[:-2], offset.shape[:-1])
    M = np.zeros(shape + (4, 4), dtype=np.result_type(linear, offset))
    M[..., :3, :3] = linear
    M[..., :3, 3] = offset
    M[..., 3, 3] = 1.0
    return M


class AffineGeometry(SharedGeometry):
    """Base class for Nil, Sol and S2xR: subclasses set `name` and implement `metric`,
    `christoffel`, `from_origin`, `to_origin`, `flow_from_origin`, `reorthonormalize`."""

    name: str
    projective = False
    affine_isometries = True
    diameter = math.inf  # R^3: unbounded
    copy_rings = 2  # rings of neighbouring domains searched for the parts of large objects
    reference_depth = math.inf  # `geodesic` is a reference at any depth (closed form, integrator)
    # Newton on the exponential map stops when the residual is below this, relative to 1 + |target|
    connect_tolerance = 1e-13
    newton_halvings = 8
    continuation_stages = 8
    # central-difference step for the Jacobian of the exponential map (tangent space at the origin,
    # where the metric is the identity): balances truncation (h^2) against rounding (eps / h)
    jacobian_step = 1e-5

    def from_origin(self, x):
        """Isometries (..., 4, 4) taking the origin to the chart points x."""
        raise NotImplementedError

    def to_origin(self, x):
        """Isometries (..., 4, 4) taking the chart points x to the origin (inverse of from_origin)."""
        raise NotImplementedError

    def flow_from_origin(self, v, t):
        """Chart position and velocity (..., 3) at arclength t (...) along the geodesic from the
        origin with unit velocity v (..., 3); v, t have the same leading shape."""
        raise NotImplementedError

    # --- charts -------------------------------------------------------------------------------
    def to_chart(self, X):
        X = floats(X)
        return X[..., :3] / X[..., 3:4]

    def to_model(self, x):
        return homogeneous(x, 1.0)

    def in_chart(self, x):
        """Every finite chart point is a point of the geometry."""
        return np.all(np.isfinite(np.asarray(x, float)), axis=-1)

    def tangent_to_model(self, x, u):
        """Model tangent vector of the chart vector u at chart point x (the chart is the model)."""
        x, u = np.broadcast_arrays(floats(x), floats(u))
        return homogeneous(u, 0.0)

    def tangent_to_chart(self, X, V):
        """Chart velocity of a model tangent vector V at X (differential of to_chart)."""
        X, V = floats(X), floats(V)
        return (V[..., :3] - X[..., :3] * (V[..., 3:4] / X[..., 3:4])) / X[..., 3:4]

    def normalize_point(self, X):
        X = floats(X)
        return X / X[..., 3:4]

    def normalize_tangent(self, X, V):
        """V with V[..., 3] = 0, scaled to unit length in the metric at X."""
        X, V = np.broadcast_arrays(floats(X), floats(V))
        V = V.copy()
        V[..., 3] = 0.0
        return V / np.sqrt(self.dot(X, V, V))[..., None]

    # --- metric ---------------------------------------------------------------------------------
    def dot(self, X, A, B):
        """g_X(A, B) for model tangent vectors A, B at model points X."""
        g = self.metric(self.to_chart(X))
        return np.einsum("...i,...ij,...j->...", floats(A)[..., :3], g, floats(B)[..., :3])

    def volume_density(self, x):
        """sqrt(det g) of the chart metric (1 for Nil and Sol; computed, not assumed)."""
        return np.sqrt(np.linalg.det(np.asarray(self.metric(x), float)))

    # --- geodesics --------------------------------------------------------------------------------
    def geodesic(self, P, V, t):
        """Position and unit velocity (model 4-vectors) at arclength t along the geodesic from P
        with unit tangent V; P, V (..., 4) and t (...) broadcast."""
        return self._geodesic(P, V, t, self.flow_from_origin)

    def _geodesic(self, P, V, t, flow):
        """Move P to the origin, flow there with `flow`, move back (errors do not grow with |P|)."""
        P, V, t = floats(P), floats(V), floats(t)
        p = self.to_chart(P)
        shape = np.broadcast_shapes(p.shape[:-1], V.shape[:-1], t.shape)
        v0 = apply(self.to_origin(p), V)[..., :3]
        x0, u0 = flow(np.broadcast_to(v0, shape + (3,)), np.broadcast_to(t, shape))
        back = self.from_origin(p)
        return apply(back, homogeneous(x0, 1.0)), apply(back, homogeneous(u0, 0.0))

    # --- the exponential map at the origin --------------------------------------------------------
    def exp_from_origin(self, w):
        """exp_O(w) in chart coordinates for tangent vectors w (..., 3) at the origin (an
        orthonormal frame there); exp_O(0) = 0."""
        w = floats(w)
        r = np.linalg.norm(w, axis=-1)
        safe = np.where(r > 0, r, 1.0)
        x, _ = self.flow_from_origin(w / safe[..., None], r)
        return np.where((r == 0)[..., None], 0.0, x)

    def exp_jacobian(self, w):
        """d exp_O at w (..., 3, 3), [i, j] = d x_i / d w_j, by central differences (one flow
        call for all six evaluations)."""
        w = floats(w)
        h = self.jacobian_step
        steps = h * np.eye(3, dtype=w.dtype).reshape((3,) + (1,) * (w.ndim - 1) + (3,))
        x = self.exp_from_origin(np.concatenate([w + steps, w - steps]))
        return np.moveaxis((x[:3] - x[3:]) / (2 * h), 0, -1)

    def connect(self, A, B, max_iterations=30):
        """(V, r, ok): unit tangent V at A and length r with geodesic(A, V, r) = B, by damped
        Newton on exp_A from the straight-chart guess (the chart displacement of B seen from A
        moved to the origin); where that fails, by continuation along the straight chart segment
        (Newton for the targets k/8 of the way, each from the previous solution). ok is False
        where neither converged (V, r are NaN there). When A = B, r = 0 and V is the unit vector
        along the frame's first axis (any direction reaches B)."""
        A, B = floats(A), floats(B)
        shape = np.broadcast_shapes(A.shape[:-1], B.shape[:-1])
        a = np.broadcast_to(self.to_chart(A), shape + (3,)).reshape(-1, 3)
        target = self.to_chart(apply(self.to_origin(a), np.broadcast_to(B, shape + (4,)).reshape(-1, 4)))
        w, ok = self._invert_exp_from_origin(target, target.copy(), max_iterations)
        retry = np.flatnonzero(~ok)
        w[retry] = 0.0
        for fraction in np.arange(1, self.continuation_stages + 1) / self.continuation_stages:
            w[retry], ok[retry] = self._invert_exp_from_origin(fraction * target[retry], w[retry], max_iterations)
        r = np.linalg.norm(w, axis=-1)
        direction = np.where((r > 0)[:, None], w / np.where(r > 0, r, 1.0)[:, None], np.eye(3)[0])
        V = apply(self.from_origin(a), homogeneous(direction, 0.0))
        V, r = np.where(ok[:, None], V, np.nan), np.where(ok, r, np.nan)
        return V.reshape(shape + (4,)), r.reshape(shape), ok.reshape(shape)

    def _invert_exp_from_origin(self, target, w, max_iterations):
        """(w, ok) with exp_O(w) = target (n, 3), by Newton from w (updated in place). Each step
        is halved until the residual shrinks (far from the solution exp_O is far from linear and
        full steps overshoot); rows where no halving helps, or where |w| would pass
        3 |target| + 3 (which also bounds the integration work), give up."""
        norm = lambda a: np.linalg.norm(a, axis=-1)
        tolerance = self.connect_tolerance * (1.0 + norm(target))
        longest = 3.0 * norm(target) + 3.0
        residual = self.exp_from_origin(w) - target
        error = norm(residual)
        live = np.flatnonzero(~(error <= tolerance))
        for _ in range(max_iterations):
            if not live.size:
                break
            J = self.exp_jacobian(w[live])
            # a singular or non-finite Jacobian (a conjugate point, NaN input) ends the search there
            solvable = np.all(np.isfinite(J), axis=(-2, -1)) & (np.abs(np.linalg.det(J)) > 0)
            step = np.zeros_like(w)
            step[live[solvable]] = -np.linalg.solve(J[solvable], residual[live[solvable]][..., None])[..., 0]
            live, given_up = live[solvable], live[~solvable]
            pending = live
            for _ in range(self.newton_halvings):
                trial = w[pending] + step[pending]
                reachable = norm(trial) <= longest[pending]
                trial_residual = np.full_like(trial, np.inf)
                trial_residual[reachable] = self.exp_from_origin(trial[reachable]) - target[pending[reachable]]
                trial_error = norm(trial_residual)
                better = trial_error < error[pending]
                done = pending[better]
                w[done], residual[done], error[done] = trial[better], trial_residual[better], trial_error[better]
                pending = pending[~better]
                if not pending.size:
                    break
                step[pending] /= 2
            live = np.setdiff1d(live[~(error[live] <= tolerance[live])], np.concatenate([pending, given_up]))
        return w, error <= tolerance

    def distance(self, A, B):
        """Length r of the geodesic connect finds from A to B (NaN where Newton failed): the
        geodesic reached from the straight-chart guess, which is the shortest one for nearby
        points but not in general (Nil and Sol points are joined by several geodesics)."""
        return self.connect(A, B)[1]

    def falloff_along(self, P, V, r):
        """Falloff of a point light at P seen at distance r along the geodesic (P, V): 1 / J with
        J = r^2 |det d exp_P(r V)| in orthonormal frames at both ends (the area density of the
        geodesic sphere per unit solid angle; the same seen from either end). Both metrics have
        det g = 1, so chart determinants are frame determinants. Tends to 1 / r^2 as r -> 0."""
        P, V, r = floats(P), floats(V), floats(r)
        p = self.to_chart(P)
        v0 = apply(self.to_origin(p), V)[..., :3]
        shape = np.broadcast_shapes(v0.shape[:-1], r.shape)
        w = np.broadcast_to(v0, shape + (3,)) * np.broadcast_to(r, shape)[..., None]
        return 1.0 / (r * r * np.abs(np.linalg.det(self.exp_jacobian(w))))

    # --- isometries -------------------------------------------------------------------------------
    def is_isometry(self, M, tol=1e-9):
        """Whether M is a 4x4 finite affine matrix whose linear part A pulls the metric back onto
        itself, A^T g(M x) A = g(x), at ISOMETRY_SAMPLE_POINTS; each entry is compared relative to
        the size of the terms that enter it (|A|^T |g(M x)| |A| + |g(x)|)."""
        M = np.asarray(M, float)
        if M.shape != (4, 4) or not np.all(np.isfinite(M)):
            return False
        if not np.allclose(M[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=tol):
            return False
        A = M[:3, :3]
        x = ISOMETRY_SAMPLE_POINTS
        # far maps overflow Sol's exponentials: inf and NaN then fail the comparison
        with np.errstate(over="ignore", invalid="ignore"):
            g, g_image = self.metric(x), self.metric(x @ A.T + M[:3, 3])
            pulled = np.einsum("ki,nkl,lj->nij", A, g_image, A)
            scale = np.einsum("ki,nkl,lj->nij", np.abs(A), np.abs(g_image), np.abs(A)) + np.abs(g)
            return bool(np.all(np.abs(pulled - g) <= tol * scale))

    def element_key(self, M):
        """Identifies a group element: its image of the origin and its linear part."""
        return tuple(np.round(np.asarray(M, float)[:3].ravel(), 7))
