"""A material's scattering (roughness, metallic, specular, ior) is checked where it is read, within
what the tracer keeps: float32. A specular level or IOR beyond float32's range (inf, 1e39) or an
IOR that float32 rounds to 0 (1e-60) used to pass the scene's checks and reach the core, which
refused it as "material_scattering row 0", naming neither the file nor the material."""

from __future__ import annotations

import numpy as np
import pytest

from thurston_addon import render, spaces
from thurston_addon.scenes import Material, Scene, SceneError, SceneObject, load_scene_file

FLOAT32 = np.finfo(np.float32)


@pytest.mark.parametrize(
    "key, value",
    [("specular", "inf"), ("specular", "1e39"), ("specular", "nan"), ("ior", "inf"), ("ior", "1e39"), ("ior", "1e-60")],
)
def test_scattering_beyond_float32_is_an_error_naming_the_file_and_material(tmp_path, key, value):
    (tmp_path / "scene.toml").write_text(f'[[object]]\nprimitive = "sphere"\n{key} = {value}\n')
    with pytest.raises(SceneError, match=f"scene.toml: object 0: material 'sphere': {key} must be a number"):
        load_scene_file(tmp_path / "scene.toml")


def test_scattering_at_float32_edges_is_what_the_tracer_takes():
    """The largest specular level and the smallest and largest IORs that float32 holds pass the
    scene's checks, and the core (the independent judge of what it can use) takes them."""
    space = spaces.load("torus")
    for specular, ior in ((float(FLOAT32.max), float(FLOAT32.smallest_subnormal)), (0.5, float(FLOAT32.max))):
        material = Material(color=(0.5, 0.5, 0.5), specular=specular, ior=ior)
        triangle = SceneObject(
            "triangle", [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], [[0, 1, 2]], materials=[material], triangle_material=[0]
        )
        tracer = render.make_tracer(space, Scene(objects=[triangle]))
        assert tracer.num_triangles == 1  # the one triangle, kept
