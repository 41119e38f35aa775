"""Independent truth shared by the tests: the chart metrics written from the textbook formulas,
not taken from the library."""
import numpy as np

AMBIENT = {"E3": np.diag([1.0, 1.0, 1.0, 0.0]), "S3": np.eye(4), "H3": np.diag([1.0, 1.0, 1.0, -1.0])}


def chart_metric(name, x):
    x = np.asarray(x, float)
    r2 = x @ x
    if name == "E3":
        return np.eye(3)
    if name == "S3":
        return np.eye(3) / (1 + r2) - np.outer(x, x) / (1 + r2) ** 2
    if name == "H3":
        return np.eye(3) / (1 - r2) + np.outer(x, x) / (1 - r2) ** 2
    raise ValueError(name)


def nil_metric(x):
    """Nil: dx^2 + dy^2 + (dz - x dy)^2, the square of the 1-form dz - x dy = (0, -x, 1) added."""
    form = np.array([0.0, -x[0], 1.0])
    return np.diag([1.0, 1.0, 0.0]) + np.outer(form, form)


def sol_metric(x):
    """Sol: e^{2z} dx^2 + e^{-2z} dy^2 + dz^2."""
    return np.diag([np.exp(2 * x[2]), np.exp(-2 * x[2]), 1.0])


CURVED_METRICS = {"Nil": nil_metric, "Sol": sol_metric}


def h2xr_metric(x):
    """H2xR: the Klein disk's (dx^2 + dy^2) / (1 - r^2) + (x dx + y dy)^2 / (1 - r^2)^2, plus dz^2."""
    p = np.array([x[0], x[1], 0.0])
    q = 1.0 - p @ p
    return np.diag([1.0 / q, 1.0 / q, 1.0]) + np.outer(p, p) / q**2


def s2xr_metric(x):
    """S2xR: |dx|^2 / |x|^2 on R^3 minus the origin (x = e^w u: dw^2 + the unit sphere's metric)."""
    return np.eye(3) / (np.asarray(x, float) @ x)
