"""The mesh files trimesh reads: PLY, STL and glTF/GLB."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..files import reference_folders
from .gltf import gltf_base_textures, gltf_parts, gltf_resolver, gltf_scattering
from .model import DEFAULT_COLOR, Material, SceneError, SceneObject


def read_trimesh_file(path: Path, folders: tuple[Path, ...] | None = None) -> list[SceneObject]:
    """Meshes of PLY, STL and glTF/GLB files with their vertex normals where the file has them
    (else flat shading), glTF's TEXCOORD_0 and base colour textures; the files a glTF refers to are
    read from `folders` (files.reference_folders; default: the file's own folder)."""
    import trimesh

    folders = folders or reference_folders(path)
    header, binary = gltf_parts(path, folders)  # (first: its own errors are clearer than the reader's)
    loaded = trimesh.load(str(path), force="scene", process=False, resolver=gltf_resolver(path, folders))
    order = {str(n.get("name", i)): i for i, n in enumerate(header.get("nodes", []))}
    textures = gltf_base_textures(path, header, binary, folders)
    out = []
    for node in sorted(loaded.graph.nodes_geometry, key=lambda n: order.get(n, len(order))):
        transform, geom_name = loaded.graph[node]
        mesh = loaded.geometry[geom_name]
        if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
            continue
        F = np.asarray(mesh.faces)
        V = trimesh.transform_points(np.asarray(mesh.vertices, dtype=np.float64), transform)
        normals = uvs = None
        if "vertex_normals" in mesh._cache:  # given by the file; trimesh would make up smooth ones
            # normals are covectors: they move by the inverse transpose of the linear part
            N = np.asarray(mesh.vertex_normals, np.float64) @ np.linalg.inv(np.asarray(transform)[:3, :3])
            normals = N[F]
        uv = getattr(mesh.visual, "uv", None)
        if uv is not None and len(uv) == len(mesh.vertices):
            uvs = np.asarray(uv, np.float64)[F]
        color, emission = _trimesh_material(mesh)
        material = getattr(mesh.visual, "material", None)
        texture = textures.get(getattr(material, "name", None))
        if texture is not None and uvs is None:
            warnings.warn(
                f"{path}: object {str(node)!r}: its material's texture has no texture coordinates (TEXCOORD_0): "
                "the texel at UV (0, 0) colours it",
                stacklevel=2,
            )
        name = str(getattr(material, "name", ""))
        try:
            materials = [Material(color, emission, texture, name=name, **gltf_scattering(material))]
            out.append(
                SceneObject(
                    str(node), V, F, color, emission, corner_normals=normals, corner_uvs=uvs, materials=materials
                )
            )
        except SceneError as exc:
            raise SceneError(f"{path}: {exc}") from None
    return out


def _trimesh_material(mesh):
    visual = mesh.visual
    color, emission = np.array(DEFAULT_COLOR), np.zeros(3)
    material = getattr(visual, "material", None)
    if material is not None:
        base = getattr(material, "baseColorFactor", None)
        if base is None:
            base = getattr(material, "diffuse", None)
        if base is not None:
            color = np.asarray(base)[:3] / (255.0 if np.asarray(base).dtype.kind in "ui" else 1.0)
        emissive = getattr(material, "emissiveFactor", None)
        if emissive is not None:
            emission = np.asarray(emissive, dtype=np.float64)[:3]
    elif getattr(visual, "kind", None) in ("face", "vertex"):
        rgba = visual.face_colors if visual.kind == "face" else visual.vertex_colors
        color = np.asarray(rgba, dtype=np.float64)[:, :3].mean(axis=0) / 255.0
    return color, emission
