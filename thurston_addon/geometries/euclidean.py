"""E3: Euclidean space, X = (x, 1); isometries are affine maps."""

import numpy as np

from .projective import ProjectiveGeometry
from .shared import floats


class Euclidean(ProjectiveGeometry):
    name = "E3"
    curvature = 0
    affine_isometries = True
    light_reach_circumradii = 2.0  # the domain's diameter at most: a point's own copy and the ring around it
    form = np.array([1.0, 1.0, 1.0, 0.0])

    def cos_sin(self, t):
        t = floats(t)
        return np.ones_like(t), t

    def distance(self, A, B):
        return np.linalg.norm(self.to_chart(A) - self.to_chart(B), axis=-1)

    def falloff(self, r):
        return 1.0 / np.asarray(r, float) ** 2
