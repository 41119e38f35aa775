"""Adaptive sampling (--noise-threshold, --min-samples) and the time limit (--time-limit), against
independent truth: off, the render is today's fixed-sample render bit for bit; a pixel of zero
variance (the sky) stops at min_samples while the path-traced surfaces take more; the reached noise
(RMS of the per-pixel standard errors) against the RMS error measured from a converged reference
rendered with other random numbers (the seed); the time limit stops after a whole pass and says so."""

from __future__ import annotations

import numpy as np
import pytest

from thurston_addon import cli, render, spaces
from thurston_addon.scenes import default_scene

SIZE = dict(width=32, height=18)


@pytest.fixture(scope="module")
def world():
    space = spaces.load("torus")
    return space, default_scene(space)


def go(world, **kw):
    space, scene = world
    return render.render(space, scene, render.Settings(**SIZE, **kw))


def test_off_is_fixed_sampling_bit_for_bit(world):
    fixed = go(world, samples=8, bounces=1)
    off = go(world, samples=8, bounces=1, noise_threshold=0.0, min_samples=0, time_limit=None)
    assert np.array_equal(fixed.passes["color"], off.passes["color"])
    assert off.stats["noise"] == fixed.stats["noise"]
    assert off.stats["samples_mean"] == off.stats["samples_max"] == 8
    assert not off.stats["time_limit_reached"]


def test_flat_pixels_stop_at_min_samples_noisy_ones_go_on(world):
    # object shading: a pixel inside one object is one flat brightness (zero variance), a pixel
    # across an edge may vary with the sample position (object colours are of one brightness, 0.5,
    # so only edges onto misses vary: the estimate is of the brightness, as the noise figure's)
    fixed = go(world, samples=16, shading="object")
    r = go(world, samples=16, shading="object", noise_threshold=1e-6, min_samples=4)
    taken = r.samples_taken
    flat, edge = taken == 4, taken == 16
    assert np.all(flat | edge) and flat.sum() > 100 and edge.sum() > 10
    # a hit is of brightness 0.5, a miss 0: a pixel of brightness 0.5 in the fixed render had 16
    # hits and is flat, so it stopped at 4; a stopped pixel's 4 samples were all hits (brightness
    # 0.5; its later samples, not taken, may have missed); the others took the fixed render's 16
    bright, bright_fixed = r.passes["color"].mean(axis=2), fixed.passes["color"].mean(axis=2)
    assert np.all(flat[np.isclose(bright_fixed, 0.5, atol=1e-6)])
    assert np.allclose(bright[flat], 0.5, atol=1e-6)
    assert np.array_equal(r.passes["color"][edge], fixed.passes["color"][edge])
    assert r.stats["samples_max"] == 16 and r.stats["samples_mean"] == taken.mean()
    # path traced: noisy pixels go on until their error is below the threshold
    p = go(world, samples=32, bounces=1, noise_threshold=0.05, min_samples=4)
    assert 4 <= p.samples_taken.min() and p.stats["samples_max"] == 32 and p.stats["samples_mean"] < 16


def test_reached_noise_matches_measured_error(world):
    ref = go(world, samples=128, bounces=1, seed=10_000)
    truth = ref.passes["color"].mean(axis=2)
    errs, noises = [], []
    for seed in range(3):
        r = go(world, samples=64, bounces=1, noise_threshold=0.01, min_samples=8, seed=seed * 1000 + 1)
        errs.append(np.mean((r.passes["color"].mean(axis=2) - truth) ** 2))
        noises.append(r.stats["noise"] ** 2)
    measured = np.sqrt(np.mean(errs) - ref.stats["noise"] ** 2)
    reached = np.sqrt(np.mean(noises))
    assert abs(measured / reached - 1) < 0.3, (measured, reached)


def test_time_limit_stops_after_a_whole_pass(world):
    r = go(world, samples=16, time_limit=1e-9)
    assert r.stats["time_limit_reached"]
    assert r.stats["samples_mean"] == r.stats["samples_max"] == 1  # one whole pass, every pixel
    assert "time limit" in r.summary()
    assert np.all(np.isfinite(r.passes["color"]))


def test_cli_options_and_summary(tmp_path, capsys):
    argv = ["render", "--space", "torus", "--size", "32x18", "--samples", "16", "--bounces", "1"]
    code = cli.main([*argv, "--noise-threshold", "0.001", "--min-samples", "4", "--out", str(tmp_path / "a.png")])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "samples per pixel used: mean" in out + err and "noise threshold 0.001" in out + err


@pytest.mark.parametrize(
    "option, name",
    [
        (["--noise-threshold", "-1"], "noise threshold"),
        (["--noise-threshold", "nan"], "noise threshold"),
        (["--time-limit", "-1"], "time limit"),
        (["--time-limit", "nan"], "time limit"),
        (["--min-samples", "8"], "min samples"),
    ],
)
def test_cli_bad_values_name_the_option(tmp_path, capsys, option, name):
    argv = ["render", "--space", "torus", "--size", "4x4", "--samples", "4", *option, "--out", str(tmp_path / "x.png")]
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert code == 2
    assert name in err and "Traceback" not in err
