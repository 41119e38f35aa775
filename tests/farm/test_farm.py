"""Renders on a real two-node Ray cluster on loopback (the `cluster` fixture) against the single
process's render of the same settings and seed: tiles and sample passes, a worker killed mid-job,
a job stopped and resumed, the command line; and the plain render path without Ray."""

import dataclasses
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from thurston_addon import cli, farm, images, render, scenes

pytestmark = pytest.mark.slow  # a Ray cluster starts in about 10 s here

# bounces draw random numbers per pixel; light paths 0 (the exact sum) keeps each pixel's light
# independent of the pixels traced before it in the same task
SETTINGS = render.Settings(width=32, height=18, quality="draft", samples=4, bounces=1, light_paths=0, threads=1)


@pytest.fixture(scope="module")
def world(space_of):
    space = space_of("torus")
    c = space.camera
    return space, scenes.default_scene(space), scenes.Camera(c.position, c.forward, c.up, c.fov)


def single(world, settings):
    space, scene, camera = world
    return render.render(space, scene, settings, camera=camera)


def on_farm(world, cluster, settings, out, **split):
    space, scene, camera = world
    return farm.render(space, scene, settings, camera, cluster["address"], out, progress=lambda *a: None, **split)


def assert_same_passes(a, b):
    assert a.passes.keys() == b.passes.keys()
    for name in a.passes:
        np.testing.assert_array_equal(a.passes[name], b.passes[name], err_msg=name)


def test_tiles_are_the_single_process_render(world, cluster, tmp_path):
    merged = on_farm(world, cluster, SETTINGS, tmp_path / "t.exr", tiles=3)
    reference = single(world, SETTINGS)
    assert_same_passes(merged, reference)
    assert merged.stats["rays"] == reference.stats["rays"]
    assert merged.stats["noise"] == pytest.approx(reference.stats["noise"], rel=1e-9)
    assert not list(tmp_path.iterdir())  # nothing kept once written


def test_tiles_of_whole_ray_blocks_keep_sampled_light_exact(world, cluster, tmp_path):
    """With sampled light paths the bands are whole blocks of pixel ids (render.ray_block): the
    tiles are the single process's render bit for bit."""
    settings = dataclasses.replace(SETTINGS, width=64, height=48, light_paths=4)
    parts = farm.split(settings, 3)
    step = render.ray_block() // 64
    assert len(parts) == 3 and all(p.region[1] % step == 0 for p in parts)
    assert_same_passes(on_farm(world, cluster, settings, tmp_path / "t.exr", tiles=3), single(world, settings))


def test_tiles_keep_adaptive_sampling_exact(world, cluster, tmp_path):
    """Adaptive sampling decides per pixel: a tile's pixels take the samples they take in the whole image."""
    adaptive = dataclasses.replace(SETTINGS, samples=12, bounces=2, noise_threshold=0.05, min_samples=4)
    merged = on_farm(world, cluster, adaptive, tmp_path / "a.exr", tiles=3)
    reference = single(world, adaptive)
    assert reference.samples_taken.min() < 12  # some pixels stopped early
    np.testing.assert_array_equal(merged.samples_taken, reference.samples_taken)
    assert_same_passes(merged, reference)
    assert merged.stats["noise"] == pytest.approx(reference.stats["noise"], rel=1e-9)


def test_tiles_are_denoised_whole(world, cluster, tmp_path):
    """Denoising is the merged image's, once, as the single process denoises its whole image."""
    denoised = dataclasses.replace(SETTINGS, denoise=True)
    merged = on_farm(world, cluster, denoised, tmp_path / "d.exr", tiles=3)
    reference = single(world, denoised)
    np.testing.assert_array_equal(merged.passes["noisy"], reference.passes["noisy"])
    np.testing.assert_allclose(merged.passes["color"], reference.passes["color"], rtol=1e-5, atol=1e-6)
    assert merged.stats["denoised"]


def test_two_passes_of_four_samples_are_one_render_of_eight(world, cluster, tmp_path):
    """Pass p takes samples p, p + 2, ... of the 8-sample render (its sub-pixel positions and its
    seeds), so the merged image is that render's, up to float rounding of the sums."""
    eight = dataclasses.replace(SETTINGS, samples=8)
    merged = on_farm(world, cluster, eight, tmp_path / "s.exr", sample_passes=2)
    reference = single(world, eight)
    four = single(world, SETTINGS)
    for name in reference.passes:
        np.testing.assert_allclose(merged.passes[name], reference.passes[name], rtol=1e-6, atol=1e-6, err_msg=name)
    assert merged.stats["samples_per_pixel"] == 8
    assert merged.stats["noise"] == pytest.approx(reference.stats["noise"], rel=1e-6)
    assert np.abs(merged.passes["color"] - four.passes["color"]).max() > 1e-3  # more samples, another image


def _workers_rendering(cluster):
    """The test cluster's worker processes running a farm task."""
    found = []
    for pid in cluster["processes"]():
        try:
            if Path(f"/proc/{pid}/cmdline").read_bytes().startswith(b"ray::render_part"):
                found.append(pid)
        except OSError:
            continue
    return found


def test_a_killed_worker_loses_nothing(world, cluster, tmp_path):
    settings = dataclasses.replace(SETTINGS, width=64, height=36, samples=16)
    done, killed = {}, []

    def run():
        done["result"] = on_farm(world, cluster, settings, tmp_path / "k.exr", tiles=4)

    job = threading.Thread(target=run)
    job.start()
    deadline = time.monotonic() + 60
    while not killed and job.is_alive() and time.monotonic() < deadline:
        workers = _workers_rendering(cluster)
        if workers:
            os.kill(workers[0], signal.SIGKILL)
            killed.append(workers[0])
        time.sleep(0.05)
    job.join(120)
    assert killed, "no worker was seen rendering"
    assert_same_passes(done["result"], single(world, settings))


def test_a_stopped_job_resumes_and_a_changed_one_starts_afresh(world, cluster, tmp_path):
    out = tmp_path / "r.exr"
    space, scene, camera = world

    def stop_after_two(done, total, busy):
        if done >= 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        farm.render(space, scene, SETTINGS, camera, cluster["address"], out, tiles=6, progress=stop_after_two)
    (folder,) = tmp_path.iterdir()
    kept = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
    assert 2 <= len(kept) < 6
    first_report = []

    def record(done, total, busy):
        first_report.append(done) if not first_report else None

    def written(result):
        assert {p.name: p.stat().st_mtime_ns for p in folder.iterdir() if p.name in kept} == kept  # not redone
        images.write(out, result.passes)

    merged = farm.render(
        space, scene, SETTINGS, camera, cluster["address"], out, tiles=6, progress=record, write=written
    )
    assert first_report[0] >= len(kept)  # the kept tiles count as done from the start
    assert_same_passes(merged, single(world, SETTINGS))
    assert [p.name for p in tmp_path.iterdir()] == ["r.exr"]  # the kept parts removed once written

    with pytest.raises(KeyboardInterrupt):
        farm.render(space, scene, SETTINGS, camera, cluster["address"], out, tiles=6, progress=stop_after_two)
    (before,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    changed = dataclasses.replace(SETTINGS, samples=2)
    with pytest.raises(KeyboardInterrupt):
        farm.render(space, scene, changed, camera, cluster["address"], out, tiles=6, progress=stop_after_two)
    (after,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert after != before  # another job's parts: the old ones removed, none reused


def test_command_line_render_on_the_cluster(cluster, tmp_path, capsys):
    common = ["render", "--space", "torus", "--size", "32x18", "--quality", "draft", "--bounces", "1"]
    common += ["--light-paths", "0", "--threads", "1"]
    assert cli.main([*common, "--out", str(tmp_path / "one.exr")]) == 0
    capsys.readouterr()
    args = [*common, "--out", str(tmp_path / "farm.exr"), "--cluster", cluster["address"], "--tiles", "2"]
    assert cli.main(args) == 0
    one, farmed = (images.read_texture(tmp_path / n) for n in ("one.exr", "farm.exr"))
    np.testing.assert_array_equal(one, farmed)
    # one progress line for the job: parts done of all, samples, workers busy, time, ETA while under way
    lines = [line.strip() for line in capsys.readouterr().err.splitlines() if line.startswith("farm:")]
    assert lines[-1].startswith("farm: 2/2 tiles (1 samples/pixel), 0 workers busy,"), lines
    assert any(line.startswith("farm: 1/2 tiles") and "ETA" in line for line in lines), lines


def test_both_eyes_of_an_omni_directional_stereo_panorama_on_the_cluster(world, cluster, tmp_path):
    """Each eye a job of tiles (the eyes' per-pixel geodesics computed per tile): the same passes as
    the single process's eyes."""
    space, scene, camera = world
    stereo = render.Stereo(interocular=0.1)
    settings = dataclasses.replace(SETTINGS, projection="equirect", width=32, height=16, stereo=stereo)
    eyes = render.render_eyes(space, scene, settings, camera)
    for eye, alone in zip(render.EYES, eyes):
        farmed = on_farm(world, cluster, dataclasses.replace(settings, eye=eye), tmp_path / f"{eye}.exr", tiles=3)
        assert_same_passes(farmed, alone)


def test_plain_render_does_not_import_ray(tmp_path):
    code = (
        "import sys; from thurston_addon import cli; "
        f"assert cli.main(['render', '--space', 'torus', '--size', '8x6', '--quality', 'draft', '--out', "
        f"{str(tmp_path / 'p.png')!r}]) == 0; assert 'ray' not in sys.modules, 'ray imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)


def test_adaptive_sampling_over_sample_passes(world, cluster, tmp_path):
    """Rounds of the single process's samples in its order (the first 4, then one per pass and
    round), the pooled noise estimate deciding after each round which pixels take more; the single
    process decides after every sample. So a pixel that stopped there at a round's end (4, 6, ...,
    or never) stops at the same count here, with the same samples (the same colour), and one that
    stopped after an odd count takes more here (no round's end before it let it stop)."""
    adaptive = dataclasses.replace(SETTINGS, samples=12, bounces=2, noise_threshold=0.05, min_samples=4)
    merged = on_farm(world, cluster, adaptive, tmp_path / "a.exr", sample_passes=2)
    reference = single(world, adaptive)
    farm_taken, single_taken = merged.samples_taken, reference.samples_taken
    assert set(np.unique(farm_taken)) <= {4, 6, 8, 10, 12}
    at_round_end = single_taken % 2 == 0
    assert 0 < at_round_end.mean() < 1 and farm_taken.min() < 12  # both kinds of pixel, some stopped
    np.testing.assert_array_equal(farm_taken[at_round_end], single_taken[at_round_end])
    assert np.all(farm_taken[~at_round_end] > single_taken[~at_round_end])
    same = farm_taken == single_taken
    np.testing.assert_allclose(merged.passes["color"][same], reference.passes["color"][same], rtol=1e-6, atol=1e-6)
    assert merged.stats["samples_mean"] == pytest.approx(farm_taken.mean())


def test_a_jobs_key_is_the_same_in_another_process(world):
    """The key that finds a stopped job's parts, computed by a later run (another process, other
    hash seeds), is the same; another setting gives another."""
    space, scene, camera = world
    parts = farm.split(SETTINGS, 4)
    key = farm.Job(space, scene, SETTINGS, camera).key(parts)
    code = (
        "from thurston_addon import farm, render, scenes, spaces; s = spaces.load('torus'); c = s.camera; "
        f"settings = render.{SETTINGS!r}; "
        "job = farm.Job(s, scenes.default_scene(s), settings, scenes.Camera(c.position, c.forward, c.up, c.fov)); "
        "print(job.key(farm.split(settings, 4)))"
    )
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert other.stdout.strip() == key, other.stderr
    changed = dataclasses.replace(SETTINGS, samples=5)
    assert farm.Job(space, scene, changed, camera).key(farm.split(changed, 4)) != key


def test_without_ray_one_error_names_the_extra(tmp_path):
    code = (
        "import sys; sys.modules['ray'] = None; from thurston_addon import cli; "
        f"sys.exit(cli.main(['render', '--space', 'torus', '--size', '8x6', '--out', {str(tmp_path / 'p.png')!r}, "
        "'--cluster', 'local:1']))"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2
    assert "install the 'farm' extra" in run.stderr and "Traceback" not in run.stderr
    assert not list(tmp_path.iterdir())
