"""Denoising (Intel Open Image Denoise through pyoidn) and its guides: the albedo pass against the
materials' known base colours (plain and textured), the guide normal against the sphere's closed
form in the camera's frame (E3 directly; S3 across a face of the Poincaré space, the frame carried
back by closed-form parallel transport in the model), the denoiser's gain against a converged
reference, the binding's absence, and OIDN's libtbb beside the core's in either import order."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest
import trimesh
from support.textured_quad import texel_centres, textured_quad

from thurston_addon import cli, render, spaces
from thurston_addon.render import denoise as denoise_module
from thurston_addon.scenes import Camera, PointLight, Scene, SceneObject

pytest.importorskip("pyoidn")


def sphere(centre, radius, color=(0.2, 0.5, 0.9)):
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    normals = (mesh.vertices / radius)[mesh.faces]
    return SceneObject("sphere", mesh.vertices + centre, mesh.faces, color=np.array(color), corner_normals=normals)


def camera_space(frame, N):
    """(right, up, back) components of model tangent vectors N at the camera, Euclidean form (E3, S3)."""
    _, (f, r, u) = frame
    return np.stack([N @ r, N @ u, -(N @ f)], axis=-1)


# --- albedo ----------------------------------------------------------------------------------------
def test_albedo_is_the_base_colour_and_zero_on_misses():
    torus = spaces.load("torus")
    colour = (0.2, 0.5, 0.9)
    scene = Scene(
        objects=[sphere(np.array([0.25, 0.0, 0.0]), 0.1, colour)], lights=[PointLight(np.zeros(3), np.ones(3), 0.3)]
    )
    camera = Camera(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), fov=60)
    result = render.render(torus, scene, render.Settings(width=48, height=27, samples=4, max_distance=0.45), camera)
    p = result.passes
    whole = p["alpha"] == 1  # with transparent off alpha is 1: use the hits of all samples instead
    hit = np.isfinite(p["depth"])
    inner = hit & np.all(p["albedo"] > 0, axis=-1)
    assert whole.all() and inner.sum() > 50
    # pixels whose samples all met the sphere hold its colour exactly; misses hold 0
    full = np.all(np.abs(p["albedo"] - np.array(colour, np.float32)) < 1e-6, axis=-1)
    assert full.sum() > 0.8 * hit.sum()
    centre_miss = ~hit & np.all(p["albedo"] == 0, axis=-1)
    assert centre_miss.sum() > 0.8 * (~hit).sum()


def test_albedo_of_a_texture_and_a_plain_material():
    """A quad at x = 0.2 facing the camera: triangle 0 has a 4x4 texture (texel centres sample the
    texel), triangle 1 a plain colour; the albedo is the texel's and the colour's, lit or not."""
    torus = spaces.load("torus")
    quad, texels, plain = textured_quad()
    scene = Scene(objects=[quad], lights=[PointLight(np.zeros(3), np.ones(3), 0.3)])
    targets, rows, cols, textured = texel_centres()
    g = torus.geometry
    X = g.to_model(np.zeros((len(targets), 3)))
    D = g.normalize_tangent(X, g.tangent_to_model(np.zeros((len(targets), 3)), targets))
    expected = np.where(textured[:, None], texels[rows, cols], plain.color)
    tracer = render.make_tracer(torus, scene, light_reach=0.5)
    for shade in (False, True):
        out = tracer.trace(X, D, 0.45, 20, shade=shade)
        assert out["albedo"].dtype == np.float32
        np.testing.assert_allclose(out["albedo"], expected, rtol=1e-6)


# --- the guide normal ------------------------------------------------------------------------------
def test_guide_normal_of_a_sphere_in_e3_is_its_camera_space_normal():
    torus = spaces.load("torus")
    C, R = np.array([0.25, 0.03, -0.02]), 0.1
    camera = Camera(np.zeros(3), np.array([1.0, 0.2, 0.1]), np.array([0, 0.3, 1.0]), fov=60)
    settings = render.Settings(width=48, height=27, samples=1, max_distance=0.45)
    p = render.render(torus, Scene(objects=[sphere(C, R)]), settings, camera).passes
    hit = np.isfinite(p["depth"]) & (p["crossings"] == 0)
    assert hit.sum() > 100
    n = p["position"][hit] - C  # the sphere's closed-form normal at the hit
    n /= np.linalg.norm(n, axis=1)[:, None]
    frame = render.camera_frame(torus, camera)
    expected = camera_space(frame, np.concatenate([n, np.zeros((len(n), 1))], axis=1))
    got = p["guide_normal"][hit]
    assert np.degrees(np.arccos(np.clip(np.sum(got * expected, axis=1), -1, 1))).max() < 1.0
    assert np.all(p["guide_normal"][~np.isfinite(p["depth"])] == 0)
    # Blender's camera space: a sphere's visible side faces the camera (+Z, back)
    assert np.all(got[:, 2] > 0)


def test_guide_normal_across_a_face_of_the_poincare_space_is_carried_back():
    """A sphere about the domain's centre, seen through a face from a camera looking away from it:
    the copy met lies across the face, whose pairing turns by pi/5. Truth: the hit's cover point at
    its depth along the camera's geodesic, the copy's centre among the pairings' images, the normal
    of the geodesic sphere there, parallel transport back to the camera in S3's model (the part
    along the great circle turns with its tangent, the part normal to its plane stays)."""
    space = spaces.load("poincare")
    r = 0.08
    c = np.asarray(space.domain.covectors(), float)[0, :3]
    n = c / np.linalg.norm(c)  # towards the centre of face 0
    up = np.cross(n, [0.3, 1.0, 0.1])
    up /= np.linalg.norm(up)
    camera = Camera(0.15 * n, n + 0.05 * up, up, fov=70)
    settings = render.Settings(width=48, height=27, samples=1)
    p = render.render(space, Scene(objects=[sphere(np.zeros(3), r)]), settings, camera).passes
    hit = (np.isfinite(p["depth"]) & (p["crossings"] == 1)).ravel()
    assert hit.sum() > 80
    frame = render.camera_frame(space, camera)
    X0, _ = frame
    _, D = render.camera_rays(space, camera, settings, render.CENTRE, frame=frame)
    D = np.asarray(D, float)[hit]
    d = p["depth"].ravel()[hit][:, None]
    Y = np.cos(d) * X0 + np.sin(d) * D  # the hit in the cover
    T = -np.sin(d) * X0 + np.cos(d) * D
    pairings = [np.asarray(f.pairing, float) for f in space.domain.faces]
    O = np.array([0, 0, 0, 1.0])
    centres = np.array([M @ O for M in pairings])
    radius = np.arctan(r)  # the chart sphere about the chart's centre is a geodesic sphere
    gap = np.abs(np.arccos(np.clip(Y @ centres.T, -1, 1)) - radius)
    assert np.all(gap.min(axis=1) < 2e-3)  # each hit lies on one copy's sphere
    Cc = centres[np.argmin(gap, axis=1)]
    N = -(Cc - np.sum(Cc * Y, axis=1)[:, None] * Y)  # outward: away from the centre
    N /= np.linalg.norm(N, axis=1)[:, None]
    along = np.sum(N * T, axis=1)[:, None]
    back = along * D + (N - along * T)
    expected = camera_space(frame, back)
    got = p["guide_normal"].reshape(-1, 3)[hit]
    angles = np.degrees(np.arccos(np.clip(np.sum(got * expected, axis=1), -1, 1)))
    assert angles.max() < 1.5, angles.max()
    # without the pairing's turn the frame would be off by up to pi/5 about the ray
    assert np.all(got[:, 2] > 0)


# --- the denoiser --------------------------------------------------------------------------------
def path_traced(samples, seed, denoise=False):
    """A lit ball filling the view, lit by an emissive quad (one light sample) and one bounce: noisy
    at a few samples per pixel."""
    space = spaces.load("torus")
    ball = sphere(np.array([0.28, 0.0, 0.0]), 0.12, (0.8, 0.8, 0.8))
    quad = np.array([[0.2, -0.05, 0.4], [0.3, -0.05, 0.4], [0.3, 0.05, 0.4], [0.2, 0.05, 0.4]])
    lamp = SceneObject("lamp", quad, np.array([[0, 2, 1], [0, 3, 2]]), color=np.ones(3), emission=np.full(3, 20.0))
    camera = Camera(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), fov=40)
    settings = render.Settings(
        width=64, height=36, samples=samples, seed=seed, bounces=1, light_samples=1, denoise=denoise
    )
    return render.render(space, Scene(objects=[ball, lamp]), settings, camera)


def test_denoise_reduces_the_error_against_a_converged_reference_and_keeps_flat_means():
    reference = path_traced(64, seed=1000).passes["color"]
    result = path_traced(4, seed=0, denoise=True)
    p = result.passes
    assert result.stats["denoised"] and "denoised" in result.summary()
    rms_noisy = np.sqrt(np.mean((p["noisy"] - reference) ** 2))
    rms_denoised = np.sqrt(np.mean((p["color"] - reference) ** 2))
    print(f"RMS against the reference: noisy {rms_noisy:.4f}, denoised {rms_denoised:.4f}")
    # measured: 1.96 -> 0.50 (the reference's own noise at 64 samples is part of what remains)
    assert rms_denoised < rms_noisy / 3
    # regions without edges: pixels whose 5x5 neighbourhood is all the ball
    obj = p["object"]
    flat = np.zeros(obj.shape, bool)
    for i in range(2, obj.shape[0] - 2):
        for j in range(2, obj.shape[1] - 2):
            flat[i, j] = obj[i, j] == 0 and np.all(obj[i - 2 : i + 3, j - 2 : j + 3] == 0)
    assert flat.sum() > 200
    mean, truth = p["color"][flat].mean(axis=0), reference[flat].mean(axis=0)
    # the 4-sample image's own flat mean is off by up to 7% (seeds 0-40: -6.8% to +0.9%), the
    # denoised one by up to 4.7%: the denoiser keeps the mean within the samples' own noise
    assert np.all(np.abs(mean - truth) <= 0.06 * truth), (mean, truth)


def test_denoise_on_the_command_line_writes_the_noisy_image(tmp_path):
    out = tmp_path / "d.exr"
    code = cli.main(["render", "--space", "torus", "--size", "32x18", "--samples", "4", "--denoise", "--out", str(out)])
    assert code in (0, None)
    import OpenImageIO as oiio

    names = oiio.ImageInput.open(str(out)).spec().channelnames
    for prefix in ("Noisy Image.", "Denoising Albedo.", "Denoising Normal."):
        assert any(n.startswith(prefix) for n in names), names


def test_denoise_without_the_binding_names_what_to_install(monkeypatch, capsys):
    import importlib.util

    find = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "pyoidn" else find(name, *a))
    with pytest.raises(render.RenderError, match=r"thurston\[denoise\]"):
        render.Settings(denoise=True).check()
    code = cli.main(["render", "--space", "torus", "--size", "8x8", "--denoise", "--out", "/tmp/never.png"])
    assert code not in (0, None)
    assert "pyoidn" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "pyoidn", None)  # import pyoidn raises ImportError
    with pytest.raises(render.RenderError, match="pyoidn"):
        denoise_module.denoise(*(np.zeros((4, 4, 3), np.float32),) * 3)


CHILD = """
import numpy as np
{first}
{second}
from thurston_addon import render, spaces
from thurston_addon.scenes import default_scene
space = spaces.load("torus")
r = render.render(space, default_scene(space), render.Settings(width=32, height=18, samples=4, bounces=1, denoise=True))
assert r.stats["denoised"] and np.all(np.isfinite(r.passes["color"]))
print("ok")
"""


@pytest.mark.parametrize("order", ["core first", "pyoidn first"])
def test_oidn_and_the_core_share_one_libtbb_in_either_order(order):
    core, oidn = "import thurston_core", "import pyoidn; pyoidn.denoise(np.ones((8, 8, 3), np.float32))"
    first, second = (core, oidn) if order == "core first" else (oidn, core)
    run = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(CHILD.format(first=first, second=second))],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0 and "ok" in run.stdout, run.stderr
