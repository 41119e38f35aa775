"""What trimesh does not read of a glTF/GLB file: its JSON and binary chunk, its materials' base
colour textures and their metallic-roughness factors."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from ..files import check_reference
from .model import SceneError, checked_texture


def gltf_parts(path: Path, folders: tuple[Path, ...]) -> tuple[dict, bytes]:
    """A glTF/GLB file's JSON and its binary chunk (b"" for .gltf); ({}, b"") for other files. Its
    external buffers are checked where they lie (`folders`: files.reference_folders)."""
    if path.suffix.lower() not in (".glb", ".gltf"):
        return {}, b""
    data = path.read_bytes()
    binary = b""
    if data[:4] == b"glTF":  # binary: 12-byte header, the JSON chunk (length, type, data), the BIN chunk
        if len(data) < 20:
            raise SceneError(f"{path}: the GLB file ends inside its header ({len(data)} bytes)")
        length = struct.unpack_from("<I", data, 12)[0]
        binary = data[28 + length :]
        data = data[20 : 20 + length]
    try:
        header = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: its JSON is not UTF-8 text (byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise SceneError(f"{path}: its JSON is not valid: {exc.msg} (line {exc.lineno}, column {exc.colno})") from None
    if not isinstance(header, dict):
        raise SceneError(f"{path}: the glTF JSON is not an object")
    # the buffers trimesh's reader opens: regular files within the size limit (a FIFO would block it)
    buffers = header.get("buffers", [])
    for k, buffer in enumerate(buffers if isinstance(buffers, list) else []):
        uri = buffer.get("uri") if isinstance(buffer, dict) else None
        if isinstance(uri, str) and not uri.startswith("data:"):
            check_reference(path.parent / uri, folders, f"{path}: buffer {k}", SceneError, "mesh file")
    return header, binary


def gltf_base_textures(path: Path, header: dict, binary: bytes, folders: tuple[Path, ...]) -> dict[str, np.ndarray]:
    """Material name -> its base colour texture (linear), read here since trimesh needs Pillow
    for images. Materials are matched to trimesh's by name, so unnamed ones get no texture."""
    import base64
    import tempfile

    from ..images import read_texture

    out = {}
    for material in header.get("materials", []):
        info = material.get("pbrMetallicRoughness", {}).get("baseColorTexture")
        if info is None or "name" not in material:
            continue
        image = header["images"][header["textures"][info["index"]]["source"]]
        uri = image.get("uri", "")
        where = f"{path}: material {material['name']!r}"
        if uri and not uri.startswith("data:"):
            image_file = check_reference(path.parent / uri, folders, f"{where}: image", SceneError, "texture")
            out[material["name"]] = checked_texture(image_file, where)
            continue
        if uri:
            blob = base64.b64decode(uri.split(",", 1)[1])
        else:
            view = header["bufferViews"][image["bufferView"]]
            buffer = header["buffers"][view["buffer"]]
            data = (
                binary
                if "uri" not in buffer
                else (
                    base64.b64decode(buffer["uri"].split(",", 1)[1])
                    if buffer["uri"].startswith("data:")
                    else check_reference(
                        path.parent / buffer["uri"], folders, f"{path}: buffer", SceneError, "mesh file"
                    ).read_bytes()
                )
            )
            start = view.get("byteOffset", 0)
            blob = data[start : start + view["byteLength"]]
        suffix = {"image/png": ".png", "image/jpeg": ".jpg"}.get(image.get("mimeType", ""), ".png")
        with tempfile.TemporaryDirectory() as folder:  # OpenImageIO's Python API reads files
            file = Path(folder) / f"texture{suffix}"
            file.write_bytes(blob)
            try:
                out[material["name"]] = read_texture(file)
            except ValueError:
                raise SceneError(f"{where}: its base colour image cannot be decoded") from None
    return out


def gltf_resolver(path: Path, folders: tuple[Path, ...]):
    """trimesh's resolver for the files a glTF refers to, under the same rule as every file a scene
    refers to (check_reference), and its errors in those words (trimesh's own resolver reads
    anywhere or refuses in its internals' words)."""
    import trimesh

    class SceneFolderResolver(trimesh.resolvers.Resolver):
        def __init__(self):
            pass

        def get(self, name: str) -> bytes:
            return check_reference(path.parent / name, folders, f"{path}: file", SceneError, "mesh file").read_bytes()

        def write(self, name, data):
            raise SceneError(f"{path}: reading a mesh file writes nothing ({name!r})")

        def namespaced(self, namespace):
            return gltf_resolver(path.parent / namespace / path.name, folders)

        def keys(self):
            return iter(())

    return SceneFolderResolver()


def gltf_scattering(material) -> dict:
    """A glTF material's metallic and roughness factors (absent: 1, as the format says) over its
    dielectric's normal reflectance 0.04 (IOR 1.5 at Blender's specular level 0.5); Lambert for
    the other formats' materials."""
    from trimesh.visual.material import PBRMaterial

    if not isinstance(material, PBRMaterial):
        return {}
    metallic, roughness = material.metallicFactor, material.roughnessFactor
    return dict(
        metallic=1.0 if metallic is None else float(metallic),
        roughness=1.0 if roughness is None else float(roughness),
        specular=0.5,
        ior=1.5,
    )
