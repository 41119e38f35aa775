"""Stereo views against closed forms: the disparity of a small ball in the 3-torus (perspective:
f b (1/d - 1/c), parallel and off-axis; omni-directional stereo: the tangent rays of the eye circle,
2 asin(b / 2d) parallel, and the converged rays' own equation), the parallax of a point at distance d
from eyes a baseline b apart in S3 and H3 (the right triangle's sin(b/2) / tan(d) and
sinh(b/2) / tanh(d)), toe-in's convergence point on both eyes' axes, the two views of a panorama
equal where the pole merge has faded the offset, the eyes in Nil the interocular distance apart,
and an eye whose offset leaves the domain through a turning face against the universal cover."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy import ndimage
from scipy.optimize import brentq
from support.cover import check_depths

from thurston_addon import cli, render, spaces
from thurston_addon.geometries.frames import parallel_transport
from thurston_addon.scenes import Camera, Scene, SceneObject

FORWARD, UP = np.array([1.0, 0, 0]), np.array([0, 0, 1.0])


def ball_ahead(chart_distance, radius=0.01):
    ball = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    return Scene(objects=[SceneObject("ball", ball.vertices + chart_distance * FORWARD, ball.faces, (0.5,) * 3)])


def ball_columns(space, scene, settings, fov=90.0):
    """The ball's centroid column (pixels from the image's left edge) in the left and right views."""
    camera = Camera(np.zeros(3), FORWARD, UP, fov=fov)
    views = render.render_eyes(space, scene, settings, camera)
    return [ndimage.center_of_mass(view.passes["stop"] == 0)[1] + 0.5 for view in views]


def settings(stereo, width, height, projection="perspective"):
    return render.Settings(
        width=width,
        height=height,
        projection=projection,
        samples=1,
        shading="normal",
        max_distance=0.45,
        stereo=stereo,
    )


@pytest.mark.parametrize("mode", ["parallel", "off-axis"])
def test_perspective_disparity_in_the_torus_is_euclidean(mode):
    d, b, c, W = 0.3, 0.1, 0.5, 256
    stereo = render.Stereo(interocular=b, convergence=c, mode=mode)
    left, right = ball_columns(spaces.load("torus"), ball_ahead(d, 0.02), settings(stereo, W, 64), fov=60)
    f = W / 2 / math.tan(math.radians(30))
    expected = f * b * (1 / d - (1 / c if mode == "off-axis" else 0))
    assert abs((left - right) - expected) < 1.0, (left - right, expected)


def omni_column(b, c, d, sign, W):
    """The column at which an omni-directional stereo eye (sign -1 left, +1 right; c None: parallel)
    sees the point at distance d ahead: the longitude whose eye ray (from the circle of radius b/2,
    along the converged direction) passes through it, solved in the plane."""

    def miss(lon):
        side = np.array([-math.sin(lon), math.cos(lon)])
        eye = sign * b / 2 * side
        direction = np.array([math.cos(lon), math.sin(lon)])
        if c is not None:
            direction = c * direction - eye
        to_point = np.array([d, 0.0]) - eye
        return direction[0] * to_point[1] - direction[1] * to_point[0]

    lon = brentq(miss, -0.5, 0.5, xtol=1e-14)
    return (lon / math.pi + 1) / 2 * W


@pytest.mark.parametrize("mode", ["parallel", "off-axis"])
def test_omni_directional_disparity_in_the_torus(mode):
    d, b, c, W = 0.3, 0.1, 0.5, 512
    stereo = render.Stereo(interocular=b, convergence=c, mode=mode)
    left, right = ball_columns(spaces.load("torus"), ball_ahead(d, 0.02), settings(stereo, W, 256, "equirect"))
    converge = None if mode == "parallel" else c
    expected = [omni_column(b, converge, d, sign, W) for sign in (-1, 1)]
    assert abs(left - expected[0]) < 0.5 and abs(right - expected[1]) < 0.5, (left, right, expected)
    if mode == "parallel":  # the eye circle's tangents: 2 asin(b / 2d)
        assert abs((left - right) - 2 * math.asin(b / 2 / d) * W / (2 * math.pi)) < 1.0


@pytest.mark.parametrize(
    "space_id, chart, offset, other",
    [
        # S3 (the Poincare space's chart: gnomonic, chart distance tan d): sin(b/2) / tan(d)
        ("poincare", math.tan, lambda a, d: math.sin(a) / math.tan(d), lambda a, d: a / d),
        # H3 (Klein: tanh d): sinh(b/2) / tanh(d)
        ("seifert_weber", math.tanh, lambda a, d: math.sinh(a) / math.tanh(d), lambda a, d: a / d),
    ],
)
def test_parallax_in_constant_curvature(space_id, chart, offset, other):
    """Eyes b apart, parallel: the point at distance d ahead of the camera makes a right triangle
    (camera, eye, point) with legs b/2 and d; the eye's carried forward is square to the leg to the
    camera, so the point is seen at tan(angle) = offset(b/2, d) from the eye's axis."""
    d, b, W = 0.25, 0.6, 512
    stereo = render.Stereo(interocular=b, mode="parallel")
    left, right = ball_columns(spaces.load(space_id), ball_ahead(chart(d)), settings(stereo, W, 32), fov=120)
    f = W / 2 / math.tan(math.radians(60))
    expected = f * offset(b / 2, d)
    assert abs((left - W / 2) - expected) < 0.5 and abs((right - W / 2) + expected) < 0.5, (left, right, expected)
    assert abs(f * other(b / 2, d) - expected) > 3  # the flat formula would fail


def test_toe_in_eyes_look_at_the_convergence_point():
    c = 0.3
    stereo = render.Stereo(interocular=0.1, convergence=c, mode="toe-in")
    left, right = ball_columns(spaces.load("torus"), ball_ahead(c, 0.02), settings(stereo, 256, 64), fov=60)
    assert abs(left - 128) < 0.5 and abs(right - 128) < 0.5


def test_a_pivot_eye_sees_what_the_camera_sees():
    space, scene = spaces.load("poincare"), ball_ahead(0.2, 0.05)
    camera = Camera(np.zeros(3), FORWARD, UP, fov=60)
    stereo = render.Stereo(interocular=0.2, mode="parallel", pivot="left")
    s = settings(stereo, 48, 27)
    mono = render.render(space, scene, render.Settings(**{**s.__dict__, "stereo": None}), camera)
    left, right = render.render_eyes(space, scene, s, camera)
    assert np.allclose(left.passes["depth"], mono.passes["depth"], rtol=0, atol=1e-12, equal_nan=True)
    assert not np.allclose(right.passes["depth"], mono.passes["depth"], equal_nan=True)


def test_the_panoramas_eyes_agree_where_the_pole_merge_faded_the_offset():
    """Two balls, at altitude 80 degrees (beyond the merge, offset 0) and 0: the rows beyond 75
    degrees are the same in both views, the ball on the horizon is not."""
    d = 0.3
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    high = d * np.array([math.cos(math.radians(80)), 0, math.sin(math.radians(80))])
    scene = Scene(
        objects=[
            SceneObject("high", ball.vertices + high, ball.faces, (0.5,) * 3),
            SceneObject("level", ball.vertices + d * FORWARD, ball.faces, (0.5,) * 3),
        ]
    )
    stereo = render.Stereo(interocular=0.1, pole_merge=(60.0, 75.0))
    W, H = 256, 128
    camera = Camera(np.zeros(3), FORWARD, UP)
    left, right = render.render_eyes(spaces.load("torus"), scene, settings(stereo, W, H, "equirect"), camera)
    rows = (0.5 - (np.arange(H) + 0.5) / H) * 180
    merged = np.abs(rows) > 75
    for name in ("depth", "object", "color"):
        assert np.array_equal(left.passes[name][merged], right.passes[name][merged])
    assert (left.passes["object"][merged] == 0).sum() > 20  # the high ball is there
    level = np.abs(rows) < 10
    assert not np.array_equal(left.passes["object"][level], right.passes["object"][level])


def test_the_eyes_in_nil_are_the_interocular_distance_apart():
    nil = spaces.load("nil")
    g = nil.geometry
    b = 0.3
    s = render.Settings(width=8, height=8, stereo=render.Stereo(interocular=b))
    camera = Camera(np.array([0.05, -0.02, 0.1]), np.array([1.0, 0.3, 0.2]), UP)
    frame = render.camera_frame(nil, camera)
    eyes = [
        render.stereo.eye_view(nil, camera, render.Settings(**{**s.__dict__, "eye": eye}), frame)[1][0]
        for eye in render.EYES
    ]
    assert abs(g.distance(eyes[0][None], eyes[1][None])[0] - b) < 1e-9


def test_an_eye_beyond_a_turning_face_sees_what_the_universal_cover_shows():
    """The quarter-turn space: the camera just below the top face, its right direction up, so the
    right eye's offset leaves through the face glued with a quarter turn; its depths against the
    geodesics of the unmoved eye marched in the universal cover."""
    space = spaces.load("quarter_turn")
    g = space.geometry
    centres = np.array([[0.3, 0.1, -0.2], [0.25, -0.2, 0.3], [-0.3, 0.3, 0.0]])
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.12)
    scene = Scene(
        objects=[SceneObject(f"b{i}", ball.vertices + c, ball.faces, (0.5,) * 3) for i, c in enumerate(centres)]
    )
    camera = Camera(np.array([0.0, 0.0, 0.46]), FORWARD, np.array([0, 1.0, 0]), fov=100)
    b = 0.2
    stereo = render.Stereo(interocular=b, mode="parallel")
    s = render.Settings(width=24, height=16, samples=1, shading="normal", max_distance=2.0, stereo=stereo)
    right = render.render(space, scene, render.Settings(**{**s.__dict__, "eye": "right"}), camera)
    X, (f, r, u) = render.camera_frame(space, camera)
    P, _, F = parallel_transport(g, X[None], r[None], b / 2, np.stack([f, r, u])[None])
    assert g.to_chart(P)[0][2] > 0.5  # outside the domain: beyond the top face
    a, bb, c = render.view_directions(camera, s)
    D = (a[..., None] * F[0, 0] + bb[..., None] * F[0, 1] + c[..., None] * F[0, 2]).reshape(-1, 4)
    out = {k: np.ravel(right.passes[k]) for k in ("stop", "depth")}
    outer = inner = np.full(len(centres), 0.12)
    inner = inner * math.cos(math.radians(20))  # the icosphere's inscribed radius, generously
    compared, hits = check_depths(g, space, out, np.broadcast_to(P[0], D.shape), D, 2.0, centres, outer, inner)
    assert compared > 200 and hits > 50, (compared, hits)


def test_cli_writes_a_top_bottom_panorama_marked_as_stereo(tmp_path):
    import OpenImageIO as oiio

    out = tmp_path / "ods.png"
    code = cli.main(
        ["render", "--space", "torus", "--size", "64x32", "--projection", "equirect", "--quality", "draft"]
        + ["--shading", "normal", "--stereo", "--interocular", "0.1", "--out", str(out)]
    )
    assert code == 0
    image = oiio.ImageInput.open(str(out))
    spec = image.spec()
    image.close()
    assert (spec.width, spec.height) == (64, 64)  # 2:1 per eye, left on top
    assert spec.getattribute("GPano:ProjectionType") == "equirectangular"
    assert spec.getattribute("GSpherical:StereoMode") == "top-bottom"
    assert int(spec.getattribute("GPano:FullPanoWidthPixels")) == 64
    exr = tmp_path / "ods.exr"  # the same packet, as a string attribute of the EXR
    assert (
        cli.main(
            ["render", "--space", "torus", "--size", "16x8", "--projection", "equirect", "--quality", "draft"]
            + ["--shading", "normal", "--stereo", "--out", str(exr)]
        )
        == 0
    )
    image = oiio.ImageInput.open(str(exr))
    packet = image.spec().getattribute("XML:com.adobe.xmp")
    image.close()
    assert 'GSpherical:StereoMode="top-bottom"' in packet and 'GPano:ProjectionType="equirectangular"' in packet


def test_cli_writes_two_files_and_refuses_stereo_options_alone(tmp_path, capsys):
    out = tmp_path / "pair.exr"
    args = ["render", "--space", "torus", "--size", "32x18", "--quality", "draft", "--shading", "normal"]
    assert cli.main(args + ["--stereo", "--stereo-layout", "separate", "--out", str(out)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pair_L.exr", "pair_R.exr"]
    assert cli.main(args + ["--interocular", "0.1", "--out", str(tmp_path / "mono.png")]) == 2
    assert "--interocular needs --stereo" in capsys.readouterr().err
    assert cli.main(args + ["--stereo", "--interocular", "-1", "--out", str(tmp_path / "bad.png")]) == 2
    assert "interocular distance must be a positive number" in capsys.readouterr().err
