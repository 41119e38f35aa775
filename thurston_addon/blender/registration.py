"""The add-on's registration with Blender: its classes, scene and view-layer settings, handlers."""

import bpy

from .. import operators, panels
from . import engine, properties, results


def register():
    for cls in _classes():
        bpy.utils.register_class(cls)
    properties.register()
    results.register()
    engine.register()


def unregister():
    engine.unregister()
    results.unregister()
    properties.unregister()
    for cls in reversed(_classes()):
        bpy.utils.unregister_class(cls)


def _classes():
    return [*properties.CLASSES, *operators.CLASSES, *engine.CLASSES, *panels.CLASSES]
