"""Frames of tangent vectors, for any geometry of the contract: orthonormalised in the metric, and
carried by parallel transport along geodesics (the transport equation
dW^k/dt = -Gamma^k_ij u^i W^j integrated with the geodesic in the geometry's chart (classical
Runge-Kutta, steps of at most STEP), the end point and velocity then taken from the geometry's own
`geodesic` (closed form or its reference) and the vectors re-orthonormalised there). The camera's
frame is made by `orthonormalize`, the stereo eyes' frames carried from it (render/stereo.py)."""

from __future__ import annotations

import math

import numpy as np

from .base import Geometry

# the largest Runge-Kutta step, in arclength: the local error is O(STEP^5) times the curvature's
# derivatives, below 1e-11 over the interocular distances eyes are offset by
STEP = 0.005


def parallel_transport(g: Geometry, X, V, t: float, vectors):
    """The end point, end velocity and transported vectors of the geodesic from model points X (N, 4)
    with unit tangents V (N, 4) at arclength t (one length for all, >= 0): vectors (N, k, 4) are model
    tangents at X, orthonormal in the metric (a frame), returned orthonormal at the end point."""
    X, V, vectors = (np.asarray(a, float) for a in (X, V, vectors))
    n, k = vectors.shape[:2]
    end, velocity = g.geodesic(X, V, t)
    if t == 0:
        return X, V, vectors.copy()
    x = g.to_chart(X)
    u = g.tangent_to_chart(X, V)
    W = g.tangent_to_chart(np.broadcast_to(X[:, None], (n, k, 4)), vectors)

    def rates(x, u, W):
        G = g.christoffel(x)  # (N, 3, 3, 3): [k, i, j]
        du = -np.einsum("nkij,ni,nj->nk", G, u, u)
        dW = -np.einsum("nkij,ni,nmj->nmk", G, u, W)
        return u, du, dW

    steps = max(2, math.ceil(t / STEP))
    h = t / steps
    for _ in range(steps):
        k1 = rates(x, u, W)
        k2 = rates(*(a + 0.5 * h * d for a, d in zip((x, u, W), k1)))
        k3 = rates(*(a + 0.5 * h * d for a, d in zip((x, u, W), k2)))
        k4 = rates(*(a + h * d for a, d in zip((x, u, W), k3)))
        x, u, W = (a + h / 6 * (d1 + 2 * d2 + 2 * d3 + d4) for a, d1, d2, d3, d4 in zip((x, u, W), k1, k2, k3, k4))
    carried = g.tangent_to_model(np.broadcast_to(x[:, None], (n, k, 3)), W)
    # at the exact end point, which removes the integration's rounding
    return end, velocity, orthonormalize(g, end, carried)


def orthonormalize(g: Geometry, X, vectors):
    """Gram-Schmidt in the metric: model tangent vectors (..., k, 4) at model points X (..., 4) made
    tangent there and orthonormal, in their order."""
    frame = []
    for i in range(vectors.shape[-2]):
        # only directions count: each scaled to at most 1 before the metric squares it (Sol's
        # isometry from |z| = 355 stretches a tangent by e^355, whose square overflows)
        w = _scaled(vectors[..., i, :])
        for b in frame:
            w = w - g.dot(X, w, b)[..., None] * b
        frame.append(g.normalize_tangent(X, _scaled(w)))
    return np.stack(frame, axis=-2)


def _scaled(v):
    return v / np.abs(v).max(axis=-1, keepdims=True)
