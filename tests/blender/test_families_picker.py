"""The space picker's named spaces in real bpy: a family's member or SnapPy's manifold by name
(with the name field's suggestions), loaded as the command line loads it, its domain guide drawn
with the domain's vertices; a name that names nothing is one clear error."""

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from support import blender_helpers as bh  # noqa: E402

import thurston_addon  # noqa: E402
from thurston_addon import spaces  # noqa: E402
from thurston_addon.blender import export, properties  # noqa: E402


@pytest.fixture(autouse=True)
def registered(tmp_path, monkeypatch):
    monkeypatch.setenv("THURSTON_CACHE_DIR", str(tmp_path))
    if not hasattr(bpy.types.Scene, "thurston"):
        thurston_addon.register()
    yield


@pytest.mark.parametrize("name", ["flat(amphicosm1)", "lens(7,2)", "snappy:m003(-3,1)"])
def test_a_named_space_is_loaded_and_its_guide_drawn(name):
    sc = bh.fresh_scene("torus")
    s = sc.thurston
    s.space = export.NAMED
    s.space_name = name
    space = export.load_space(s)
    assert space.id == name and space.volume == pytest.approx(spaces.load(name).volume, rel=1e-12)
    assert bpy.ops.thurston.domain_guide() == {"FINISHED"}
    guide = bpy.data.objects["Thurston Domain"]
    points = np.array([tuple(v.co) for v in guide.data.vertices])
    assert len(points) == len(space.domain.vertices)
    assert np.abs(np.sort(points, axis=0) - np.sort(space.domain.vertices, axis=0)).max() < 1e-5


def test_the_name_field_suggests_the_families_and_refuses_unknown_names():
    s = bh.fresh_scene("torus").thurston
    suggested = properties._name_suggestions(s, bpy.context, "")
    assert all(f.example in suggested for f in spaces.FAMILIES) and "snappy:m003(-3,1)" in suggested
    assert properties._name_suggestions(s, bpy.context, "LENS") == ["lens(7,2)"]
    s.space = export.NAMED
    s.space_name = "klein(3)"
    with pytest.raises(export.ExportError, match="names no space"):
        export.load_space(s)
    s.space_name = "lens(7,1)"
    with pytest.raises(export.ExportError, match="not supported"):
        export.load_space(s)
