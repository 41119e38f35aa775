"""Thurston: inside views of 3-manifolds modeled on Thurston's geometries.

Importable without Blender: the geometry kernels, the spaces, the scene description and the tracer
work in plain Python. Blender calls `register()` / `unregister()`, which load the Blender layer
(`engine`, `properties`, `export`, `results`, `guide`, `batch`, `operators/`, `panels/`) only then.
"""
__version__ = "0.1.0"


def register():
    import bpy

    from . import engine, properties, results

    for cls in _classes():
        bpy.utils.register_class(cls)
    properties.register()
    results.register()
    engine.register()


def unregister():
    import bpy

    from . import engine, properties, results

    engine.unregister()
    results.unregister()
    properties.unregister()
    for cls in reversed(_classes()):
        bpy.utils.unregister_class(cls)


def _classes():
    from . import engine, operators, panels, properties

    return [*properties.CLASSES, *operators.CLASSES, *engine.CLASSES, *panels.CLASSES]
