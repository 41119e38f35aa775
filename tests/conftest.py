"""Shared fixtures, the `blender` marker on every test that runs bpy, and the built-in presets only."""

import os
from pathlib import Path

import pytest

from thurston_addon import spaces

BLENDER_TESTS = Path(__file__).parent / "blender"
# The tests see the built-in presets only (tests that need a user's folder set it themselves).
os.environ.pop(spaces.SPACE_PATH_VARIABLE, None)


def pytest_collection_modifyitems(items):
    """tests/blender/ and every test using the add-on registered in bpy are `blender` tests."""
    for item in items:
        if BLENDER_TESTS in item.path.parents or "registered_addon" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.blender)


@pytest.fixture
def registered_addon():
    """The add-on registered in this process's bpy (once: Blender keeps it between tests)."""
    import bpy

    import thurston_addon

    if not hasattr(bpy.types.Scene, "thurston"):
        thurston_addon.register()


@pytest.fixture(scope="module")
def space_of():
    """spaces.load, once per space and test module."""
    cache = {}

    def load(sid):
        if sid not in cache:
            cache[sid] = spaces.load(sid)
        return cache[sid]

    return load
