"""The geometry contract (geometries/base.py), checked for every geometry of the registry: the
Christoffel symbols against numerical derivatives of the metric, geodesics against DOP853 of the
geodesic equation, the isometries (the generators of the presets of each geometry) pulling the metric
back onto itself, the C++ flow against the Python one, and the C++ and Python registries naming the
same geometries. A test-only geometry, registered here, fulfils the contract and renders through the
whole pipeline (space -> scene -> render) with no product file changed.
"""

from __future__ import annotations

import tomllib
from functools import cache

import numpy as np
import pytest
from support.truth import christoffel_from, dop853

from thurston_addon import geometries, render, scenes, spaces
from thurston_addon.geometries.euclidean import Euclidean

NAMES = list(geometries.GEOMETRIES)


@cache
def presets_of(name: str) -> tuple:
    """The built-in presets of the geometry `name`."""
    found = (spaces.load(s) for s in spaces.preset_ids() if spaces.preset_path(s).parent == spaces.PRESET_DIR)
    return tuple(space for space in found if space.geometry.name == name)


def interior_points(space, rng, n):
    """n chart points inside the space's domain (rejection from the box around its vertices)."""
    g = space.geometry
    lo, hi = space.domain.vertices.min(axis=0), space.domain.vertices.max(axis=0)
    out = np.zeros((0, 3))
    while len(out) < n:
        x = rng.uniform(lo, hi, (8 * n, 3))
        x = x[g.in_chart(x)]
        out = np.vstack([out, x[space.domain.contains(g.to_model(x), tol=-1e-3)]])
    return out[:n]


def unit(g, x, u):
    """The chart vector u at x scaled to unit length in the geometry's metric."""
    return u / np.sqrt(u @ g.metric(x) @ u)


def metric_derivative(g, x, h=1e-5):
    """dg[l, i, j] = d g_ij / d x_l by central differences."""
    return np.stack([(g.metric(x + e) - g.metric(x - e)) / (2 * h) for e in h * np.eye(3)])


def point_jacobian(f, x, h=1e-6):
    return np.stack([(f(x + e) - f(x - e)) / (2 * h) for e in h * np.eye(3)], axis=-1)


# --- the checks, for a geometry and a space of it ---------------------------------------------------


def check_christoffel(g, space, rng):
    """Gamma^k_ij = 1/2 g^kl (d_i g_lj + d_j g_li - d_l g_ij) from the metric's numerical derivatives."""
    for x in interior_points(space, rng, 6):
        want = christoffel_from(g.metric(x), metric_derivative(g, x))
        np.testing.assert_allclose(g.christoffel(x), want, rtol=0, atol=1e-7 * max(1.0, np.abs(want).max()))


def check_geodesics(g, space, rng):
    """chart_geodesic against DOP853 of x'' = -Gamma(x)(x', x') (the symbols check_christoffel tests)."""
    for x in interior_points(space, rng, 4):
        u = unit(g, x, rng.normal(size=3))
        for t in (0.3, 1.0):
            x_ref, v_ref = dop853(g.christoffel, x, u, t)
            xt, vt = g.chart_geodesic(x, u, t)
            np.testing.assert_allclose(xt, x_ref, rtol=1e-8, atol=1e-8)
            np.testing.assert_allclose(vt, v_ref, rtol=1e-8, atol=1e-8)
            assert float(vt @ g.metric(xt) @ vt) == pytest.approx(1.0, abs=1e-9)


def check_isometries(g, space, rng):
    """Each generator M and its inverse is an isometry of the model and pulls the chart metric back
    onto itself: D^T g(M x) D = g(x), D the Jacobian of x -> M x in the chart."""
    x = interior_points(space, rng, 4)
    for M in space.generators:
        for N in (M, np.linalg.inv(M)):
            assert g.is_isometry(g.reorthonormalize(N))
            for p in x:
                y = g.transform_points(N, p)
                assert g.in_chart(y)
                D = point_jacobian(lambda q: g.transform_points(N, q), p)
                want = g.metric(p)
                np.testing.assert_allclose(D.T @ g.metric(y) @ D, want, rtol=0, atol=1e-6 * np.abs(want).max())


def check_core_flow(g, space, rng):
    """The core's kernel traces the geometry's geodesics: a marching kernel's flow equals the Python
    one; where geodesics are chart lines (projective) the core has no flow, and the Python
    geodesics are chart lines."""
    import thurston_core

    x = interior_points(space, rng, 16)
    u = np.array([unit(g, p, d) for p, d in zip(x, rng.normal(size=(16, 3)))])
    t = rng.uniform(0.2, 1.2, 16)
    if g.projective:
        with pytest.raises(ValueError, match="no marching flow"):
            thurston_core.geodesic_flow(g.kernel, x, u, t)
        xt, _ = g.chart_geodesic(x, u, t)
        x_half, _ = g.chart_geodesic(x, u, t / 2)
        # the midpoint in arclength lies on the chart segment from x to the end
        along = np.cross(x_half - x, xt - x)
        assert np.all(np.linalg.norm(along, axis=1) <= 1e-12 * (1 + np.linalg.norm(xt - x, axis=1) ** 2))
        return
    parameters = list(getattr(g, "kernel_parameters", []))  # (graph's bumps)
    xc, vc = thurston_core.geodesic_flow(
        g.kernel, np.ascontiguousarray(x), np.ascontiguousarray(u), t, parameters=parameters
    )
    xp, vp = g.chart_geodesic(x, u, t)
    np.testing.assert_allclose(xc, xp, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(vc, vp, rtol=1e-9, atol=1e-9)


CHECKS = [check_christoffel, check_geodesics, check_isometries, check_core_flow]


# --- every geometry of the registry -------------------------------------------------------------------


@pytest.mark.parametrize("check", CHECKS, ids=lambda c: c.__name__)
@pytest.mark.parametrize("name", NAMES)
def test_contract(name, check):
    assert presets_of(name), f"{name} has no preset to take a domain and isometries from"
    for k, space in enumerate(presets_of(name)):
        # the space's own geometry: graph's is made from its file's bumps (the registry's is flat)
        check(space.geometry, space, np.random.default_rng(1800 + 10 * NAMES.index(name) + k))


@pytest.mark.parametrize("name", NAMES)
def test_every_geometry_implements_the_contract(name):
    g = geometries.get(name)
    assert isinstance(g, geometries.Geometry) and g.name == name
    abstract = geometries.Geometry.__abstractmethods__
    assert abstract and all(getattr(g, member, None) is not None for member in abstract)
    assert isinstance(g.face_shape, geometries.faces.FaceShape)


def test_the_core_and_python_registries_name_the_same_geometries():
    """Every Python geometry is served by a kernel of the core, and every kernel of the core by a
    Python geometry of its name."""
    import thurston_core

    core = set(thurston_core.KERNELS)
    assert {g.kernel for g in geometries.GEOMETRIES.values()} == core
    assert set(geometries.GEOMETRIES) == core


# --- a test-only geometry -------------------------------------------------------------------------------


class RenamedEuclidean(Euclidean):
    """E3 under another name: a geometry only this test registers, which the core's E3 kernel serves."""

    name = "E3 (test)"
    kernel = "E3"


@pytest.fixture
def renamed():
    g = RenamedEuclidean()
    geometries.register(g)
    yield g
    geometries.unregister(g.name)


def renamed_torus(g):
    data = tomllib.loads(spaces.preset_path("torus").read_text())
    return spaces.from_data({**data, "geometry": g.name, "id": "renamed_torus"}, "renamed_torus.toml")


def test_register_and_unregister(renamed):
    assert geometries.get(renamed.name) is renamed
    with pytest.raises(ValueError, match="already registered"):
        geometries.register(RenamedEuclidean())
    with pytest.raises(TypeError, match="contract"):
        geometries.register(object())
    geometries.unregister(renamed.name)
    with pytest.raises(ValueError, match="unknown geometry"):
        geometries.get(renamed.name)
    geometries.register(renamed)  # (for the fixture's unregister)


@pytest.mark.parametrize("check", CHECKS, ids=lambda c: c.__name__)
def test_a_test_geometry_fulfils_the_contract(renamed, check):
    check(renamed, renamed_torus(renamed), np.random.default_rng(1899))


def test_a_test_geometry_renders_through_the_whole_pipeline(renamed):
    """Registered from here, with no product file changed: its space loads and validates, the default
    scene is built in it, and it renders as E3 itself does (the same domain, scene and kernel)."""
    space = renamed_torus(renamed)
    assert space.geometry is renamed and len(space.domain.faces) == 6 and space.volume == pytest.approx(1.0)
    reference = spaces.load("torus")
    settings = render.Settings(width=32, height=24, quality="draft")
    got = render.render(space, scenes.default_scene(space), settings)
    want = render.render(reference, scenes.default_scene(reference), settings)
    assert got.stats["hit_fraction"] > 0.5
    assert got.passes.keys() == want.passes.keys()
    for name, image in want.passes.items():
        np.testing.assert_array_equal(got.passes[name], image, err_msg=name)
