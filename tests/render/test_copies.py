"""The copies of an object that reach the domain: the box screen (compilation._box_verdict, which
judges a copy by the corners of the object's chart box where the face tests are linear) keeps and
drops exactly what testing every vertex does, for objects inside, across faces and far out, in the
geometries where it applies."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from thurston_addon import spaces
from thurston_addon.render import compilation
from thurston_addon.scenes import SceneObject


@pytest.mark.parametrize("space_id", ["torus", "quarter_turn", "poincare", "seifert_weber", "nil", "sol"])
def test_the_box_screen_keeps_what_every_vertex_keeps(space_id, monkeypatch):
    space = spaces.load(space_id)
    C = space.domain.covectors()
    C = C / np.linalg.norm(C, axis=1)[:, None]
    reach = np.max(np.abs(space.domain.vertices))
    rng = np.random.default_rng(7)
    ball = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    screened = 0
    for k in range(24):
        centre = rng.uniform(-0.9, 0.9, 3) * reach
        radius = reach * rng.choice([0.05, 0.3, 0.8])
        obj = SceneObject(f"b{k}", ball.vertices * radius + centre, ball.faces, (0.5,) * 3)
        if not np.all(space.geometry.in_chart(obj.vertices)):
            continue
        boxed, covered = compilation._object_copies(space, obj, C)
        with monkeypatch.context() as m:
            m.setattr(compilation, "_box_corners", lambda g, x: None)
            every, every_covered = compilation._object_copies(space, obj, C)
        assert np.array_equal(covered, every_covered)
        assert len(boxed) == len(every)
        for (Y, kept, M), (Y2, kept2, M2) in zip(boxed, every):
            assert np.array_equal(kept, kept2) and np.array_equal(M, M2) and np.array_equal(Y, Y2)
        screened += 1
    assert screened >= 6
    assert compilation._box_corners(space.geometry, ball.vertices) is not None
