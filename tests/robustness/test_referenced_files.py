"""Issue 21: the files a scene refers to (material libraries, textures, glTF buffers and images, a
scene file's mesh files) are read only from the scene file's folder and below unless the user
allows another folder, alike for OBJ, glTF and TOML scenes; errors never quote a line of such a
file; and a texture's header is checked against the pixel limit before its pixels are read."""

from __future__ import annotations

import json
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from support.gltf_triangle import textured_triangle
from support.outputs import error_line

from thurston_addon import cli, images, scenes

TRIANGLE = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], np.float32)
UV = np.array([[0, 0], [1, 0], [0, 1]], np.float32)
GREY = 0.5  # the texture's linear value, as read back


def write_texture(path: Path) -> Path:
    images.write(path, {"color": np.full((4, 4, 3), GREY, np.float32)})
    return path


def gltf(scene: Path, buffer_uri: str, image_uri: str) -> Path:
    """A textured triangle whose buffer and image are the files these URIs name."""
    path = scene / "painted.gltf"
    path.write_text(json.dumps(textured_triangle(buffer_uri, image_uri, top=0.1)))
    return path


def obj(scene: Path, mtllib: str) -> Path:
    path = scene / "painted.obj"
    path.write_text(f"mtllib {mtllib}\nusemtl painted\nv 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nvt 0 0\nf 1/1 2/1 3/1\n")
    return path


@pytest.fixture
def folders(tmp_path):
    """(scene, outside): the scene's folder, and a sibling holding a texture, a material library
    naming it, a glTF buffer and an OBJ, all valid."""
    scene, outside = tmp_path / "scene", tmp_path / "outside"
    scene.mkdir()
    outside.mkdir()
    write_texture(outside / "tex.png")
    (outside / "m.mtl").write_text(f"newmtl painted\nmap_Kd {outside / 'tex.png'}\n")
    (outside / "buf.bin").write_bytes(TRIANGLE.tobytes() + UV.tobytes())
    obj(outside, "m.mtl")
    return scene, outside


# Each: (what the scene refers to outside its folder, how it names it) -> the scene file to load.
LAYOUTS = {
    "OBJ mtllib, relative": lambda s, o: obj(s, "../outside/m.mtl"),
    "OBJ mtllib, absolute": lambda s, o: obj(s, str(o / "m.mtl")),
    "MTL map_Kd, absolute": lambda s, o: (
        (s / "m.mtl").write_text(f"newmtl painted\nmap_Kd {o / 'tex.png'}\n"),
        obj(s, "m.mtl"),
    )[1],
    "OBJ mtllib, a link inside to a file outside": lambda s, o: (
        os.symlink(o / "m.mtl", s / "m.mtl"),
        obj(s, "m.mtl"),
    )[1],
    "glTF image URI": lambda s, o: (
        (s / "buf.bin").write_bytes((o / "buf.bin").read_bytes()),
        gltf(s, "buf.bin", "../outside/tex.png"),
    )[1],
    "glTF buffer": lambda s, o: (
        write_texture(s / "tex.png"),
        gltf(s, str(o / "buf.bin"), "tex.png"),
    )[1],
    "TOML mesh file": lambda s, o: (
        (s / "scene.toml").write_text('[[object]]\nfile = "../outside/painted.obj"\n'),
        s / "scene.toml",
    )[1],
}


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_files_outside_the_scene_folder_are_read_only_where_allowed(folders, layout):
    """Refused naming the file, the scene's folder and the option; loaded (the texture's grey on the
    triangle) once the user allows the outside folder."""
    scene, outside = folders
    path = LAYOUTS[layout](scene, outside)
    with pytest.raises(scenes.SceneError) as caught:
        scenes.load_scene_file(path)
    message = str(caught.value)
    assert "is outside the scene's folder" in message and str(scene) in message, message
    assert "--allow-files-outside" in message and "Traceback" not in message
    (loaded,) = scenes.load_scene_file(path, allowed=[outside]).objects
    np.testing.assert_allclose(loaded.materials[0].color_texture, GREY, atol=0.01)
    np.testing.assert_allclose(loaded.vertices[:, :2].max(axis=0), [0.1, 0.1], atol=1e-6)


def test_the_command_line_flag_allows_a_folder(folders, capsys):
    scene, outside = folders
    path = LAYOUTS["OBJ mtllib, relative"](scene, outside)
    argv = ["render", "--space", "torus", "--scene", str(path), "--size", "8x6", "--quality", "draft"]
    assert cli.main([*argv, "--out", str(scene / "a.png")]) == 2
    assert "--allow-files-outside" in error_line(capsys.readouterr().err)
    assert cli.main([*argv, "--allow-files-outside", str(outside), "--out", str(scene / "a.png")]) == 0
    assert (scene / "a.png").stat().st_size > 0


@pytest.mark.parametrize(
    "kind, body",
    [
        ("obj", "v 0 0 0\nv 1 SECRET-7f3a 0\n"),
        ("obj", "v 0 0 0\nf 1 SECRET-7f3a\n"),
        ("mtl", "newmtl m\nKd SECRET-7f3a 1 1\n"),
        ("mtl", "newmtl m\nKd 1 SECRET-7f3a\n"),
        ("mtl", "newmtl m\nNs SECRET-7f3a\n"),
    ],
)
def test_parse_errors_never_quote_the_file(tmp_path, kind, body):
    """A parse error names the file, the line and what it needs, not the line's contents (the
    file may be one the user never named: a library a mesh refers to)."""
    if kind == "mtl":
        (tmp_path / "m.mtl").write_text(body)
        path = obj(tmp_path, "m.mtl")
    else:
        path = tmp_path / "bad.obj"
        path.write_text(body)
    with pytest.raises(scenes.SceneError) as caught:
        scenes.load_scene_file(path)
    message = str(caught.value)
    assert "SECRET" not in message and ":2:" in message, message


def png_header_only(path: Path, width: int, height: int) -> Path:
    """A PNG whose header claims width x height and whose pixel data is a few rows (a few KB)."""

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    rows = zlib.compress(b"\0" * (width * 3 + 1) * 4)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
        + chunk(b"IDAT", rows)
        + chunk(b"IEND", b"")
    )
    return path


@pytest.mark.parametrize("side", [16384, 30000])
def test_a_texture_beyond_the_pixel_limit_is_refused_from_its_header(tmp_path, side):
    """A small PNG claiming side x side pixels is refused before its pixels are read (16384 took
    14.5 GB and 50 s; 30000 ended in std::bad_alloc), naming the size, the limit and what to do."""
    path = png_header_only(tmp_path / "huge.png", side, side)
    assert path.stat().st_size < 200_000
    with pytest.raises(ValueError) as caught:
        images.read_texture(path)
    message = str(caught.value)
    assert f"{side}x{side} pixels" in message and "8192x8192" in message and "scale it down" in message


def test_a_truncated_texture_says_why(tmp_path):
    """A PNG cut short in its pixel data: the reason is said (it was empty)."""
    path = png_header_only(tmp_path / "cut.png", 64, 64)
    with pytest.raises(ValueError) as caught:
        images.read_texture(path)
    reason = str(caught.value).split(": ", 1)[1]
    assert reason.strip() and str(path) in str(caught.value), str(caught.value)


def test_a_gltf_texture_without_texture_coordinates_is_read_at_uv_0(tmp_path):
    """A textured glTF whose mesh has no TEXCOORD_0 (the tracer refused it: "material 0 has a
    texture, which needs corner_uvs"): a warning, and the texel at UV (0, 0) colours it, as an OBJ
    corner without vt."""
    from thurston_addon import render, spaces

    write_texture(tmp_path / "tex.png")
    (tmp_path / "buf.bin").write_bytes(TRIANGLE.tobytes() + UV.tobytes())
    path = gltf(tmp_path, "buf.bin", "tex.png")
    tree = json.loads(path.read_text())
    del tree["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"]
    path.write_text(json.dumps(tree))
    with pytest.warns(UserWarning, match="has no texture coordinates"):
        scene = scenes.load_scene_file(path)
    assert render.make_tracer(spaces.load("torus"), scene, threads=1).num_triangles == 1
