"""The surface tests' textured quad (test_surfaces.py, test_denoise.py): a quad at x = 0.2 facing a
camera at the torus's origin, triangle 0 with a 4x4 texture, triangle 1 a plain colour with an
emission; and the points at its texel centres (a texel centre samples the texel itself)."""

from __future__ import annotations

import numpy as np

from thurston_addon.scenes import Material, SceneObject


def textured_quad():
    """(the quad, its texels (4, 4, 3) linear, the plain material of triangle 1)."""
    texels = np.random.default_rng(3).uniform(0.1, 1.0, (4, 4, 3)).astype(np.float32)
    V = [[0.2, -0.1, -0.1], [0.2, 0.1, -0.1], [0.2, 0.1, 0.1], [0.2, -0.1, 0.1]]
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    T = np.array([[0, 1, 2], [0, 2, 3]])
    plain = Material([0.2, 0.5, 0.9], [0.05, 0.0, 0.0])
    quad = SceneObject(
        "quad",
        V,
        T,
        corner_uvs=uv[T],
        triangle_material=[0, 1],
        materials=[Material([1, 1, 1], [0, 0, 0], texels), plain],
    )
    return quad, texels, plain


def texel_centres():
    """(chart points (N, 3) on the quad at its texel centres off the diagonal between the triangles,
    which is ambiguous; their texels' rows and columns; whether each lies on triangle 0)."""
    rows, cols = np.meshgrid(np.arange(4), np.arange(4), indexing="ij")
    u, v = (cols + 0.5) / 4, 1 - (rows + 0.5) / 4  # row 0 is the top (v = 1)
    off = u != v
    targets = np.stack([np.full(off.sum(), 0.2), -0.1 + 0.2 * u[off], -0.1 + 0.2 * v[off]], axis=1)
    return targets, rows[off], cols[off], (u > v)[off]
