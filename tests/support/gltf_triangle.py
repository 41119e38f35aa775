"""A glTF written by hand (the tests' textured triangle): one triangle with TEXCOORD_0 and a base
colour texture, its buffer and image wherever the given URIs point."""

from __future__ import annotations

import base64

import numpy as np


def embedded(blob: bytes) -> str:
    """A data URI holding `blob`."""
    return "data:application/octet-stream;base64," + base64.b64encode(blob).decode()


def triangle_blob(positions, uvs) -> bytes:
    """The buffer: the three float32 positions (36 bytes), then the three UVs (24 bytes)."""
    return np.asarray(positions, np.float32).tobytes() + np.asarray(uvs, np.float32).tobytes()


def textured_triangle(buffer_uri: str, image_uri: str, top: float, byte_length: int = 60) -> dict:
    """The glTF document; the triangle spans [0, top] in x and y (its POSITION accessor's bounds)."""
    return {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "tri"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "material": 0}]}],
        "materials": [{"name": "painted", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 0}],
        "images": [{"uri": image_uri}],
        "buffers": [{"byteLength": byte_length, "uri": buffer_uri}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 36},
            {"buffer": 0, "byteOffset": 36, "byteLength": 24},
        ],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": 3,
                "type": "VEC3",
                "min": [0, 0, 0],
                "max": [top, top, 0],
            },
            {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"},
        ],
    }
