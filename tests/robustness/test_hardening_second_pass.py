"""Issue 21's adversarial cases, each a regression test from its small or generated input: deep TOML
nesting, repeated generators, a pass named twice, a rays file of no rays, a frame range of a
billion frames."""

from __future__ import annotations

import math
import subprocess
import time

import numpy as np
import pytest
from support.outputs import error_line

from thurston_addon import cli, spaces
from thurston_addon.scenes import scene_file


def cli_error(argv, capsys) -> str:
    code = cli.main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and "encountered" not in err, err
    return error_line(err)


@pytest.mark.parametrize("kind", ["space", "scene"])
def test_toml_nested_100000_deep_is_one_clear_error(tmp_path, kind):
    path = tmp_path / f"{kind}.toml"
    path.write_text("x = " + "[" * 100000 + "]" * 100000 + "\n")
    load, error = (
        (spaces.load, spaces.SpaceError) if kind == "space" else (scene_file.load_scene_file, scene_file.SceneError)
    )
    with pytest.raises(error, match="nest too deeply") as caught:
        load(path)
    assert str(path) in str(caught.value)


def test_repeated_generators_load_in_time_near_linear_in_their_number():
    """5002 generators, the torus's three repeated (and given as inverses): the same domain, and the
    load time grows about linearly (it took over 8 minutes before the repeats were dropped first)."""
    torus = spaces.load("torus")
    base = [{"name": f"g{k}", "matrix": M.tolist()} for k, M in enumerate(torus.generators)]
    inverse = [{"name": f"i{k}", "matrix": np.linalg.inv(M).tolist()} for k, M in enumerate(torus.generators)]

    def load(n):
        data = {
            "geometry": "E3",
            "generator": [dict(g, name=f"{g['name']}_{k}") for k in range(n) for g in base + inverse],
        }
        start = time.perf_counter()
        space = spaces.from_data(data, "repeated")
        faces = len(space.domain.covectors())
        return time.perf_counter() - start, faces

    small, faces_small = load(50)
    large, faces_large = load(834)  # 5004 generators
    assert faces_small == faces_large == 6
    assert large < 30, large
    assert large < 60 * max(small, 0.01), (small, large)  # 16.7 times the generators: not their square


def test_a_pass_named_twice_is_written_once(tmp_path, capsys):
    import OpenImageIO as oiio

    out = tmp_path / "t.exr"
    argv = ["render", "--space", "torus", "--size", "8x6", "--quality", "draft", "--passes", "color,depth,color"]
    assert cli.main([*argv, "--out", str(out)]) == 0, capsys.readouterr().err
    channels = list(oiio.ImageInput.open(str(out)).spec().channelnames)
    assert channels == ["R", "G", "B", "Z"], channels  # each once (it gave channel3..5 for the second)


def test_a_rays_file_of_no_rays_is_one_clear_error(tmp_path, capsys):
    rays = tmp_path / "rays.npy"
    np.save(rays, np.zeros((0, 6)))
    line = cli_error(["trace", "--space", "torus", "--rays", rays, "--out", tmp_path / "hits.npz"], capsys)
    assert "holds no rays" in line and str(rays) in line
    assert not (tmp_path / "hits.npz").exists()


def test_a_billion_frames_are_not_listed_up_front(tmp_path, registered_addon):
    """render-blend's frames are generated as they are rendered: a range of a billion frames costs
    nothing before the first (it built every path first: 6.7 GB, then MemoryError), and a finished
    frame already in the folder is refused before any work."""
    import bpy
    from support import blender_helpers as bh

    from thurston_addon.blender import batch

    bh.fresh_scene("torus", size=(8, 6))
    blend = tmp_path / "shot.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    out = tmp_path / "out"
    out.mkdir()
    (out / "shot_0007.exr").write_bytes(b"finished")
    start = time.perf_counter()
    run = bh.render_blend(blend, out, frames="1..1000000000")
    assert run.returncode == 2 and "shot_0007.exr" in run.stderr and "exists" in run.stderr, run.stderr
    assert "Traceback" not in run.stderr and time.perf_counter() - start < 60
    assert sorted(p.name for p in out.iterdir()) == ["shot_0007.exr"]  # nothing rendered, nothing lost
    assert (out / "shot_0007.exr").read_bytes() == b"finished"
    assert batch.glob_escape("a*b?[c") == "a[*]b[?][[]c"


def test_render_blend_png_into_the_default_folder(tmp_path, registered_addon, monkeypatch):
    """`render-blend FILE.blend --format png` with its default output folder (.) writes the frame
    there (Blender could not write the bare relative name it was given)."""
    import bpy
    from support import blender_helpers as bh

    bh.fresh_scene("torus", size=(8, 6))
    bh.box("Box", 0.2, (0.0, 0.2, 0.0))
    bh.point_light((0.1, 0.0, 0.3))
    bh.camera((0.0, -0.3, 0.0), rotation=(math.radians(90), 0, 0))
    blend = tmp_path / "shot.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    run = subprocess.run(
        [str(bh.THURSTON), "render-blend", str(blend), "--frames", "1", "--format", "png"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    assert (work / "shot_0001.png").stat().st_size > 0


def test_a_gltf_buffer_that_is_a_fifo_is_refused_not_read(tmp_path):
    """A .gltf whose buffer is a named pipe: one error naming the buffer, at once (trimesh's reader
    opened it and blocked for ever)."""
    import json
    import os

    os.mkfifo(tmp_path / "buf.bin")
    gltf = tmp_path / "mesh.gltf"
    gltf.write_text(json.dumps({"asset": {"version": "2.0"}, "buffers": [{"uri": "buf.bin", "byteLength": 36}]}))
    out = tmp_path / "out.png"
    from support.blender_helpers import THURSTON

    argv = [str(THURSTON), "render", "--space", "torus", "--scene", str(gltf), "--size", "8x6", "--out", str(out)]
    run = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    assert run.returncode == 2, run.stderr
    assert "buffer 0" in run.stderr and "FIFO" in run.stderr and str(tmp_path / "buf.bin") in run.stderr
    assert not out.exists()


@pytest.mark.parametrize("space_id, copies", [("s2xs1", 14), ("rp3_rp3", 8)])
def test_s2xr_light_copies_far_below_are_kept(space_id, copies):
    """Every copy of the light within reach 40 of the domain, against an enumeration of the group's
    elements by their own keys (a reach of 40 kept 7 of s2xs1's 14: the copies periods below were
    keyed by model vectors crowded at the origin, and merged)."""
    from thurston_addon import render

    space = spaces.load(space_id)
    g = space.geometry
    L = g.normalize_point(g.to_model(np.array([space.camera.position], float)))[0]
    steps = [*space.generators, *(np.linalg.inv(M) for M in space.generators)]
    distance = lambda M: g.domain_distance(g.normalize_point((M @ L)[None]), space.domain)[0]  # noqa: E731
    found, frontier = {g.element_key(np.eye(4)): np.eye(4)}, [np.eye(4)]
    while frontier:  # breadth first, through the copies within 60 (the group is a line of periods)
        fresh = {}
        for N in (S @ M for M in frontier for S in steps):
            if g.element_key(N) not in found and distance(N) <= 60:
                fresh[g.element_key(N)] = N
        found.update(fresh)
        frontier = list(fresh.values())
    within = {k for k, M in found.items() if distance(M) <= 40 + 1e-9}
    kept = {g.element_key(M) for M in render.cover_copies(space, L, 40.0)}
    assert len(within) == copies and kept == within
