"""Shared fixtures."""
import pytest


@pytest.fixture
def registered_addon():
    """The add-on registered in this process's bpy (once: Blender keeps it between tests)."""
    import bpy

    import thurston_addon

    if not hasattr(bpy.types.Scene, "thurston"):
        thurston_addon.register()
