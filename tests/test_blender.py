"""The Blender layer in real bpy (5.0.1, background): registration, operators, the THURSTON render
engine, export from the depsgraph, the domain guide, the panorama, errors and background batch
renders. Pixels are compared with independent truths: the core (`thurston render`) fed with mesh
files written here from the Blender data, closed-form distances, and Blender's own conventions."""
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import thurston_addon  # noqa: E402
from thurston_addon import cli, spaces  # noqa: E402
from thurston_addon.blender import export  # noqa: E402
from thurston_addon.blender.engine import ThurstonRenderEngine  # noqa: E402

import blender_helpers as bh  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
THURSTON = Path(sys.executable).with_name("thurston")


def _registered():
    return hasattr(bpy.types.Scene, "thurston")


@pytest.fixture(autouse=True)
def registered(monkeypatch):
    import warnings

    # cli.main replaces warnings.showwarning; put it back after each test
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)
    if not _registered():
        thurston_addon.register()
    yield


def engine_ids():
    """The render engines Blender accepts: its error message for an unknown engine lists them."""
    with pytest.raises(TypeError) as info:
        bpy.context.scene.render.engine = "NO_SUCH_ENGINE"
    return info.value.args[0]


def cli_render(tmp_path, toml, space, name, size=(bh.W, bh.H), quality="draft", projection="perspective", extra=()):
    out = tmp_path / f"{name}.exr"
    code = cli.main(["render", "--space", space, "--scene", str(toml), "--size", f"{size[0]}x{size[1]}",
                     "--quality", quality, "--projection", projection, "--threads", "2", "--out", str(out), *extra])
    assert code == 0
    return bh.read_exr(out)


def close(a, b, tol=1e-4):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert a.shape == b.shape
    err = np.abs(a - b) / (1 + np.abs(b))
    assert err.max() < tol, f"max relative difference {err.max():.3g} at {np.unravel_index(err.argmax(), err.shape)}"


# --- 1. registration ---------------------------------------------------------------------------------
def test_register_unregister_twice():
    if _registered():
        thurston_addon.unregister()
    try:
        for _ in range(2):
            thurston_addon.register()
            assert _registered()
            assert ThurstonRenderEngine.is_registered
            assert "THURSTON" in engine_ids()
            bpy.context.scene.render.engine = "THURSTON"
            assert hasattr(bpy.ops.thurston, "render_view")
            bpy.context.scene.render.engine = "BLENDER_EEVEE"
            thurston_addon.unregister()
            assert not _registered()
            left = [n for n in dir(bpy.types) if n.startswith("THURSTON_") or n.startswith("Thurston")]
            assert left == []
            assert not ThurstonRenderEngine.is_registered
            assert "THURSTON" not in engine_ids()
    finally:
        if not _registered():
            thurston_addon.register()


# --- a small scene used by several tests ---------------------------------------------------------------
def build_scene(space="torus", scale=1.0, rotation=(1.45, 0.08, 0.25)):
    """Boxes of different colours (one emissive) and a point light around a camera at the origin,
    everything well inside the domain (torus: the unit cube; poincare: chart radius < 0.32)."""
    sc = bh.fresh_scene(space, scale)
    s = scale
    bh.box("Red", 0.12 * s, (0.04 * s, 0.22 * s, 0.03 * s), color=(0.9, 0.2, 0.1), rotation=(0.3, 0.2, 0.1))
    bh.box("Lamp", (0.06 * s, 0.05 * s, 0.08 * s), (-0.1 * s, 0.2 * s, -0.05 * s), color=(0.1, 0.1, 0.1), emission=(0.2, 0.9, 0.4), strength=2.0)
    bh.box("Floor", (0.5 * s, 0.5 * s, 0.02 * s), (0, 0.1 * s, -0.15 * s), color=(0.5, 0.5, 0.7))
    bh.point_light((0.05 * s, 0.05 * s, 0.1 * s), energy=3.0, color=(1.0, 0.9, 0.8))
    bh.camera((0, -0.05 * s, 0), rotation, lens=35.0)
    return sc


# --- 2. renders through every path equal the core's render of the same scene as files ------------------
@pytest.mark.parametrize("space,scale", [("torus", 1.0), ("poincare", 2.0)])
def test_operators_and_f12_match_core(tmp_path, space, scale):
    sc = build_scene(space, scale)
    toml = bh.write_scene_files(sc, tmp_path, scale)
    truth = cli_render(tmp_path, toml, space, "truth")
    color = bh.rgb(truth)
    assert color.max() > 0.05 and np.ptp(color) > 0.05  # not a blank image

    assert bpy.ops.thurston.render_view() == {"FINISHED"}
    close(bh.image_pixels(bpy.data.images["Thurston View"])[..., :3], color)

    chans = bh.f12(sc, tmp_path / "f12.exr")
    close(bh.rgb(chans, "ViewLayer.Combined."), color)

    # preview: same size here (48 px < 320), quality 'preview'
    prev = bh.rgb(cli_render(tmp_path, toml, space, "prev", quality="preview"))
    assert bpy.ops.thurston.preview() == {"FINISHED"}
    close(bh.image_pixels(bpy.data.images["Thurston Preview"])[..., :3], prev)

    # panorama: Blender's equirect image centre looks along world -X, up +Z
    sc.thurston.panorama_width = 32
    pano = bh.rgb(cli_render(tmp_path, toml, space, "pano", size=(32, 16), projection="equirect",
                             extra=["--camera-forward=-1,0,0", "--camera-up=0,0,1"]))
    assert bpy.ops.thurston.bake_panorama() == {"FINISHED"}
    close(bh.image_pixels(bpy.data.images["Thurston Panorama"])[..., :3], pano)
