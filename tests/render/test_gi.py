"""Global illumination (path tracing along geodesics) against closed forms.

White furnace: a closed surface around the camera, every point of it of albedo rho and emitting Le
(two-sided). Radiance leaving any of its points is Le + rho * (the radiance arriving, which is the
same everywhere), so L = Le / (1 - rho) in any geometry. The tracer's camera hit adds its own
emission and rho times its next-event estimate of the emitters (Le: every line of sight ends on the
surface); each bounce adds rho times the next vertex's, so with a bounce limit B a pixel is exactly
Le (1 + rho + ... + rho^(B+1)) (bounces = 0: direct light, Le (1 + rho)). With rho = 1 that is
(B + 2) Le: a bounce neither gains nor loses energy. Rays from the centre in random directions
(each its own random numbers); the mean against the truth within four standard errors measured
from the spread, and that spread small enough to tell a bounce's term missing. The emission that
bounces meet counts too, weighed against the emitters' samples of the same geodesics (multiple
importance sampling): the weights of the two must add up to 1 on every geodesic, or the furnace
gains or loses light.

Multiple importance sampling against its parts: a small bright emitter over a matte and a shiny
floor, lit by the emitters' samples alone, by the emission the bounces meet alone, and by both
weighed: the same mean, and the weighed one less noisy than the worse of the two."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from support.furnace import LE, furnace_tracer, mean_and_error, random_rays
from support.presets import simplest_per_geometry

from thurston_addon import cli, render, spaces
from thurston_addon.scenes import Camera, Material, PointLight, Scene, SceneObject, default_scene

SPACES = simplest_per_geometry()  # one preset of each geometry


@pytest.mark.parametrize("space_id", SPACES)
@pytest.mark.parametrize("rho, bounces", [(0.5, 0), (0.5, 2), (1.0, 3), (0.8, 5)])
def test_white_furnace_gives_the_geometric_series_of_the_albedo(space_id, rho, bounces):
    """With bounces >= 4 Russian roulette ends some paths early, which must leave the mean as it
    was. Chords within 1e-6 of the curved geodesics: a shadow ray is tested on its chords, and
    along the surface (as here) looser chords meet it where the geodesic does not."""
    space = spaces.load(space_id)
    tracer, centre = furnace_tracer(space, rho)
    P, D = random_rays(space, centre, 2000, seed=1)
    out = tracer.trace(P, D, 5.0, 40, shade=True, tolerance=1e-6, light_samples=1, seed=11, bounces=bounces)
    assert np.all(out["stop"] == 0)
    assert int(out["light_failures"]) == 0
    # every emissive triangle is known among the emitters' copies, and bounces meet them
    assert tracer.num_unmatched_emitters == 0 and (int(out["emitter_hits"]) > 0) == (bounces > 0)
    mean, error = mean_and_error(out["color"][:, 0])
    truth = LE * sum(rho**k for k in range(bounces + 2))
    print(
        f"{space_id} rho {rho} bounces {bounces}: mean {mean:.5f} truth {truth:.5f} "
        f"({mean / truth - 1:+.1e}), standard error {error / truth:.1e}"
    )
    assert 4 * error < LE * rho ** (bounces + 1)  # a missing last bounce would show
    assert abs(mean - truth) < 4 * error


def test_bounces_zero_is_direct_light_and_traces_no_bounce():
    space = spaces.load("torus")
    tracer, centre = furnace_tracer(space, 0.5)
    P, D = random_rays(space, centre, 200, seed=2)
    direct = tracer.trace(P, D, 5.0, 40, light_samples=2, seed=3)
    zero = tracer.trace(P, D, 5.0, 40, light_samples=2, seed=3, bounces=0)
    assert int(zero["bounce_paths"]) == 0
    assert np.array_equal(direct["color"], zero["color"])
    two = tracer.trace(P, D, 5.0, 40, light_samples=2, seed=3, bounces=2)
    assert int(two["bounce_paths"]) == 2 * 200  # every bounce meets the walls, no roulette before the 4th


def test_albedo_one_with_a_point_light_converges_as_the_bounce_limit_grows():
    """Energy: white (albedo 1) objects, no emission, one point light, in the 3-torus with a distance
    limit of 1.5 per geodesic. A bounce whose geodesic meets nothing within the limit ends its path,
    so each bounce's share is the last one's times the chance of meeting something (below 1): the
    increments shrink geometrically and the image stays bounded. Independent random numbers per
    bounce limit; the increments against their standard errors."""
    space = spaces.load("torus")
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.15)
    slab = trimesh.creation.box([0.6, 0.6, 0.05])
    objects = [
        SceneObject("ball", ball.vertices + [0.2, 0.1, 0.0], ball.faces, (1.0, 1.0, 1.0)),
        SceneObject("slab", slab.vertices + [0.0, 0.0, -0.3], slab.faces, (1.0, 1.0, 1.0)),
    ]
    tracer = render.make_tracer(
        space,
        Scene(objects=objects, lights=[PointLight([-0.2, -0.2, 0.2], (1, 1, 1), 0.05)]),
        threads=2,
        light_reach=1.0,
    )
    P, D = random_rays(space, [-0.3, 0.3, 0.1], 20000, seed=4)
    limits = [0, 1, 2, 4, 8, 16]
    means, errors = [], []
    for b in limits:
        out = tracer.trace(P, D, 1.5, 40, light_samples=1, seed=5 + b, bounces=b)
        m, e = mean_and_error(out["color"].mean(axis=1))
        means.append(m)
        errors.append(e)
    print(
        "bounce limits",
        limits,
        "means",
        np.round(means, 5),
        "standard errors",
        np.format_float_scientific(max(errors), 1),
    )
    means, errors = np.array(means), np.array(errors)
    steps = np.diff(means)
    step_errors = np.hypot(errors[1:], errors[:-1])
    assert np.all(steps > -4 * step_errors)  # light only adds
    assert steps[0] > 4 * step_errors[0]  # the first bounce adds something
    assert steps[-1] < 0.5 * steps[0]  # shrinking
    assert abs(means[-1] - means[-2]) < 0.02 * means[-1] + 4 * step_errors[-1]  # converged


def test_render_noise_estimate_matches_the_error_against_the_furnace_truth():
    """render() with bounces: every pixel of the furnace has the same truth, so the RMS over the
    pixels of (pixel mean - truth) is the pixels' actual standard error, against which the render's
    noise estimate (from each pixel's own samples) is checked; and the image's mean is the truth."""
    space = spaces.load("torus")
    rho, bounces, samples = 0.5, 2, 16
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.2)
    walls = SceneObject("walls", ball.vertices, ball.faces, (rho,) * 3, (LE,) * 3)
    settings = render.Settings(
        width=40, height=30, samples=samples, bounces=bounces, light_samples=1, light_reach=0.6, threads=2
    )
    result = render.render(
        space,
        Scene(objects=[walls], lights=[]),
        settings,
        camera=Camera((0.0, 0.0, 0.0), (1.0, 0.2, 0.1), (0.0, 0.0, 1.0), 90.0),
    )
    truth = LE * sum(rho**k for k in range(bounces + 2))
    pixels = result.passes["color"].mean(axis=2).ravel()
    actual = math.sqrt(np.mean((pixels - truth) ** 2))
    noise = result.stats["noise"]
    print(f"image mean {pixels.mean():.5f} truth {truth:.5f}; noise estimate {noise:.3e}, actual {actual:.3e}")
    assert abs(pixels.mean() - truth) < 4 * actual / math.sqrt(len(pixels))
    assert 0.85 < noise / actual < 1.15
    assert result.stats["bounce_paths_per_point"] == pytest.approx(bounces, abs=1e-9)  # no roulette before the 4th
    assert "bounce limit 2" in result.summary() and f"noise {noise:.2e}" in result.summary()


def test_one_sample_has_no_noise_estimate_and_direct_light_says_so():
    space = spaces.load("torus")
    result = render.render(space, default_scene(space), render.Settings(width=16, height=9, samples=1, threads=2))
    assert result.stats["noise"] is None and result.stats["bounces"] == 0
    assert "direct light only, noise: one sample per pixel, not estimated" in result.summary()


@pytest.mark.parametrize("bounces", [-1, 1.5, True, render.MAX_BOUNCES + 1])
def test_bad_bounces_are_one_clear_error(bounces):
    with pytest.raises(render.RenderError, match="bounces must be a whole number between 0"):
        render.Settings(bounces=bounces).check()


@pytest.mark.parametrize("seed", [-1, 0.5, 2**63])
def test_bad_seeds_are_one_clear_error(seed):
    with pytest.raises(render.RenderError, match="seed must be a whole number >= 0"):
        render.Settings(seed=seed).check()


def test_seed_offsets_the_samples_random_numbers():
    """The same seed, the same image (any threads); another seed, other light samples and bounces."""
    space = spaces.load("torus")
    scene = default_scene(space)

    def image(seed):
        return render.render(
            space, scene, render.Settings(width=16, height=9, samples=2, bounces=1, seed=seed, threads=2)
        ).passes["color"]

    assert np.array_equal(image(3), image(3))
    assert not np.array_equal(image(3), image(4))


def test_cli_bounces(tmp_path, capsys):
    out = tmp_path / "gi.exr"
    assert (
        cli.main(
            ["render", "--space", "torus", "--size", "16x9", "--samples", "2", "--bounces", "1", "--out", str(out)]
        )
        == 0
    )
    assert out.exists() and "bounce limit 1" in capsys.readouterr().out
    assert cli.main(["render", "--space", "torus", "--bounces", "-1", "--out", str(tmp_path / "bad.exr")]) == 2
    err = capsys.readouterr().err
    assert err.count("thurston: error:") == 1 and "bounces must be a whole number between 0" in err


def mis_scene(space):
    """A matte slab and a metal one (roughness 0.25) below the space's camera point, a small bright
    emitter (black, radius 0.06 of the inradius, radiance 100) above them; sizes from the chart's
    inradius."""
    inr = space.chart_inradius
    c = np.asarray(space.camera.position, float)
    slab = trimesh.creation.box([0.5 * inr, 0.9 * inr, 0.04 * inr])
    matte = SceneObject("matte", slab.vertices + c + inr * np.array([-0.26, 0.0, -0.3]), slab.faces, (0.7, 0.7, 0.7))
    shiny = SceneObject(
        "shiny",
        slab.vertices + c + inr * np.array([0.26, 0.0, -0.3]),
        slab.faces,
        materials=[Material((0.9, 0.9, 0.9), name="metal", roughness=0.25, metallic=1.0)],
        triangle_material=np.zeros(len(slab.faces), np.int32),
    )
    bulb = trimesh.creation.icosphere(subdivisions=2, radius=0.06 * inr)
    lamp = SceneObject(
        "lamp", bulb.vertices + c + inr * np.array([0.1, 0.25, 0.05]), bulb.faces, (0, 0, 0), (100.0,) * 3
    )
    return Scene(objects=[matte, shiny, lamp], lights=[])


def by_sampling(space, tracer, P, D, length, modes=("mis", "light", "bounce")):
    """{mode: (mean, standard error)} of the pixels' brightness with one bounce."""
    out = {}
    for mode in modes:
        res = tracer.trace(P, D, length, space.max_crossings, light_samples=1, seed=3, bounces=1, emitter_sampling=mode)
        if mode == "mis":
            assert int(res["emitter_hits"]) > 0
        out[mode] = mean_and_error(res["color"].mean(axis=1))
    return out


@pytest.mark.parametrize("space_id", SPACES)
def test_mis_has_the_mean_of_its_parts_and_less_noise(space_id):
    """With a distance limit no longer than the light reach, the emitters' samples (every geodesic
    within the reach) and the bounces reach the same geodesics, so all three estimates have one
    mean."""
    space = spaces.load(space_id)
    reach = 2.5 * space.inradius
    tracer = render.make_tracer(space, mis_scene(space), threads=2, light_reach=reach)
    assert tracer.num_unmatched_emitters == 0
    P, D = random_rays(space, space.camera.position, 20000, seed=7, down=True)
    est = by_sampling(space, tracer, P, D, reach)
    print(space_id, {mode: (round(m, 4), round(e, 4)) for mode, (m, e) in est.items()})
    (m, e) = est["mis"]
    for mode in ("light", "bounce"):
        assert abs(m - est[mode][0]) < 4 * math.hypot(e, est[mode][1]), mode
    assert e < 0.9 * max(est["light"][1], est["bounce"][1])


@pytest.mark.parametrize("space_id", ["torus", "seifert_weber"])
def test_emitters_beyond_the_light_reach_light_through_bounces(space_id):
    """A light reach shorter than the way from the slabs to the emitter: its samples bring nothing
    (what is left is the emitter itself, which a few rays see), the bounces that meet it bring its
    light, as much as without the samples."""
    space = spaces.load(space_id)
    tracer = render.make_tracer(space, mis_scene(space), threads=2, light_reach=0.1 * space.inradius)
    P, D = random_rays(space, space.camera.position, 20000, seed=8, down=True)
    est = by_sampling(space, tracer, P, D, 2.5 * space.inradius)
    print(space_id, est)
    assert est["light"][0] < 0.02 * est["mis"][0]
    assert est["mis"][0] > 8 * est["mis"][1]
    assert abs(est["mis"][0] - est["bounce"][0]) < 4 * math.hypot(est["mis"][1], est["bounce"][1])
