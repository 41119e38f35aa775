"""The command line, in process (thurston_addon.cli.main) and once through the installed entry point:
listings, renders read back from disk, batch traces against closed forms, and errors (exit code 2
with a one-line message naming the culprit)."""

import json
import math
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from support.outputs import error_line
from support.presets import BUILT_IN, presets

from thurston_addon import cli, render, spaces
from thurston_addon.scenes import default_scene


@pytest.fixture(autouse=True)
def restore_showwarning(monkeypatch):
    # cli.main replaces warnings.showwarning; put it back after each test
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)


def run(argv, capsys):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def read_image(path):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    try:
        spec = inp.spec()
        pixels = inp.read_image(oiio.FLOAT)
        meta = {a.name: a.value for a in spec.extra_attribs}
        return list(spec.channelnames), np.asarray(pixels).reshape(spec.height, spec.width, spec.nchannels), spec, meta
    finally:
        inp.close()


def pixel_ray(space, pos, fwd, up, fov, W, H, i, j):
    """Model origin and direction of the pinhole ray through the centre of pixel (i, j) (E3)."""
    f = np.asarray(fwd, float) / np.linalg.norm(fwd)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    t = math.tan(math.radians(fov) / 2)
    sx = (2 * (j + 0.5) / W - 1) * t
    sy = (1 - 2 * (i + 0.5) / H) * t * H / W
    d = f + sx * r + sy * u
    d /= np.linalg.norm(d)
    g = space.geometry
    X, _, M = space.bring_inside(g.to_model(np.asarray(pos, float)))
    return X, M @ np.append(d, 0.0)


# --- spaces ---------------------------------------------------------------------------------------------
def test_spaces_listing(capsys):
    code, out, _ = run(["spaces"], capsys)
    assert code == 0
    lines = out.strip().split("\n\n")[0].splitlines()  # the presets (the families follow)
    assert len(lines) == len(BUILT_IN)
    for line in lines:
        sid, geom, *description = line.split()
        assert BUILT_IN[sid] == geom and len(description) >= 5  # a one-line description of each
    code, out, _ = run(["spaces", "--json"], capsys)
    assert code == 0
    rows = json.loads(out)
    assert {r["id"]: r["geometry"] for r in rows} == BUILT_IN
    faces = {r["id"]: (r["faces"], r["vertices"]) for r in rows}
    assert faces["torus"] == (6, 8) and faces["poincare"] == (12, 20) and faces["seifert_weber"] == (12, 20)
    assert faces["sixth_turn"] == (8, 12)


def test_entry_point_subprocess():
    exe = Path(sys.executable).parent / "thurston"
    proc = subprocess.run([str(exe), "spaces", "--json"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert {r["id"] for r in json.loads(proc.stdout)} == set(BUILT_IN)
    proc = subprocess.run(
        [str(exe), "render", "--space", "torus", "--passes", "bogus", "--out", "x.exr"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2 and "bogus" in proc.stderr


# --- render ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("sid", presets())
def test_every_preset_renders_its_default_view(tmp_path, capsys, sid):
    """From the command line, each preset's default scene: rays meet it, and the image is not flat."""
    out = tmp_path / f"{sid}.exr"
    code, _, err = run(["render", "--space", sid, "--size", "64x36", "--quality", "draft", "--out", out], capsys)
    assert code == 0, err
    names, pix, _, _ = read_image(out)
    hit = np.isfinite(pix[..., names.index("Z")])
    assert hit.mean() > 0.05
    assert np.ptp(pix[..., :3][hit]) > 0.05


def test_render_png_and_exr(tmp_path, capsys):
    png = tmp_path / "view.png"
    code, out, err = run(["render", "--space", "torus", "--size", "64x36", "--quality", "draft", "--out", png], capsys)
    assert code == 0, err
    assert f"{png}: 64x36 torus;" in out and "rays" in out and "accuracy" in out
    names, pix, spec, _ = read_image(png)
    assert names[:3] == ["R", "G", "B"] and pix.shape == (36, 64, len(names))
    assert str(spec.format) == "uint8"
    assert pix[..., :3].max() > 0.05  # something is lit

    exr = tmp_path / "view.exr"
    code, out, err = run(["render", "--space", "torus", "--size", "64x36", "--quality", "draft", "--out", exr], capsys)
    assert code == 0, err
    names, pix, spec, meta = read_image(exr)
    expected = [
        "R",
        "G",
        "B",
        "Z",
        "Normal.X",
        "Normal.Y",
        "Normal.Z",
        "Position.X",
        "Position.Y",
        "Position.Z",
        "IndexOB",
        "Crossings",
        "Stop",
        *(f"Denoising Albedo.{c}" for c in "RGB"),
        *(f"Denoising Normal.{c}" for c in "XYZ"),
    ]
    assert sorted(names) == sorted(expected)
    assert meta.get("thurston:space") == "torus"
    ch = {n: pix[..., names.index(n)] for n in names}
    # Z is the geodesic depth: the ray of pixel (i, j) traced directly
    space = spaces.load("torus")
    tracer = render.make_tracer(space, default_scene(space))
    cam = space.camera
    checked = 0
    for i, j in ((18, 32), (10, 5), (30, 60), (0, 0)):
        X, D = pixel_ray(space, cam.position, cam.forward, cam.up, cam.fov, 64, 36, i, j)
        o = tracer.trace(X[None], D[None], space.max_distance, space.max_crossings, shade=False)
        assert ch["IndexOB"][i, j] == o["object"][0] and ch["Stop"][i, j] == o["stop"][0]
        assert ch["Crossings"][i, j] == o["crossings"][0]
        if o["stop"][0] == 0:
            checked += 1
            assert ch["Z"][i, j] == pytest.approx(o["depth"][0], rel=1e-6)
            np.testing.assert_allclose([ch[f"Position.{a}"][i, j] for a in "XYZ"], o["position"][0], atol=1e-6)
        else:
            assert np.isinf(ch["Z"][i, j])
    assert checked >= 2
    # the colour of the EXR is linear, the PNG's the sRGB encoding of the same render (draft: same rays)
    srgb = np.clip(
        np.where(ch["R"] <= 0.0031308, 12.92 * ch["R"], 1.055 * np.clip(ch["R"], 0, None) ** (1 / 2.4) - 0.055), 0, 1
    )
    np.testing.assert_allclose(read_image(png)[1][..., 0], srgb, atol=1 / 255 + 1e-6)


def test_render_passes_limit_channels(tmp_path, capsys):
    exr = tmp_path / "few.exr"
    code, _, err = run(
        [
            "render",
            "--space",
            "poincare",
            "--size",
            "16x9",
            "--quality",
            "draft",
            "--passes",
            "depth,object",
            "--out",
            exr,
        ],
        capsys,
    )
    assert code == 0, err
    names, pix, _, _ = read_image(exr)
    assert sorted(names) == ["IndexOB", "Z"]
    assert pix.shape == (9, 16, 2)


def test_render_equirect_and_camera_options(tmp_path, capsys):
    exr = tmp_path / "pano.exr"
    code, out, err = run(
        [
            "render",
            "--space",
            "seifert_weber",
            "--size",
            "32x16",
            "--quality",
            "draft",
            "--projection",
            "equirect",
            "--camera-position",
            "0.1,0,0",
            "--camera-forward",
            "0,1,0",
            "--camera-up",
            "0,0,1",
            "--passes",
            "depth,stop",
            "--out",
            exr,
        ],
        capsys,
    )
    assert code == 0, err
    names, pix, _, _ = read_image(exr)
    assert pix.shape == (16, 32, 2)
    stop = pix[..., names.index("Stop")]
    assert set(np.unique(stop)) <= {0, 1, 2}


def user_space(tmp_path):
    """A flat torus from a box 1 x 1 x 2 (translations by 1, 1, 2)."""
    path = tmp_path / "my.toml"
    path.write_text(
        textwrap.dedent("""
        name = "tall torus"
        geometry = "E3"
        [camera]
        position = [0, 0, 0]
        forward = [0, 0, 1]
        up = [0, 1, 0]
        [[generator]]
        matrix = [[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
        [[generator]]
        matrix = [[1, 0, 0, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]]
        [[generator]]
        matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 2], [0, 0, 0, 1]]
    """)
    )
    return path


def test_render_user_space_file(tmp_path, capsys):
    exr = tmp_path / "mine.exr"
    scene = tmp_path / "plate.toml"
    # a thin plate filling the box's cross-section at z = 0.7 (its copies repeat every 2 along z)
    scene.write_text(
        textwrap.dedent("""
        [[object]]
        primitive = "box"
        center = [0, 0, 0.7]
        size = [0.9, 0.9, 0.02]
    """)
    )
    code, out, err = run(
        [
            "render",
            "--space",
            user_space(tmp_path),
            "--scene",
            scene,
            "--size",
            "9x9",
            "--quality",
            "draft",
            "--fov",
            "30",
            "--passes",
            "depth,object",
            "--out",
            exr,
        ],
        capsys,
    )
    assert code == 0, err
    assert "mine.exr: 9x9 my;" in out
    names, pix, _, _ = read_image(exr)
    z = pix[4, 4, names.index("Z")]
    assert z == pytest.approx(0.69, abs=1e-6)  # straight ahead along +z
    # with the camera turned round, the plate is met after going 2 - 0.71 = 1.29 through the z faces
    exr2 = tmp_path / "back.exr"
    code, out, err = run(
        [
            "render",
            "--space",
            user_space(tmp_path),
            "--scene",
            scene,
            "--size",
            "9x9",
            "--quality",
            "draft",
            "--fov",
            "30",
            "--camera-forward",
            "0,0,-1",
            "--passes",
            "depth",
            "--out",
            exr2,
        ],
        capsys,
    )
    assert code == 0, err
    names, pix, _, _ = read_image(exr2)
    assert pix[4, 4, names.index("Z")] == pytest.approx(1.29, abs=1e-6)


# --- trace ----------------------------------------------------------------------------------------------
def test_trace_against_closed_form(tmp_path, capsys):
    """The torus with one sphere: depths are the first entries into the balls about c + Z^3."""
    centre, rho = np.array([0.1, 0.15, -0.1]), 0.15
    scene = tmp_path / "ball.toml"
    scene.write_text(
        textwrap.dedent(f"""
        [[object]]
        primitive = "sphere"
        center = [{centre[0]}, {centre[1]}, {centre[2]}]
        radius = {rho}
        subdivisions = 5
    """)
    )
    ico = trimesh.creation.icosphere(subdivisions=5, radius=rho)
    F, Vi = ico.faces, ico.vertices
    n = np.cross(Vi[F[:, 1]] - Vi[F[:, 0]], Vi[F[:, 2]] - Vi[F[:, 0]])
    sagitta = rho - np.min(np.abs(np.einsum("ij,ij->i", n, Vi[F[:, 0]])) / np.linalg.norm(n, axis=1))
    rng = np.random.default_rng(11)
    N = 3000
    p = rng.uniform(-0.5, 0.5, size=(N, 3))
    p[: N // 3] += rng.integers(-3, 4, size=(N // 3, 3))  # origins outside the domain are brought in
    d = rng.normal(size=(N, 3))
    d *= rng.uniform(0.5, 3.0, size=(N, 1))  # directions need not be unit
    L = 2.5
    lattice = np.array([[a, b, c] for a in range(-4, 5) for b in range(-4, 5) for c in range(-4, 5)], float)
    centres = centre + lattice
    # closed form: |p + t u - C|^2 = rho^2, with p moved into the cube by a lattice translation
    u = d / np.linalg.norm(d, axis=1)[:, None]
    w = (p - np.round(p))[:, None, :] - centres[None]
    b = np.einsum("nj,nkj->nk", u, w)
    disc = b * b - (np.einsum("nkj,nkj->nk", w, w) - rho * rho)
    inside = np.any(disc > b * b, axis=1) | np.any(np.linalg.norm(w, axis=2) < rho + 1e-3, axis=1)
    with np.errstate(invalid="ignore"):
        t = np.where((disc > 0) & (-b - np.sqrt(np.maximum(disc, 0)) > 0), -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    k = np.argmin(t, axis=1)
    first = t[np.arange(N), k]
    cos = np.sqrt(np.maximum(disc[np.arange(N), k], 0)) / rho
    rays = np.hstack([p, d])[~inside]
    first, cos = first[~inside], cos[~inside]
    np.save(tmp_path / "rays.npy", rays)
    out = tmp_path / "hits.npz"
    code, stdout, err = run(
        [
            "trace",
            "--space",
            "torus",
            "--scene",
            scene,
            "--rays",
            tmp_path / "rays.npy",
            "--out",
            out,
            "--max-distance",
            L,
            "--max-crossings",
            200,
        ],
        capsys,
    )
    assert code == 0, err
    assert "hits.npz" in stdout and "rays" in stdout
    hits = np.load(out)
    assert set(hits.files) >= {"depth", "object", "position", "normal", "crossings", "stop"}
    tol = 2 * sagitta / np.maximum(cos, 1e-3) + 1e-6
    hit = (first < L - tol) & (cos > 0.3)
    miss = first > L
    assert hit.sum() > 300 and miss.sum() > 100
    assert np.all(hits["stop"][hit] == 0)
    assert np.all(np.abs(hits["depth"][hit] - first[hit]) <= tol[hit])
    assert np.all(hits["object"][hit] == 0)
    assert np.all(hits["stop"][miss] == 1) and np.all(np.isinf(hits["depth"][miss]))
    # hit positions are chart points in the cube, on the sphere about the centre
    pos = hits["position"][hit]
    assert np.all(np.abs(pos) <= 0.5 + 1e-9)
    r = np.linalg.norm(pos - centre, axis=1)
    assert np.all((r <= rho + 1e-6) & (r >= rho - sagitta - 1e-6))


# --- errors ---------------------------------------------------------------------------------------------
def test_output_exists_untouched(tmp_path, capsys):
    out = tmp_path / "keep.png"
    out.write_bytes(b"precious bytes")
    code, _, err = run(["render", "--space", "torus", "--size", "8x8", "--quality", "draft", "--out", out], capsys)
    assert code == 2
    line = error_line(err)
    assert "keep.png" in line and "--overwrite" in line
    assert out.read_bytes() == b"precious bytes"
    code, _, err = run(
        ["render", "--space", "torus", "--size", "8x8", "--quality", "draft", "--out", out, "--overwrite"], capsys
    )
    assert code == 0, err
    assert out.read_bytes() != b"precious bytes"
    # trace too
    hits = tmp_path / "hits.npz"
    hits.write_bytes(b"old")
    np.save(tmp_path / "rays.npy", np.zeros((2, 6)) + [0, 0, 0, 1, 0, 0])
    code, _, err = run(["trace", "--space", "torus", "--rays", tmp_path / "rays.npy", "--out", hits], capsys)
    assert code == 2 and "hits.npz" in error_line(err)
    assert hits.read_bytes() == b"old"


def bad_space(tmp_path):
    """p4 x Z: a quarter turn about the vertical line through (0.3, 0.1) with the unit lattice. The
    group is discrete but has fixed points: the edges around the axis sum to pi/2, not 2 pi."""
    path = tmp_path / "orbifold.toml"
    path.write_text(
        textwrap.dedent("""
        geometry = "E3"
        [[generator]]
        matrix = [[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
        [[generator]]
        matrix = [[1, 0, 0, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]]
        [[generator]]
        matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1]]
        [[generator]]
        matrix = [[0, -1, 0, 0.4], [1, 0, 0, -0.2], [0, 0, 1, 0], [0, 0, 0, 1]]
    """)
    )
    return path


def test_command_errors(tmp_path, capsys):
    out = tmp_path / "x.exr"
    cases = [
        (["render", "--space", "torus", "--scene", tmp_path / "missing.obj", "--out", out], ["missing.obj"]),
        (["render", "--space", tmp_path / "nospace.toml", "--out", out], ["nospace.toml", "does not exist"]),
        (["render", "--space", "no_such_preset", "--out", out], ["no_such_preset"]),
        (["render", "--space", bad_space(tmp_path), "--size", "8x8", "--out", out], ["orbifold.toml", "2 pi"]),
        (
            ["render", "--space", "seifert_weber", "--size", "8x8", "--camera-position", "2,0,0", "--out", out],
            ["camera"],
        ),
        (["render", "--space", "torus", "--size", "8x8", "--out", tmp_path / "x.bmpx"], ["x.bmpx"]),
        (["render", "--space", "torus", "--size", "8x8", "--out", tmp_path / "nodir" / "x.exr"], ["nodir"]),
    ]
    np.save(tmp_path / "nan.npy", np.array([[0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 1, 0], [0, 0, np.nan, 0, 0, 1.0]]))
    np.save(tmp_path / "shape.npy", np.zeros((4, 3)))
    np.save(tmp_path / "dtype.npy", np.ones((4, 6), np.float32))
    np.save(tmp_path / "zero.npy", np.zeros((4, 6)))
    np.save(tmp_path / "h3.npy", np.array([[1.5, 0, 0, 1, 0, 0.0]]))
    (tmp_path / "junk.npy").write_bytes(b"not numpy")
    for name, words in (
        ("nan.npy", ["nan.npy", "ray 2"]),
        ("shape.npy", ["shape.npy", "(4, 3)"]),
        ("dtype.npy", ["dtype.npy", "float32"]),
        ("zero.npy", ["zero.npy", "zero direction"]),
        ("junk.npy", ["junk.npy"]),
        ("absent.npy", ["absent.npy"]),
    ):
        cases.append((["trace", "--space", "torus", "--rays", tmp_path / name, "--out", tmp_path / "h.npz"], words))
    cases.append(
        (
            ["trace", "--space", "seifert_weber", "--rays", tmp_path / "h3.npy", "--out", tmp_path / "h.npz"],
            ["h3.npy", "ray 0", "outside the chart"],
        )
    )
    for argv, words in cases:
        code, _, err = run(argv, capsys)
        assert code == 2, (argv, err)
        line = error_line(err)
        for w in words:
            assert w in line, (argv, line)
    assert not out.exists() and not (tmp_path / "h.npz").exists()
    assert not list(tmp_path.glob(".*partial*"))


@pytest.mark.parametrize(
    "argv",
    [
        ["render", "--space", "torus", "--passes", "depth,bogus", "--out", "x.exr"],
        ["render", "--space", "torus", "--size", "0x5", "--out", "x.exr"],
        ["render", "--space", "torus", "--camera-position", "1,2", "--out", "x.exr"],
        ["render", "--space", "torus", "--quality", "ultra", "--out", "x.exr"],
        ["frobnicate"],
    ],
)
def test_argument_errors_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.strip()


@pytest.mark.parametrize("option", [["--max-distance", "-1"], ["--max-distance", "0"], ["--max-crossings", "-3"]])
def test_render_bad_limits_exit_2(tmp_path, capsys, option):
    code, _, err = run(["render", "--space", "torus", "--size", "4x4", "--out", tmp_path / "x.png", *option], capsys)
    assert code == 2
    assert "max" in error_line(err)


@pytest.mark.parametrize(
    "option", [["--max-distance", "-1"], ["--max-distance", "nan"], ["--max-distance", "0"], ["--max-crossings", "-3"]]
)
def test_trace_bad_limits_exit_2(tmp_path, capsys, option):
    np.save(tmp_path / "rays.npy", np.array([[0, 0, 0, 1, 0, 0.0]]))
    try:
        code, _, err = run(
            ["trace", "--space", "torus", "--rays", tmp_path / "rays.npy", "--out", tmp_path / "h.npz", *option], capsys
        )
    except ValueError:
        code, err = 1, ""
    assert code == 2
    assert "max" in error_line(err)
    assert not (tmp_path / "h.npz").exists()


# --- bad input that used to end in a traceback ------------------------------------------------------------
TORUS_GENERATORS = """
[[generator]]
matrix = [[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
[[generator]]
matrix = [[1, 0, 0, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]]
[[generator]]
matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1]]
"""


@pytest.mark.parametrize(
    "head,tail,word",
    [
        ('geometry = "E3"\ngenerator = [1, 2]\n', "", "generator"),
        ('geometry = "E3"\ncamera = 5\n', TORUS_GENERATORS, "camera"),
        ('geometry = "E3"\nmax_crossings = "many"\n', TORUS_GENERATORS, "max_crossings"),
        ('geometry = "E3"\nmax_crossings = 2.7\n', TORUS_GENERATORS, "max_crossings"),
        ('geometry = "E3"\nmax_crossings = -5\n', TORUS_GENERATORS, "max_crossings"),
        ('geometry = "E3"\nmax_distance = -3\n', TORUS_GENERATORS, "max_distance"),
        ('geometry = "E3"\n[camera]\nforward = [0, 1, 0]\nup = [0, -3, 0]\n', TORUS_GENERATORS, "parallel"),
    ],
)
@pytest.mark.parametrize("command", ["render", "trace"])
def test_bad_space_file_fields_exit_2(tmp_path, capsys, head, tail, word, command):
    space = tmp_path / "odd.toml"
    space.write_text(head + tail)
    np.save(tmp_path / "rays.npy", np.array([[0, 0, 0, 1, 0, 0.0]]))
    out = tmp_path / ("x.png" if command == "render" else "h.npz")
    extra = ["--size", "4x4"] if command == "render" else ["--rays", tmp_path / "rays.npy"]
    code, _, err = run([command, "--space", space, *extra, "--out", out], capsys)
    assert code == 2, err
    line = error_line(err)
    assert "odd.toml" in line and word in line, line
    assert not out.exists()


@pytest.mark.parametrize("command", ["render", "trace"])
def test_negative_threads_exit_2(tmp_path, capsys, command):
    np.save(tmp_path / "rays.npy", np.array([[0, 0, 0, 1, 0, 0.0]]))
    out = tmp_path / ("x.png" if command == "render" else "h.npz")
    extra = ["--size", "4x4"] if command == "render" else ["--rays", tmp_path / "rays.npy"]
    code, _, err = run([command, "--space", "torus", *extra, "--threads", "-1", "--out", out], capsys)
    assert code == 2, err
    assert "threads" in error_line(err)
    assert not out.exists()


@pytest.mark.parametrize("command", ["render", "trace"])
def test_core_value_error_is_a_clean_error(tmp_path, capsys, monkeypatch, command):
    """Backstop: input the Python checks let through but the C++ core rejects (here: negative
    threads, with the check switched off) ends as `thurston: error:` and exit 2, not a traceback."""
    monkeypatch.setattr(render.Settings, "check", lambda self: None)
    np.save(tmp_path / "rays.npy", np.array([[0, 0, 0, 1, 0, 0.0]]))
    out = tmp_path / ("x.png" if command == "render" else "h.npz")
    extra = ["--size", "4x4"] if command == "render" else ["--rays", tmp_path / "rays.npy"]
    code, _, err = run([command, "--space", "torus", *extra, "--threads", "-1", "--out", out], capsys)
    assert code == 2, err
    assert "threads must be >= 0" in error_line(err)


def test_trace_wrapper_passes_progress_errors_through():
    """render.trace turns the core's ValueError into RenderError, but an exception raised by the
    progress callback is the caller's own and passes through unchanged."""
    space = spaces.load("torus")
    tracer = render.make_tracer(space, default_scene(space))
    X = np.tile([0.0, 0.0, 0.0, 1.0], (4, 1))
    V = np.tile([0.0, 1.0, 0.0, 0.0], (4, 1))
    with pytest.raises(render.RenderError, match="max_crossings"):
        render.trace(tracer, X, V, 5.0, -1)
    with pytest.raises(render.RenderError, match="dtype"):
        render.trace(tracer, X.astype(np.float32), V, 5.0, 3)

    def progress(done, total):
        raise ValueError("mine")

    with pytest.raises(ValueError, match="mine") as info:
        render.trace(tracer, X, V, 5.0, 3, progress=progress)
    assert not isinstance(info.value, render.RenderError)


@pytest.mark.parametrize(
    "option, value, named",
    [("--fog", v, "fog") for v in ("nan", "-0.5", "0", "inf")]
    + [("--light-reach", v, "light reach") for v in ("nan", "-0.5")],
)
def test_render_bad_fog_or_light_reach_exit_2(tmp_path, capsys, option, value, named):
    out = tmp_path / "x.png"
    code, _, err = run(["render", "--space", "torus", "--size", "4x4", option, value, "--out", out], capsys)
    assert code == 2, err
    assert named in error_line(err)
    assert not out.exists()


def test_render_light_reach_is_in_the_summary(tmp_path, capsys):
    out = tmp_path / "x.png"
    code, printed, err = run(
        ["render", "--space", "torus", "--size", "8x6", "--light-reach", "1.5", "--out", out], capsys
    )
    assert code == 0, err
    assert "copies within reach 1.5" in printed


def test_huge_size_is_refused_with_a_message(tmp_path, capsys):
    out = tmp_path / "x.png"
    code, _, err = run(["render", "--space", "torus", "--size", "40000x40000", "--out", out], capsys)
    assert code == 2, err
    assert "40000x40000" in error_line(err)
    assert not out.exists()


def test_render_warns_what_makes_the_image_dark(tmp_path, capsys):
    """A scene without lights, and one whose light is shut in a box: the render says so."""
    box = tmp_path / "scene.toml"
    box.write_text('[[object]]\nprimitive = "box"\ncenter = [0, 0.3, 0]\nsize = [0.2, 0.2, 0.2]\n')
    code, _, err = run(
        [
            "render",
            "--space",
            "torus",
            "--scene",
            str(box),
            "--size",
            "16x9",
            "--quality",
            "draft",
            "--out",
            str(tmp_path / "a.png"),
        ],
        capsys,
    )
    assert code == 0 and "warning: the scene has no lights" in err
    box.write_text(
        box.read_text() + '[[object]]\nprimitive = "box"\ncenter = [0.3, -0.3, 0.3]\nsize = [0.1, 0.1, 0.1]\n'
        "[[light]]\nposition = [0.3, -0.3, 0.3]\n"
    )
    code, _, err = run(
        [
            "render",
            "--space",
            "torus",
            "--scene",
            str(box),
            "--size",
            "16x9",
            "--quality",
            "draft",
            "--out",
            str(tmp_path / "b.png"),
        ],
        capsys,
    )
    assert code == 0 and "warning: no light reaches any surface the camera sees" in err


def test_a_graph_space_renders_in_pseudo_colour_by_default_and_refuses_lambert(tmp_path, capsys):
    """A graph of Gaussians has no light paths: without --shading it renders the normal shading (the
    same image as asked for), saying so; --shading lambert is refused with the reason."""
    common = ["render", "--space", "graph_local", "--size", "32x18", "--quality", "draft"]
    code, _, err = run([*common, "--out", tmp_path / "a.exr"], capsys)
    assert code == 0 and "render in pseudo-colour (here --shading normal)" in err
    code, _, _ = run([*common, "--shading", "normal", "--out", tmp_path / "b.exr"], capsys)
    assert code == 0
    np.testing.assert_array_equal(read_image(tmp_path / "a.exr")[1], read_image(tmp_path / "b.exr")[1])
    code, _, err = run([*common, "--shading", "lambert", "--out", tmp_path / "c.png"], capsys)
    assert code != 0 and "pseudo-colour shadings only" in err
