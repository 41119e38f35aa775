"""Thurston: inside views of 3-manifolds modeled on Thurston's geometries.

Importable without Blender: the geometry kernels, the spaces, the scene description and the tracer
work in plain Python. The Blender layer is loaded only by Blender, through `register()`.
"""
__version__ = "0.1.0"
