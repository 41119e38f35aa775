"""OBJ mesh files and their MTL material libraries, read here (trimesh regroups OBJ objects by
material and loses their order)."""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import numpy as np

from ..files import check_reference, reference_folders
from .model import DEFAULT_COLOR, Material, SceneError, SceneObject, colour


def read_obj(path: Path, folders: tuple[Path, ...] | None = None) -> list[SceneObject]:
    """OBJ objects in file order (trimesh regroups OBJ objects by material and loses their order).
    Reads v, vt, vn, f (v, v/vt, v//vn, v/vt/vn; polygons fanned; negative indices), o/g, usemtl
    (a material per face) and mtllib (Kd, Ke, map_Kd). Corners without vn get their face's normal,
    corners without vt UV (0, 0). Its material libraries and textures are read from `folders`
    (files.reference_folders; default: the file's own folder). Errors name the line and what it
    needs, never quoting it (a file the user did not name may be read)."""
    folders = folders or reference_folders(path)
    lists: dict[str, list[list[float]]] = {"v": [], "vt": [], "vn": []}
    objects: list[tuple[str, list, list[str | None]]] = []
    materials: dict[str, Material] = {}
    name, corners, face_mtl, mtl = path.stem, [], [], None  # corners: per triangle 3 (v, vt, vn)

    def flush():
        if corners:
            objects.append((name, corners, face_mtl))

    def index(text, tag):
        i = int(text)
        if abs(i) > 2**31:
            raise SceneError(f"{path}:{lineno}: index {i} refers to a {tag!r} that does not exist")
        return i - 1 if i > 0 else len(lists[tag]) + i

    for lineno, raw in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        parts = raw.split("#", 1)[0].split()
        if not parts:
            continue
        tag, args = parts[0], parts[1:]
        try:
            if tag in lists:
                width = 2 if tag == "vt" else 3
                if tag == "vt" and len(args) == 1:  # vt u [v [w]]: v defaults to 0
                    args = args + ["0"]
                if len(args) < width:
                    raise SceneError(f"{path}:{lineno}: {tag!r} needs {width} numbers, got {len(args)}")
                lists[tag].append([float(a) for a in args[:width]])
            elif tag == "f":
                if len(args) < 3:
                    raise SceneError(f"{path}:{lineno}: a face needs at least 3 vertices, got {len(args)}")
                refs = []
                for a in args:
                    fields = (a.split("/") + ["", ""])[:3]
                    refs.append(tuple(index(f, t) if f else -1 for f, t in zip(fields, ("v", "vt", "vn"))))
                corners += [(refs[0], refs[k], refs[k + 1]) for k in range(1, len(refs) - 1)]
                face_mtl += [mtl] * (len(refs) - 2)
            elif tag in ("o", "g") and args:
                flush()
                name, corners, face_mtl = " ".join(args), [], []
            elif tag == "usemtl" and args:
                mtl = args[0]
            elif tag == "mtllib" and args:
                materials.update(_read_mtl(path.parent / " ".join(args), folders))
        except SceneError:
            raise
        except ValueError:
            raise SceneError(f"{path}:{lineno}: cannot parse {tag!r}: its values must be numbers") from None
    flush()
    V, VT, VN = (np.array(lists[t], dtype=np.float64).reshape(-1, 2 if t == "vt" else 3) for t in ("v", "vt", "vn"))
    out = []
    for name, corners, face_mtl in objects:
        C = np.array(corners, dtype=np.int64)  # (m, 3, 3): corner, (v, vt, vn)
        for k, (tag, table) in enumerate((("vertex", V), ("texture coordinate", VT), ("normal", VN))):
            if k and len(table) == 0:  # references to a table the file does not have: none
                C[..., k] = -1
            given = C[..., k][C[..., k] >= 0] if k else C[..., k]
            if len(given) and (given.min() < 0 or given.max() >= len(table)):
                raise SceneError(f"{path}: object {name!r} refers to a {tag} that does not exist")
        used, T = np.unique(C[..., 0], return_inverse=True)
        T = T.reshape(-1, 3)
        normals = uvs = None
        if (C[..., 2] >= 0).any():
            P = V[C[..., 0]]
            face = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
            face /= np.maximum(np.linalg.norm(face, axis=1, keepdims=True), 1e-300)
            normals = np.where((C[..., 2] >= 0)[..., None], VN[np.maximum(C[..., 2], 0)], face[:, None, :])
        if (C[..., 1] >= 0).any():
            uvs = np.where((C[..., 1] >= 0)[..., None], VT[np.maximum(C[..., 1], 0)], 0.0)
        names = list(dict.fromkeys(face_mtl))
        mats = [materials.get(m) or Material(name=m or "") for m in names]
        try:
            out.append(
                SceneObject(
                    name,
                    V[used],
                    T,
                    mats[0].color,
                    mats[0].emission,
                    corner_normals=normals,
                    corner_uvs=uvs,
                    triangle_material=[names.index(m) for m in face_mtl],
                    materials=mats,
                )
            )
        except SceneError as exc:
            raise SceneError(f"{path}: {exc}") from None
    return out


def _read_mtl(path: Path, folders: tuple[Path, ...]) -> dict[str, Material]:
    """Kd, Ke and map_Kd (a path relative to the library; as Blender imports it, the texture
    replaces Kd) of each material, and its scattering as Blender's importer reads it: roughness Pr
    (else from the exponent Ns, 1 - sqrt(Ns / 1000)), metallic Pm, the specular level the mean of
    Ks, the index Ni (where it is one, >= 1)."""
    if not os.path.lexists(path):
        warnings.warn(f"material library {path} not found; using default colours", stacklevel=3)
        return {}
    check_reference(path, folders, "material library", SceneError, "material library")
    specs: dict[str, dict] = {}
    current = None
    for lineno, raw in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        parts = raw.split("#", 1)[0].split()
        if len(parts) >= 2 and parts[0] == "newmtl":
            current = specs.setdefault(parts[1], {})
        elif current is not None and parts and parts[0] in ("Kd", "Ke", "Ks"):  # (parts: not a blank line)
            try:
                values = [float(p) for p in parts[1:]]
            except ValueError:
                raise SceneError(f"{path}:{lineno}: cannot parse {parts[0]}: its values must be numbers") from None
            if len(values) not in (1, 3):  # r g b, or r for grey
                raise SceneError(f"{path}:{lineno}: {parts[0]} needs 1 or 3 numbers, got {len(values)}")
            current[parts[0]] = colour(values * 3 if len(values) == 1 else values, f"{path}:{lineno}: {parts[0]}")
        elif current is not None and len(parts) >= 2 and parts[0] in ("Pr", "Pm", "Ns", "Ni"):
            try:
                current[parts[0]] = float(parts[1])
            except ValueError:
                raise SceneError(f"{path}:{lineno}: cannot parse {parts[0]}: its value must be a number") from None
        elif current is not None and len(parts) >= 2 and parts[0] == "map_Kd":
            # options (-s 1 1 1, ...) come before the file name
            texture = path.parent / (parts[-1] if parts[1].startswith("-") else " ".join(parts[1:]))
            current["map_Kd"] = check_reference(texture, folders, f"{path}:{lineno}: map_Kd", SceneError, "texture")
    out = {}
    for name, spec in specs.items():
        texture = spec.get("map_Kd")
        color = np.ones(3) if texture is not None else spec.get("Kd", DEFAULT_COLOR)
        scattering = {}
        if "Pr" in spec or "Ns" in spec:
            scattering["roughness"] = (
                spec["Pr"] if "Pr" in spec else 1 - math.sqrt(min(max(spec["Ns"], 0), 1000) / 1000)
            )
        if "Pm" in spec:
            scattering["metallic"] = spec["Pm"]
        if "Ks" in spec:
            scattering["specular"] = float(np.mean(spec["Ks"]))
        if spec.get("Ni", 0) >= 1:  # exporters write Ni 0 (or 0.001) for no index
            scattering["ior"] = spec["Ni"]
        try:
            out[name] = Material(color, spec.get("Ke", np.zeros(3)), texture, name=name, **scattering)
        except SceneError as exc:
            raise SceneError(f"{path}: {exc}") from None
    return out
