"""Sampled direct light (--light-paths N) against the exact sum it estimates: the closed-form sums
over a light's copies (the torus's lattice, the Poincare sphere's 120 copies and both arcs), the
white furnace of every geometry (emitters sampled, their geodesics chosen), and the Poincare
space's default scene, where copies are shadowed: the sampled estimate's mean is the exact sum's
within its measured standard error, with the walks it was given."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from support.furnace import LE, furnace_tracer, mean_and_error, random_rays
from support.lit_ball import GLOW, RHO, ball_scene
from support.presets import simplest_per_geometry

from thurston_addon import cli, render, spaces
from thurston_addon.scenes import default_scene


def repeated_ray(space, scene, origin, target, light_reach, n):
    """The tracer and n copies of the ray from origin to target (each its own random numbers)."""
    g = space.geometry
    tracer = render.make_tracer(space, scene, threads=2, light_reach=light_reach)
    o, d = np.array([origin], float), np.array([target], float) - np.array([origin], float)
    P = g.to_model(o)
    D = g.normalize_tangent(P, g.tangent_to_model(o, d))
    return tracer, np.ascontiguousarray(np.repeat(P, n, axis=0)), np.ascontiguousarray(np.repeat(D, n, axis=0))


def sampled_against(total, out, budget):
    """The sampled colours' mean against GLOW + RHO * total within four standard errors (and float32's
    rounding: where nothing shadows, the strengths the geodesics are chosen by are their light, and
    the estimate has no variance); the walks as many as the budget."""
    mean, error = mean_and_error(out["color"][:, 0])
    truth = GLOW + RHO * total
    print(f"mean {mean:.6f} truth {truth:.6f} ({mean / truth - 1:+.1e}), standard error {error / truth:.1e}")
    assert abs(mean - truth) < 4 * error + 1e-4 * truth  # test_light holds the exact sum to 1e-4
    assert int(out["shadow_walks"]) == budget * len(out["color"])


@pytest.mark.parametrize("budget", [1, 4])
def test_sampled_light_in_the_torus_converges_to_the_lattice_sum(budget):
    """E3: the exact value sum_k max(0, cos theta_k) p / r_k^2 over the lattice copies within the
    reach (test_light's closed form), estimated from `budget` of its 20-odd facing geodesics."""
    space = spaces.load("torus")
    light, power, reach = np.array([-0.2, 0.1, 0.3]), 0.7, 2.5
    scene = ball_scene([0.1, 0.2, -0.15], light, power)
    tracer, P, D = repeated_ray(space, scene, [0.1, -0.2, -0.15], [0.1, 0.2, -0.15], reach, 4000)
    out = tracer.trace(P, D, 2.0, 20, shade=True, light_budget=budget, seed=5)
    assert np.all(out["stop"] == 0)
    g = space.geometry
    x, n = out["position"][0], out["normal"][0].astype(float)
    total = 0.0
    for k in itertools.product(range(-4, 5), repeat=3):
        v = light + np.array(k) - x
        r = np.linalg.norm(v)
        if r <= reach and n @ v > 0:
            total += (n @ v / r) * power / r**2
    assert g.name == "E3"
    sampled_against(total, out, budget)


def test_sampled_light_in_the_poincare_sphere_converges_to_the_sum_over_both_arcs():
    """S3: the exact value sums |N . u_k| p / sin^2 d_k over the 120 copies (test_light's closed form,
    both arcs), estimated from 6 geodesics of the 120 that arrive at the point's front."""
    space = spaces.load("poincare")
    g = space.geometry
    light, power = np.array([0.08, -0.05, 0.12]), 0.3
    scene = ball_scene([0.0, 0.15, 0.0], light, power)
    tracer, P, D = repeated_ray(space, scene, [0.0, -0.1, 0.0], [0.0, 0.15, 0.0], None, 4000)
    out = tracer.trace(P, D, 2.0, 20, shade=True, light_budget=6, seed=7)
    x, n = out["position"][:1], out["normal"][:1].astype(float)
    H = g.normalize_point(g.to_model(x))[0]
    N = g.normalize_tangent(H[None], g.tangent_to_model(x, n))[0]
    L = g.normalize_point(g.to_model(light[None]))[0]
    total = 0.0
    for M in space.elements_within(math.pi + 1e-6):
        Y = M @ L
        d = math.acos(np.clip(H @ Y, -1, 1))
        u = Y - (H @ Y) * H
        u /= np.linalg.norm(u)
        total += abs(N @ u) * power / math.sin(d) ** 2
    assert int(out["light_paths"]) == 120 * 4000
    sampled_against(total, out, 6)


@pytest.mark.parametrize("space_id", simplest_per_geometry())
def test_white_furnace_with_sampled_light(space_id):
    """The furnace of test_gi (truth Le (1 + rho + rho^2 + rho^3), two bounces) with the emitters'
    geodesics chosen two at a time: every geometry's copies of the sampled points weighed right."""
    space = spaces.load(space_id)
    rho, bounces = 0.5, 2
    tracer, centre = furnace_tracer(space, rho)
    P, D = random_rays(space, centre, 2000, seed=1)
    out = tracer.trace(
        P, D, 5.0, 40, shade=True, tolerance=1e-6, light_samples=2, seed=13, bounces=bounces, light_budget=2
    )
    assert np.all(out["stop"] == 0)
    mean, error = mean_and_error(out["color"][:, 0])
    truth = LE * sum(rho**k for k in range(bounces + 2))
    print(
        f"{space_id}: mean {mean:.5f} truth {truth:.5f} ({mean / truth - 1:+.1e}), standard error {error / truth:.1e}"
    )
    assert 4 * error < LE * rho ** (bounces + 1)
    assert abs(mean - truth) < 4 * error
    assert int(out["shadow_walks"]) <= 2 * int(out["emitter_paths"])


def test_sampled_light_of_a_shadowed_scene_has_the_exact_images_mean():
    """The Poincare space's default scene (copies of its objects shadow many copies of the lamp):
    16 samples per pixel with 4 walks per shaded point, against the exact sum at the same sample
    positions (which differ only by the light's estimate): the difference per pixel is noise, its
    mean over the image zero within four standard errors, and the render says how it estimated."""
    space = spaces.load("poincare")
    scene = default_scene(space)
    common = dict(width=32, height=18, quality="draft", samples=16, threads=2, light_map=0)  # every lamp walked
    exact = render.render(space, scene, render.Settings(**common, light_paths=0))
    sampled = render.render(space, scene, render.Settings(**common, light_paths=4, seed=3))
    difference = (sampled.passes["color"] - exact.passes["color"]).mean(axis=2).ravel()
    mean, error = mean_and_error(difference)
    assert error > 0 and abs(mean) < 4 * error
    assert exact.stats["light_estimate"] == "exact sum" and sampled.stats["light_estimate"] == "sampled"
    assert sampled.stats["shadow_walks_per_point"] == pytest.approx(4.0)
    assert exact.stats["shadow_walks_per_point"] > 30
    assert 0 < sampled.stats["shadowed_fraction"] < exact.stats["shadowed_fraction"]
    assert "shadow walks per shaded point" in sampled.summary() and "exact sum" in exact.summary()


def test_the_exact_sum_draws_no_random_numbers():
    """light_paths 0 leaves a render as it was before light sampling: no seed changes it."""
    space = spaces.load("torus")
    scene = default_scene(space)
    a, b = (
        render.render(space, scene, render.Settings(width=16, height=9, quality="draft", seed=s, light_paths=0))
        for s in (0, 9)
    )
    assert np.array_equal(a.passes["color"], b.passes["color"])


@pytest.mark.parametrize("paths", [-1, 2.5, True, 2**21])
def test_bad_light_paths_are_one_clear_error(paths):
    with pytest.raises(render.RenderError, match="light paths must be a whole number"):
        render.Settings(light_paths=paths).check()


def test_cli_light_paths(tmp_path, capsys):
    out = tmp_path / "t.png"
    cli.main(
        ["render", "--space", "torus", "--size", "16x9", "--quality", "draft", "--light-paths", "3", "--out", str(out)]
    )
    assert out.exists()
    assert "--light-paths 3" in capsys.readouterr().out


@pytest.mark.parametrize("adaptive", [0.0, 0.05])
def test_a_region_of_whole_ray_blocks_is_the_images_own_pixels(adaptive):
    """Sampled light learns which walks are shadowed over blocks of render.ray_block() pixel ids:
    a render region made of whole blocks (64 wide: 16 rows a block) gives exactly the whole
    image's pixels there, adaptive passes included (a farm's tiles rely on it)."""
    space = spaces.load("poincare")
    scene = default_scene(space)
    settings = render.Settings(
        width=64, height=48, samples=8, bounces=1, light_paths=4, noise_threshold=adaptive, threads=2
    )
    rows = render.ray_block() // 64
    whole = render.render(space, scene, settings)
    region = render.Settings(**{**settings.__dict__, "region": (0, rows, 64, rows)})
    part = render.render(space, scene, region)
    if adaptive:  # pixels stopped in every block: each pass traces subsets, learning by block all the same
        assert 0 < np.mean(whole.samples_taken < 8) < 1
    for name in ("color", "albedo", "depth"):
        np.testing.assert_array_equal(part.passes[name], whole.passes[name][rows : 2 * rows], err_msg=name)
