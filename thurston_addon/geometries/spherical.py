"""S3: the unit sphere of R^4 with curvature +1, authored in the gnomonic chart x = X[:3] / X[3]."""

import numpy as np

from .projective import ProjectiveGeometry


class Spherical(ProjectiveGeometry):
    name = "S3"
    curvature = 1
    form = np.array([1.0, 1.0, 1.0, 1.0])

    def cos_sin(self, t):
        return np.cos(t), np.sin(t)

    def distance(self, A, B):
        # atan2 of |A ^ B| and A.B: accurate for near and nearly antipodal points alike
        A, B = np.broadcast_arrays(np.asarray(A, float), np.asarray(B, float))
        cos = np.einsum("...i,...i->...", A, B)
        sin = np.linalg.norm(B - cos[..., None] * A, axis=-1)
        return np.arctan2(sin, cos)

    def falloff(self, r):
        return 1.0 / np.sin(np.asarray(r, float)) ** 2
