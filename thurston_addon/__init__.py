"""Thurston: inside views of 3-manifolds modeled on Thurston's geometries.

Importable without Blender: the geometry kernels, the spaces, the scene description and the tracer
work in plain Python. Blender calls `register()` / `unregister()`, which load the Blender layer
(`blender/`, `operators/`, `panels/`) only then.
"""

__version__ = "0.1.0"


def register():
    from .blender import registration

    registration.register()


def unregister():
    from .blender import registration

    registration.unregister()
