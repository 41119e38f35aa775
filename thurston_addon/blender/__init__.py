"""The Blender layer: settings, panel, domain guide, operators and the render engine. It only
translates between Blender and the Blender-free layers (spaces, scene, render)."""
import bpy

from . import engine, guide, operators, panels, properties

_MODULES = (properties, guide, operators, engine, panels)
_CLASSES = [cls for m in _MODULES for cls in m.CLASSES]


def register():
    for cls in _CLASSES:
        bpy.utils.register_class(cls)
    properties.register()
    engine.register()


def unregister():
    engine.unregister()
    properties.unregister()
    for cls in reversed(_CLASSES):
        bpy.utils.unregister_class(cls)
