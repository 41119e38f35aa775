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
