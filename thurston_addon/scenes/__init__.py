"""Scene description, independent of Blender: meshes with materials (a base colour and an
emission, each optionally an image texture through the mesh's UVs; emissive meshes are lights)
and optional corner normals, point and spot lights (area lights are emissive meshes: flat_light)
and a camera, all in chart coordinates of the space's fundamental domain.

Filled from mesh files (OBJ, PLY, STL, GLB/glTF via trimesh), from a scene file (TOML: objects,
lights, camera), from Blender's depsgraph (the add-on), or built as the default scene of a space.
Objects are numbered in the order given: files in order, inside a file in the file's order.

One job per module: model (the scene's parts and their checks), obj and gltf and trimesh_formats
(each mesh format), meshes (a mesh file by its suffix), scene_file (TOML scene files), default
(a space's default scene).
"""

from .default import default_scene
from .meshes import load_mesh_file
from .model import (
    FLOAT32_MAX,
    SCATTERING,
    Camera,
    Material,
    PointLight,
    Scene,
    SceneError,
    SceneObject,
    checked_instances,
    clean,
    degenerate,
    flat_light,
    singular,
)
from .scene_file import load_scene_file, load_scenes, primitive

__all__ = [
    "FLOAT32_MAX",
    "SCATTERING",
    "Camera",
    "Material",
    "PointLight",
    "Scene",
    "SceneError",
    "SceneObject",
    "checked_instances",
    "clean",
    "default_scene",
    "degenerate",
    "flat_light",
    "load_mesh_file",
    "load_scene_file",
    "load_scenes",
    "primitive",
    "singular",
]
