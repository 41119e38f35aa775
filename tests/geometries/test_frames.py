"""Parallel transport (geometries/frames.py) against closed forms: in E3, S3 and H3 a vector normal to
the plane of the geodesic (in the model's R^4) is parallel along it, so it stays the same model
vector, and the velocity turns in that plane; in every geometry the carried velocity is the
geodesic's own (its closed form or reference) and the frame stays orthonormal."""

from __future__ import annotations

import numpy as np
import pytest

from thurston_addon import geometries
from thurston_addon.geometries.frames import orthonormalize, parallel_transport


def frame_at(g, x):
    X = g.to_model(np.asarray(x, float)[None])
    return X, orthonormalize(g, X, g.tangent_to_model(np.asarray(x, float)[None, None], np.eye(3)[None]))


@pytest.mark.parametrize("name", list(geometries.GEOMETRIES))
@pytest.mark.parametrize("length", [0.0325, 0.7])
def test_the_carried_velocity_is_the_geodesics_and_the_frame_stays_orthonormal(name, length):
    g = geometries.get(name)
    X, F = frame_at(g, [0.1, 0.05, -0.1])
    V = g.normalize_tangent(X, F[:, 1] + 0.4 * F[:, 2])
    E, velocity, carried = parallel_transport(g, X, V, length, np.stack([V, F[:, 0]], axis=1))
    exact, exact_velocity = g.geodesic(X, V, length)
    assert np.abs(E - exact).max() < 1e-14
    assert np.abs(carried[:, 0] - exact_velocity).max() < 1e-10
    for i in range(2):
        for j in range(2):
            assert abs(g.dot(E, carried[:, i], carried[:, j])[0] - (i == j)) < 1e-12


@pytest.mark.parametrize("name", ["E3", "S3", "H3"])
def test_vectors_normal_to_the_geodesics_plane_stay_the_same_model_vector(name):
    g = geometries.get(name)
    X, F = frame_at(g, [0.2, -0.1, 0.15])
    E, velocity, carried = parallel_transport(g, X, F[:, 1], 1.3, F)
    assert np.abs(carried[:, 0] - F[:, 0]).max() < 1e-10  # forward and up: normal to span(X, V)
    assert np.abs(carried[:, 2] - F[:, 2]).max() < 1e-10
    assert np.abs(carried[:, 1] - velocity).max() < 1e-10
