"""H3: the hyperboloid <X, X> = -1 of R^{3,1} with curvature -1, authored in the Klein chart
x = X[:3] / X[3] (the open unit ball)."""

import numpy as np

from .projective import ProjectiveGeometry


class Hyperbolic(ProjectiveGeometry):
    name = "H3"
    curvature = -1
    form = np.array([1.0, 1.0, 1.0, -1.0])
    copy_rings = 1  # hyperbolic rings of copies grow too fast for more
    light_reach_circumradii = 1.0  # the copies within R grow like exp(2 R)
    # A reference geodesic goes through the universal cover, where points at distance t have
    # coordinates ~e^t and the float64 pairing matrices satisfy the group's relations only to ~1e-16
    # of their size: two words for one element differ there by ~1e-16 e^(2t), which is 1e-10 near
    # t = 5 and 1e-6 at t = 12, far above the tracer's own drift (renormalised at every crossing).
    reference_depth = 5.0

    def cos_sin(self, t):
        return np.cosh(t), np.sinh(t)

    def distance(self, A, B):
        A, B = np.broadcast_arrays(np.asarray(A, float), np.asarray(B, float))
        cosh = -self.inner(A, B)
        # |B - cosh A| is sinh d in the metric: asinh keeps small distances accurate
        D = B - cosh[..., None] * A
        return np.arcsinh(np.sqrt(np.maximum(0.0, self.inner(D, D))))

    def falloff(self, r):
        return 1.0 / np.sinh(np.asarray(r, float)) ** 2
