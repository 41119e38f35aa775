"""Denoising in Blender (real bpy 5.0.1): the engine's Denoise option denoises with the Open Image
Denoise library Blender ships, the render statistics say so, and the view layer's Denoising Data
writes Denoising Albedo, Denoising Normal and Noisy Image, filled."""

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.usefixtures("registered_addon")

from support import blender_helpers as bh  # noqa: E402

from thurston_addon.blender import export  # noqa: E402


def test_denoise_option_and_denoising_data_passes(tmp_path):
    assert export.blender_denoiser() is not None  # Blender's own OIDN (bpy/lib)
    sc = bh.fresh_scene("torus", size=(40, 24))
    bh.box("Red", 0.15, (0.1, 0.3, 0.05), color=(0.9, 0.2, 0.1))
    bh.box("Floor", (0.8, 0.8, 0.02), (0, 0.2, -0.12), color=(0.5, 0.5, 0.7))
    bh.point_light((0.05, 0.05, 0.1), energy=3.0)
    bh.camera((0, -0.1, 0), lens=30.0)
    sc.thurston.samples = 4
    sc.thurston.use_denoising = True
    sc.view_layers[0].thurston.denoising_store_passes = True
    ch = bh.f12(sc, tmp_path / "denoised.exr")
    assert sc.thurston.stats.denoised and "denoised" in sc.thurston.stats.summary
    albedo = bh.rgb(ch, "ViewLayer.Denoising Albedo.")
    normal = np.stack([ch[f"ViewLayer.Denoising Normal.{a}"] for a in "XYZ"], axis=-1)
    noisy = bh.rgb(ch, "ViewLayer.Noisy Image.")
    combined = bh.rgb(ch, "ViewLayer.Combined.")
    # the red box's colour where only it is seen: its base colour, dimmed alike in every channel
    # under the Principled BSDF's specular layer (the diffuse albedo the shading uses)
    base = np.array([0.9, 0.2, 0.1], np.float32)
    ratio = albedo / base
    red = (albedo[..., 0] > 0.5) & np.all(np.abs(ratio - ratio[..., :1]) < 1e-4, axis=-1)
    assert red.sum() > 10
    assert 0.5 < ratio[red, 0].min() and ratio[red, 0].max() <= 1.0 + 1e-6, (ratio[red, 0].min(), ratio[red, 0].max())
    assert np.mean(np.abs(np.linalg.norm(normal[red], axis=-1) - 1) < 1e-3) > 0.8  # edges: averages
    assert np.abs(noisy).sum() > 0 and not np.allclose(noisy, combined)

    sc.thurston.use_denoising = False
    bh.f12(sc, tmp_path / "plain.exr")
    assert not sc.thurston.stats.denoised
