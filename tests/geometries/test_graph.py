"""The graph of Gaussians (geometries/graph.py, src/core/graph.hpp) against independent truth: its
metric written here from f's derivatives summed image by image (no factorisation by axes), the
Christoffel symbols from that metric's derivatives by the textbook formula (not the module's
Gamma = d_k f d_i d_j f / (1 + |grad f|^2)), DOP853 of the geodesic equation they give; f = 0 is
E3; a round bump's rotational symmetry; the periodic validation of the space files."""

from __future__ import annotations

import itertools
import tomllib

import numpy as np
import pytest
import thurston_core
from support.truth import christoffel_from, dop853

from thurston_addon import geometries, spaces
from thurston_addon.geometries.graph import Bump, Graph

PRESETS = ["graph_flat", "graph_local", "graph_global", "graph_two"]


def derivatives(bumps, period, x):
    """grad f and Hess f at x, each image's Gaussian differentiated by hand and summed over the
    images within 12 widths (more than the module's cutoff of 9 needs)."""
    grad, hess = np.zeros(3), np.zeros((3, 3))
    for b in bumps:
        w2 = np.asarray(b.width) ** 2
        shifts = np.zeros((1, 3))
        if period is not None:
            n = int(np.ceil(12 * max(b.width) / min(period))) + 1
            shifts = np.array(list(itertools.product(range(-n, n + 1), repeat=3))) * period
        y = x - np.asarray(b.centre) - shifts
        G = b.height * np.exp(-0.5 * np.sum(y * y / w2, axis=1))
        grad -= np.einsum("n,ni->i", G, y / w2)
        hess += np.einsum("n,ni,nj->ij", G, y / w2, y / w2) - G.sum() * np.diag(1 / w2)
    return grad, hess


def reference_christoffel(g):
    """Gamma from g_ij = delta_ij + f_i f_j and d_l g_ij = f_li f_j + f_i f_lj (the metric's own
    derivatives) by christoffel_from's textbook formula."""

    def christoffel(x):
        f1, f2 = derivatives(g.bumps, g.period, x)
        metric = np.eye(3) + np.outer(f1, f1)
        dg = np.einsum("li,j->lij", f2, f1) + np.einsum("i,lj->lij", f1, f2)
        return christoffel_from(metric, dg)

    return christoffel


def unit(g, x, u):
    return u / np.sqrt(u @ g.metric(x) @ u)


@pytest.fixture(scope="module")
def loaded():
    return {name: spaces.load(name) for name in PRESETS}


@pytest.mark.parametrize("name", PRESETS[1:])
def test_metric_and_christoffel_against_the_derivatives_summed_image_by_image(loaded, name):
    g = loaded[name].geometry
    rng = np.random.default_rng(7)
    for x in rng.uniform(-1, 1, (5, 3)):
        f1, _ = derivatives(g.bumps, g.period, x)
        np.testing.assert_allclose(g.metric(x), np.eye(3) + np.outer(f1, f1), rtol=0, atol=1e-14)
        np.testing.assert_allclose(g.christoffel(x), reference_christoffel(g)(x), rtol=0, atol=1e-13)


@pytest.mark.parametrize("name", PRESETS[1:])
def test_geodesics_against_dop853_of_the_metric(loaded, name):
    """Python's reference and the core's flow against DOP853 of the reference equation, over
    lengths that cross bumps and faces of the cell."""
    g = loaded[name].geometry
    rng = np.random.default_rng(11)
    x = rng.uniform(-1, 1, (3, 3))
    u = np.array([unit(g, p, d) for p, d in zip(x, rng.normal(size=(3, 3)))])
    t = np.array([0.7, 1.5, 2.5])
    xc, vc = thurston_core.geodesic_flow("graph", x, u, t, parameters=list(g.kernel_parameters))
    for i in range(3):
        x_ref, v_ref = dop853(reference_christoffel(g), x[i], u[i], t[i])
        xp, vp = g.chart_geodesic(x[i], u[i], t[i])
        np.testing.assert_allclose(xp, x_ref, rtol=0, atol=1e-9)
        np.testing.assert_allclose(vp, v_ref, rtol=0, atol=1e-9)
        np.testing.assert_allclose(xc[i], x_ref, rtol=0, atol=1e-9)
        np.testing.assert_allclose(vc[i], v_ref, rtol=0, atol=1e-9)


def test_a_rays_dense_path_against_dop853_of_the_metric(loaded):
    """geodesic_path (one dense solution, the benchmark's reference) at several arclengths, against
    DOP853 of the reference equation run to each of them."""
    g = loaded["graph_two"].geometry
    x, d = np.array([0.1, -0.5, 0.05]), np.array([0.2, 1.0, -0.1])
    P = g.to_model(x)
    V = g.normalize_tangent(P, g.tangent_to_model(x, d))
    t = np.array([0.3, 1.2, 2.9])
    got = g.to_chart(g.geodesic_path(P, V, 3.0)(t))
    for k in range(3):
        np.testing.assert_allclose(
            got[k], dop853(reference_christoffel(g), x, unit(g, x, d), t[k])[0], rtol=0, atol=1e-9
        )


def test_f_zero_is_euclidean(loaded):
    """With no bumps the metric is I, geodesics are chart lines (Python and core)."""
    g = loaded["graph_flat"].geometry
    rng = np.random.default_rng(3)
    x, u = rng.uniform(-1, 1, (8, 3)), rng.normal(size=(8, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    t = rng.uniform(0.5, 5.0, 8)
    np.testing.assert_array_equal(g.metric(x), np.broadcast_to(np.eye(3), (8, 3, 3)))
    xc, vc = thurston_core.geodesic_flow("graph", x, u, t, parameters=list(g.kernel_parameters))
    np.testing.assert_allclose(xc, x + t[:, None] * u, rtol=0, atol=1e-13)
    np.testing.assert_allclose(vc, u, rtol=0, atol=1e-15)


def test_a_round_bumps_rotational_symmetry():
    """Rays from a point on an axis through a round bump's centre, at equal angles about it, end
    at points that the rotations about the axis map onto each other (core and Python)."""
    g = Graph([Bump((0.0, 0.0, 0.0), 0.6, (0.4, 0.4, 0.4))])
    start = np.array([0.0, 0.0, -1.5])
    k = 6
    phi = 2 * np.pi * np.arange(k) / k
    tilt = 0.3
    d = np.stack([np.sin(tilt) * np.cos(phi), np.sin(tilt) * np.sin(phi), np.full(k, np.cos(tilt))], -1)
    u = np.array([unit(g, start, v) for v in d])
    x = np.broadcast_to(start, (k, 3)).copy()
    xc, _ = thurston_core.geodesic_flow("graph", x, u, np.full(k, 3.0), parameters=list(g.kernel_parameters))
    xp, _ = g.chart_geodesic(x, u, np.full(k, 3.0))
    for ends in (xc, xp):
        back = np.stack(
            [
                np.cos(-phi) * ends[:, 0] - np.sin(-phi) * ends[:, 1],
                np.sin(-phi) * ends[:, 0] + np.cos(-phi) * ends[:, 1],
                ends[:, 2],
            ],
            -1,
        )
        np.testing.assert_allclose(back, np.broadcast_to(back[0], back.shape), rtol=0, atol=1e-10)
    # the bump bends the rays: the ends are not those of chart lines
    assert np.abs(xc[0] - (start + 3.0 * d[0])).max() > 1e-2


def test_the_periodic_sum_is_invariant_and_its_truncation_below_rounding(loaded):
    """f(x + L e_i) = f(x), and the module's truncated image sum equals a sum over far more images."""
    g = loaded["graph_global"].geometry  # the widest bump: the most images
    x = np.random.default_rng(5).uniform(-3, 3, (20, 3))
    for e in np.eye(3):
        np.testing.assert_allclose(g.height(x + 2.0 * e), g.height(x), rtol=0, atol=1e-14)
    b = g.bumps[0]
    w2 = np.asarray(b.width) ** 2
    many = [np.array(n) * g.period for n in itertools.product(range(-9, 10), repeat=3)]
    for p in x[:4]:
        brute = sum(b.height * np.exp(-0.5 * np.sum((p - np.asarray(b.centre) - s) ** 2 / w2)) for s in many)
        assert g.height(p) == pytest.approx(brute, abs=1e-15)


def test_the_space_files_are_validated():
    """A generator off the period's lattice, a slope with a period, a bad width: one clear error."""
    data = tomllib.loads(spaces.preset_path("graph_local").read_text())
    shifted = {**data, "generator": [dict(g) for g in data["generator"]]}
    shifted["generator"][0] = {
        **shifted["generator"][0],
        "matrix": [[1, 0, 0, 2.5], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
    }
    shifted["generator"][0]["face"] = [1, 0, 0, -1.25]
    # (the metric's isometry test at points about the bumps catches it first)
    with pytest.raises(spaces.SpaceError, match="not an isometry of graph|not invariant under generator 0"):
        spaces.from_data(shifted, "shifted.toml")
    with pytest.raises(spaces.SpaceError, match="slope must be 0 with a period"):
        spaces.from_data({**data, "graph": {**data["graph"], "slope": [0.1, 0, 0]}}, "sloped.toml")
    bad = {**data["graph"], "bump": [{"centre": [0, 0, 0], "height": 1.0, "width": [0.2, 0, 0.2]}]}
    with pytest.raises(spaces.SpaceError, match=r"bump\[0\].width must be positive"):
        spaces.from_data({**data, "graph": bad}, "flat_bump.toml")
    with pytest.raises(spaces.SpaceError, match="unknown keys"):
        spaces.from_data({**data, "graph": {**data["graph"], "bumps": []}}, "typo.toml")


def test_an_open_space_file_is_validated():
    """R^3 (no generators): its cube holds the region and everything the rays reach, the bumps'
    images lie beyond IMAGE_CUTOFF widths of it; a slope, a period, a bad region, a camera outside
    the region, a region in a closed space: one clear error each."""
    data = tomllib.loads(spaces.preset_path("graph_r3").read_text())
    space = spaces.load("graph_r3")
    g = space.geometry
    reach = 3 + space.max_distance
    assert space.half >= reach + 9 * 0.3 and np.allclose(g.period, 2 * space.half)
    assert space.max_reach == space.max_distance and space.generators
    x = np.random.default_rng(5).uniform(-reach, reach, (200, 3))  # f there: the bump alone, no image
    (b,) = g.bumps
    alone = b.height * np.exp(-0.5 * np.sum((x - np.asarray(b.centre)) ** 2 / np.asarray(b.width) ** 2, axis=1))
    np.testing.assert_allclose(g.height(x), alone, rtol=0, atol=1e-17)
    for change, words in [
        ({"graph": {**data["graph"], "slope": [0.1, 0, 0]}}, "slope is not supported in R"),
        ({"graph": {**data["graph"], "period": [2, 2, 2]}}, "give the lattice's generators"),
        ({"region": [[0, 0, 0], [1, 1, 0]]}, "has no volume"),
        ({"region": [1, 2, 3]}, "two opposite corners"),
        ({"region": [[-1, -1, -1], [0, 0, 0]]}, "camera position .* lies outside the region"),
    ]:
        with pytest.raises(spaces.SpaceError, match=words):
            spaces.from_data({**data, **change}, "open.toml")
    closed = tomllib.loads(spaces.preset_path("graph_local").read_text())
    with pytest.raises(spaces.SpaceError, match="'region' belongs to an open space"):
        spaces.from_data({**closed, "region": data["region"]}, "closed.toml")


def test_the_registry_holds_the_flat_graph_and_spaces_their_own(loaded):
    assert geometries.get("graph").bumps == ()
    assert len(loaded["graph_two"].geometry.bumps) == 2
    # the kernel refuses parameters that are not a graph's
    with pytest.raises(ValueError, match="parameters are not graph's"):
        thurston_core.geodesic_flow("graph", np.zeros((1, 3)), np.eye(3)[:1].copy(), np.ones(1), parameters=[1.0, 2.0])


def test_a_tall_narrow_bump_and_rays_grazing_it():
    """Height 3, width 0.1 (|grad f| up to 18): rays at impact parameters 0 to 3 widths from its
    centre, through it and grazing it, against DOP853 of the reference equation."""
    g = Graph([Bump((0.0, 0.0, 0.0), 3.0, (0.1, 0.1, 0.1))])
    start = np.array([-0.6, 0.0, 0.0])
    for b in (0.0, 0.05, 0.1, 0.3):
        x = start + [0.0, b, 0.0]
        u = unit(g, x, np.array([1.0, 0.0, 0.02]))
        x_ref, v_ref = dop853(reference_christoffel(g), x, u, 1.2)
        xc, vc = thurston_core.geodesic_flow(
            "graph", x[None], u[None], np.array([1.2]), parameters=list(g.kernel_parameters)
        )
        np.testing.assert_allclose(xc[0], x_ref, rtol=0, atol=1e-8)
        np.testing.assert_allclose(vc[0], v_ref, rtol=0, atol=1e-8)


def test_a_thousand_periods_keep_the_speed():
    """graph_two's flow over 2000 (about 1000 periods of the lattice): finite, and of unit speed in
    the metric to 1e-8 (the geodesic flow conserves it; the integrator does not impose it)."""
    g = spaces.load("graph_two").geometry
    x = np.array([[0.1, 0.2, 0.3], [-0.5, 0.4, 0.0]])
    u = np.array([unit(g, p, d) for p, d in zip(x, [[1.0, 0.3, 0.1], [0.2, 1.0, -0.4]])])
    xt, vt = thurston_core.geodesic_flow("graph", x, u, np.full(2, 2000.0), 1e-10, parameters=list(g.kernel_parameters))
    assert np.all(np.isfinite(xt)) and np.all(np.linalg.norm(xt - x, axis=1) > 100)
    speed = np.einsum("ni,nij,nj->n", vt, g.metric(xt), vt)
    np.testing.assert_allclose(speed, 1.0, rtol=0, atol=1e-8)
