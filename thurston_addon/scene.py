"""Scene description, independent of Blender: meshes with materials (a base colour and an
emission, each optionally an image texture through the mesh's UVs; emissive meshes are lights)
and optional corner normals, point and spot lights (area lights are emissive meshes: flat_light)
and a camera, all in chart coordinates of the space's fundamental domain.

Filled from mesh files (OBJ, PLY, STL, GLB/glTF via trimesh), from a scene file (TOML: objects,
lights, camera), from Blender's depsgraph (the add-on), or built as the default scene of a space.
Objects are numbered in the order given: files in order, inside a file in the file's order.
"""
from __future__ import annotations

import json
import math
import numbers
import struct
import tomllib
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .files import check_input, check_keys, read_text

MESH_SUFFIXES = {".obj", ".ply", ".stl", ".glb", ".gltf"}
DEFAULT_COLOR = (0.8, 0.8, 0.8)
# The tracer keeps colours, radiance and (in Embree) vertices as float32: larger values become inf.
FLOAT32_MAX = float(np.finfo(np.float32).max)
MAX_SUBDIVISIONS = 7  # an icosphere's: 20 * 4^7 = 327680 triangles
MAX_PRIMITIVE_TRIANGLES = 2**24  # of a scene file's primitives together (copies: `transforms`)


class SceneError(ValueError):
    """A scene file or scene object that cannot be used."""


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def check_float32(values, what: str):
    """SceneError unless `values` are finite and within float32's range, which the tracer keeps."""
    a = np.asarray(values, np.float64)
    if not np.all(np.isfinite(a)):
        raise SceneError(f"{what} has NaN or infinite values")
    if a.size and np.abs(a).max() > FLOAT32_MAX:
        raise SceneError(f"{what} has a value of {np.abs(a).max():.3g}, beyond the {FLOAT32_MAX:.3g} "
                         "of the tracer's float32 numbers")


def _texture(value, what: str):
    """A texture given as an image file (read as Blender reads a colour image) or an array."""
    if value is None:
        return None
    if isinstance(value, (str, Path)):
        from .images import read_texture

        check_input(value, f"{what}: texture file", SceneError, "texture")
        try:
            return read_texture(value)
        except ValueError as exc:
            raise SceneError(f"{what}: {exc}") from None
    a = np.asarray(value, dtype=np.float32)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or 0 in a.shape:
        raise SceneError(f"{what}: a texture must be an (H, W, 3) or (H, W, 4) image, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise SceneError(f"{what}: the texture has NaN or infinite pixels")
    return a


@dataclass
class Material:
    """Base colour and emission (linear RGB); a texture (an image file or a linear float image,
    rows top-down, v = 0 the bottom row) multiplies its colour at the surface's UV. How it scatters,
    as Blender's Principled BSDF: roughness, metallic, specular (its Specular IOR Level: 0.5 the
    IOR's own reflectance, 0 no specular layer) and ior. The defaults (metallic and specular 0)
    are a Lambert surface."""
    color: np.ndarray = field(default_factory=lambda: np.array(DEFAULT_COLOR))
    emission: np.ndarray = field(default_factory=lambda: np.zeros(3))
    color_texture: np.ndarray | str | Path | None = None
    emission_texture: np.ndarray | str | Path | None = None
    name: str = ""
    one_sided: bool = False  # emits from the front only (the side of its triangles' winding normal)
    roughness: float = 0.5
    metallic: float = 0.0
    specular: float = 0.0
    ior: float = 1.5

    def __post_init__(self):
        self.color = np.asarray(self.color, dtype=np.float64).reshape(3)
        self.emission = np.asarray(self.emission, dtype=np.float64).reshape(3)
        check_float32(self.color, f"material {self.name!r}: base colour")
        check_float32(self.emission, f"material {self.name!r}: emission")
        self.color_texture = _texture(self.color_texture, f"material {self.name!r}: base colour")
        self.emission_texture = _texture(self.emission_texture, f"material {self.name!r}: emission")
        for key, (low, high), meaning in SCATTERING:
            value = getattr(self, key)
            # (the tracer keeps them as float32: the IOR must stay positive there)
            if not (_is_number(value) and low <= value <= high and (key != "ior" or np.float32(value) > 0)):
                raise SceneError(f"material {self.name!r}: {key} must be {meaning}, got {value!r}")
            setattr(self, key, float(value))


# The scattering parameters of a material, their ranges (as Cycles clamps the Principled BSDF's,
# within the tracer's float32) and what the error says.
SCATTERING = (("roughness", (0.0, 1.0), "a number in [0, 1]"), ("metallic", (0.0, 1.0), "a number in [0, 1]"),
              ("specular", (0.0, FLOAT32_MAX), f"a number >= 0 within the tracer's float32 (at most {FLOAT32_MAX:.3g})"),
              ("ior", (0.0, FLOAT32_MAX), f"a number > 0 within the tracer's float32 (1.4e-45 to {FLOAT32_MAX:.3g})"))


@dataclass
class SceneObject:
    name: str
    vertices: np.ndarray  # (n, 3) float64, chart coordinates
    triangles: np.ndarray  # (m, 3) int32
    color: np.ndarray = field(default_factory=lambda: np.array(DEFAULT_COLOR))
    emission: np.ndarray = field(default_factory=lambda: np.zeros(3))
    pass_index: int = 0  # a user's index for the object (Blender's pass_index), kept for compositing
    # Optional surfaces: the normal at each triangle corner (the chart normal of the surface
    # there; None: flat shading), UVs at each corner, and each triangle's material (an index into
    # `materials`; with no materials, one made of `color` and `emission`).
    corner_normals: np.ndarray | None = None  # (m, 3, 3)
    corner_uvs: np.ndarray | None = None  # (m, 3, 2)
    triangle_material: np.ndarray | None = None  # (m,) int32
    materials: list[Material] = field(default_factory=list)
    # Optional instancing: the mesh (vertices in its own coordinates) placed by each of these
    # chart-affine maps (k, 4, 4), last row (0, 0, 0, 1); the tracer stores it once. It stays one
    # object (one index and pass_index for all its placements).
    instances: np.ndarray | None = None

    def __post_init__(self):
        self.vertices = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.triangles = np.asarray(self.triangles, dtype=np.int32).reshape(-1, 3)
        self.color = np.asarray(self.color, dtype=np.float64).reshape(3)
        self.emission = np.asarray(self.emission, dtype=np.float64).reshape(3)
        check_float32(self.color, f"object {self.name!r}: colour")
        check_float32(self.emission, f"object {self.name!r}: emission")
        m = len(self.triangles)
        self.corner_normals = self._per_triangle("corner_normals", self.corner_normals, (m, 3, 3), np.float64)
        self.corner_uvs = self._per_triangle("corner_uvs", self.corner_uvs, (m, 3, 2), np.float64)
        self.triangle_material = self._per_triangle("triangle_material", self.triangle_material, (m,), np.int32)
        self.instances = None if self.instances is None else checked_instances(self.instances, self.name)
        if self.triangle_material is not None and m and not (
                0 <= self.triangle_material.min() and self.triangle_material.max() < max(len(self.materials), 1)):
            raise SceneError(f"object {self.name!r}: triangle_material refers to a material it does not have "
                             f"(it has {len(self.materials)})")

    def _per_triangle(self, what, value, shape, dtype):
        if value is None:
            return None
        a = np.asarray(value, dtype=dtype)
        if a.shape != shape:
            raise SceneError(f"object {self.name!r}: {what} must have shape {shape} (one row per triangle), "
                             f"got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise SceneError(f"object {self.name!r}: {what} has NaN or infinite values")
        return a

    def placed(self, transforms=None) -> "SceneObject":
        """The object with the copies of its mesh by `transforms` (default: its instances) as its
        own triangles, in one object without instances: what the instances show, flattened. Corner
        normals are covectors: they move by the inverse of each map's linear part."""
        A = self.instances if transforms is None else np.asarray(transforms, float).reshape(-1, 4, 4)
        if A is None:
            return self
        k, n = len(A), len(self.vertices)
        L, t = A[:, :3, :3], A[:, :3, 3]
        tiled = lambda a: None if a is None else np.concatenate([a] * k)
        normals = None if self.corner_normals is None else np.einsum(
            "mcj,kji->kmci", self.corner_normals, np.linalg.inv(L)).reshape(-1, 3, 3)
        return SceneObject(
            self.name, (np.einsum("kij,nj->kni", L, self.vertices) + t[:, None]).reshape(-1, 3),
            (self.triangles[None] + (n * np.arange(k))[:, None, None]).reshape(-1, 3), self.color, self.emission,
            self.pass_index, normals, tiled(self.corner_uvs), tiled(self.triangle_material), self.materials)

    def surface_materials(self) -> tuple[list[Material], np.ndarray]:
        """The materials and each triangle's index into them (one material where none are given)."""
        materials = self.materials or [Material(self.color, self.emission, name=self.name)]
        index = self.triangle_material if self.triangle_material is not None else np.zeros(len(self.triangles), np.int32)
        return materials, index


def checked_instances(value, name: str) -> np.ndarray:
    """Instance transforms as (k, 4, 4) float64: finite, affine and invertible."""
    try:
        A = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"object {name!r}: instance transforms must be 4x4 matrices of numbers") from None
    if A.ndim != 3 or A.shape[1:] != (4, 4) or len(A) == 0:
        raise SceneError(f"object {name!r}: instance transforms must have shape (k, 4, 4) with k >= 1, got {A.shape}")
    for j, M in enumerate(A):
        if not np.all(np.isfinite(M)):
            raise SceneError(f"object {name!r}: instance {j} has a NaN or infinite transform")
        if not np.array_equal(M[3], [0.0, 0.0, 0.0, 1.0]):
            raise SceneError(f"object {name!r}: instance {j} is not affine (its last row must be 0 0 0 1, got {M[3].tolist()})")
        L = M[:3, :3]
        if not abs(np.linalg.det(L)) > 1e-12 * np.prod(np.linalg.norm(L, axis=1)):
            raise SceneError(f"object {name!r}: instance {j} has a singular transform (it flattens the mesh)")
    return A


@dataclass
class PointLight:
    """A point light; with spot_direction a spot light whose cone is Cycles': light leaving at
    angle theta from the axis is scaled by smoothstep((cos theta - cos(spot_size / 2)) / ((1 -
    cos(spot_size / 2)) spot_blend)), 0 outside the cone (blend 0: a sharp edge). In a curved space
    the axis is a direction at the light, and theta the angle there of each geodesic leaving it."""
    position: np.ndarray  # chart coordinates
    color: np.ndarray = field(default_factory=lambda: np.ones(3))
    power: float = 1.0  # radiant intensity scale: radiance at unit "area distance"
    spot_direction: np.ndarray | None = None  # chart vector at the light; None: a point light
    spot_size: float = math.pi  # the cone's full angle, radians, in (0, pi]
    spot_blend: float = 0.0  # in [0, 1]

    def __post_init__(self):
        where = f"light at {np.asarray(self.position).tolist()}"
        if not (_is_number(self.power) and self.power >= 0):
            raise SceneError(f"{where}: power must be a number >= 0, got {self.power!r}")
        with np.errstate(over="ignore"):
            check_float32(np.asarray(self.color, np.float64) * float(self.power), f"{where}: power times colour")
        if self.spot_direction is None:
            return
        self.spot_direction = np.asarray(self.spot_direction, np.float64).reshape(3)
        if not (np.all(np.isfinite(self.spot_direction)) and np.linalg.norm(self.spot_direction) > 0):
            raise SceneError(f"spot light at {np.asarray(self.position).tolist()}: its direction must be a "
                             f"non-zero vector, got {self.spot_direction.tolist()}")
        if not 0 < self.spot_size <= math.pi:
            raise SceneError(f"spot light at {np.asarray(self.position).tolist()}: spot size must be an angle in "
                             f"(0, pi], got {self.spot_size}")
        if not 0 <= self.spot_blend <= 1:
            raise SceneError(f"spot light at {np.asarray(self.position).tolist()}: spot blend must be in [0, 1], "
                             f"got {self.spot_blend}")

    def cone(self) -> tuple[float, float]:
        """(cos of the half angle, 1 / ((1 - that) blend)) as the tracer takes it; (-1, inf): no cone."""
        if self.spot_direction is None:
            return -1.0, math.inf
        c = math.cos(self.spot_size / 2)
        return c, 1 / ((1 - c) * self.spot_blend) if self.spot_blend > 0 and c < 1 else math.inf


def flat_light(name: str, centre, u, v, radiance, disc: bool = False, sections: int = 32) -> SceneObject:
    """An area light as an emissive mesh: the rectangle centre + a u + b v (a, b in [-1, 1]), or
    with disc the ellipse of those half-axes, emitting `radiance` from its front only (the side of
    u x v), black (it reflects nothing)."""
    centre, u, v = (np.asarray(a, np.float64).reshape(3) for a in (centre, u, v))
    if disc:
        t = 2 * math.pi * np.arange(sections) / sections
        rim = centre + np.cos(t)[:, None] * u + np.sin(t)[:, None] * v
        vertices = np.vstack([centre, rim])
        triangles = [[0, 1 + k, 1 + (k + 1) % sections] for k in range(sections)]
    else:
        vertices = np.array([centre - u - v, centre + u - v, centre + u + v, centre - u + v])
        triangles = [[0, 1, 2], [0, 2, 3]]
    material = Material(np.zeros(3), radiance, name=name, one_sided=True)
    return SceneObject(name, vertices, triangles, material.color, material.emission, materials=[material])


@dataclass
class Camera:
    position: np.ndarray
    forward: np.ndarray
    up: np.ndarray
    fov: float = 90.0  # horizontal field of view, degrees
    shift: tuple[float, float] = (0.0, 0.0)  # lens shift (x right, y up), in units of the image width
    clip_start: float = 0.0  # geodesic distance before which nothing is seen
    clip_end: float | None = None  # geodesic distance after which nothing is seen; None: no limit


@dataclass
class Scene:
    objects: list[SceneObject] = field(default_factory=list)
    lights: list[PointLight] = field(default_factory=list)
    camera: Camera | None = None

    def extend(self, other: "Scene"):
        self.objects += other.objects
        self.lights += other.lights
        self.camera = other.camera or self.camera


def clean(obj: SceneObject, where: str) -> SceneObject:
    """Reject non-finite vertices, vertices beyond float32 (Embree's) and bad indices; drop
    degenerate triangles with a warning."""
    V, T = obj.vertices, obj.triangles
    bad = ~np.all(np.isfinite(V), axis=1)
    if bad.any():
        raise SceneError(f"{where}: object {obj.name!r} has a NaN or infinite vertex (vertex {int(np.argmax(bad))})")
    far = np.abs(V).max(axis=1, initial=0.0) > FLOAT32_MAX
    if far.any():
        raise SceneError(f"{where}: object {obj.name!r}: vertex {int(np.argmax(far))} {V[np.argmax(far)].tolist()} is "
                         f"beyond the {FLOAT32_MAX:.3g} of the tracer's float32 numbers")
    if len(T) and (T.min() < 0 or T.max() >= len(V)):
        raise SceneError(f"{where}: object {obj.name!r} has a triangle index out of range")
    if len(T):
        keep = ~degenerate(V[T])
        if not keep.all():
            warnings.warn(f"{where}: object {obj.name!r}: skipped {int((~keep).sum())} degenerate triangle(s)", stacklevel=2)
            obj.triangles = T[keep]
            for name in ("corner_normals", "corner_uvs", "triangle_material"):
                if getattr(obj, name) is not None:
                    setattr(obj, name, getattr(obj, name)[keep])
    return obj


def colour(values, what: str) -> np.ndarray:
    """A colour or emission from a file: three numbers >= 0 that the tracer's float32 holds."""
    if not (isinstance(values, (list, np.ndarray)) and len(values) == 3 and all(map(_is_number, values))):
        raise SceneError(f"{what}: expected 3 numbers, got {values!r}")
    v = np.array(values, dtype=np.float64)
    check_float32(v, what)
    if np.any(v < 0):
        raise SceneError(f"{what}: {v.tolist()} is negative")
    return v


def degenerate(corners) -> np.ndarray:
    """Which triangles (m, 3, 3) have no area to float64's precision: twice the area no more than
    1e-14 of the square of the triangle's own longest side (so a far vertex elsewhere in the
    object, or the object's size, changes nothing)."""
    P = np.asarray(corners, np.float64)
    edges = P[:, [1, 2, 0]] - P
    with np.errstate(divide="ignore", invalid="ignore"):  # (a triangle of one point: 0 / 0, degenerate)
        edges /= np.max(np.abs(edges), axis=(1, 2))[:, None, None]  # scaled to 1: no under- or overflow
        area2 = np.linalg.norm(np.cross(edges[:, 0], -edges[:, 2]), axis=1)
        longest = np.max(np.sum(edges * edges, axis=2), axis=1)
        return ~(area2 > 1e-14 * longest)


# --- mesh files ------------------------------------------------------------------------------------
def _read_obj(path: Path) -> list[SceneObject]:
    """OBJ objects in file order (trimesh regroups OBJ objects by material and loses their order).
    Reads v, vt, vn, f (v, v/vt, v//vn, v/vt/vn; polygons fanned; negative indices), o/g, usemtl
    (a material per face) and mtllib (Kd, Ke, map_Kd). Corners without vn get their face's normal,
    corners without vt UV (0, 0)."""
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
                    raise SceneError(f"{path}:{lineno}: {tag!r} needs {width} numbers, got {raw.strip()!r}")
                lists[tag].append([float(a) for a in args[:width]])
            elif tag == "f":
                if len(args) < 3:
                    raise SceneError(f"{path}:{lineno}: a face needs at least 3 vertices, got {raw.strip()!r}")
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
                materials.update(_read_mtl(path.parent / " ".join(args)))
        except SceneError:
            raise
        except ValueError:
            raise SceneError(f"{path}:{lineno}: cannot parse {raw.strip()!r}") from None
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
            out.append(SceneObject(name, V[used], T, mats[0].color, mats[0].emission, corner_normals=normals,
                                   corner_uvs=uvs, triangle_material=[names.index(m) for m in face_mtl],
                                   materials=mats))
        except SceneError as exc:
            raise SceneError(f"{path}: {exc}") from None
    return out


def _read_mtl(path: Path) -> dict[str, Material]:
    """Kd, Ke and map_Kd (a path relative to the library; as Blender imports it, the texture
    replaces Kd) of each material, and its scattering as Blender's importer reads it: roughness Pr
    (else from the exponent Ns, 1 - sqrt(Ns / 1000)), metallic Pm, the specular level the mean of
    Ks, the index Ni (where it is one, >= 1)."""
    if not path.exists():
        warnings.warn(f"material library {path} not found; using default colours", stacklevel=3)
        return {}
    check_input(path, "material library", SceneError, "material library")
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
                raise SceneError(f"{path}:{lineno}: cannot parse {raw.strip()!r}") from None
            if len(values) not in (1, 3):  # r g b, or r for grey
                raise SceneError(f"{path}:{lineno}: {parts[0]} needs 1 or 3 numbers, got {raw.strip()!r}")
            current[parts[0]] = colour(values * 3 if len(values) == 1 else values, f"{path}:{lineno}: {parts[0]}")
        elif current is not None and len(parts) >= 2 and parts[0] in ("Pr", "Pm", "Ns", "Ni"):
            try:
                current[parts[0]] = float(parts[1])
            except ValueError:
                raise SceneError(f"{path}:{lineno}: cannot parse {raw.strip()!r}") from None
        elif current is not None and len(parts) >= 2 and parts[0] == "map_Kd":
            # options (-s 1 1 1, ...) come before the file name
            current["map_Kd"] = path.parent / (parts[-1] if parts[1].startswith("-") else " ".join(parts[1:]))
    out = {}
    for name, spec in specs.items():
        texture = spec.get("map_Kd")
        color = np.ones(3) if texture is not None else spec.get("Kd", DEFAULT_COLOR)
        scattering = {}
        if "Pr" in spec or "Ns" in spec:
            scattering["roughness"] = spec["Pr"] if "Pr" in spec else 1 - math.sqrt(min(max(spec["Ns"], 0), 1000) / 1000)
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


def _trimesh_objects(path: Path) -> list[SceneObject]:
    """Meshes of PLY, STL and glTF/GLB files with their vertex normals where the file has them
    (else flat shading), glTF's TEXCOORD_0 and base colour textures."""
    import trimesh

    header, binary = _gltf_parts(path)  # (first: its own errors are clearer than the reader's)
    loaded = trimesh.load(str(path), force="scene", process=False)
    order = {str(n.get("name", i)): i for i, n in enumerate(header.get("nodes", []))}
    textures = _gltf_base_textures(path, header, binary)
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
        name = str(getattr(material, "name", ""))
        try:
            materials = [Material(color, emission, texture, name=name, **_gltf_scattering(material))]
            out.append(SceneObject(str(node), V, F, color, emission, corner_normals=normals, corner_uvs=uvs,
                                   materials=materials))
        except SceneError as exc:
            raise SceneError(f"{path}: {exc}") from None
    return out


def _gltf_parts(path: Path) -> tuple[dict, bytes]:
    """A glTF/GLB file's JSON and its binary chunk (b"" for .gltf); ({}, b"") for other files."""
    if path.suffix.lower() not in (".glb", ".gltf"):
        return {}, b""
    data = path.read_bytes()
    binary = b""
    if data[:4] == b"glTF":  # binary: 12-byte header, the JSON chunk (length, type, data), the BIN chunk
        if len(data) < 20:
            raise SceneError(f"{path}: the GLB file ends inside its header ({len(data)} bytes)")
        length = struct.unpack_from("<I", data, 12)[0]
        binary = data[28 + length:]
        data = data[20:20 + length]
    try:
        header = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: its JSON is not UTF-8 text (byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise SceneError(f"{path}: its JSON is not valid: {exc.msg} (line {exc.lineno}, column {exc.colno})") from None
    if not isinstance(header, dict):
        raise SceneError(f"{path}: the glTF JSON is not an object")
    return header, binary


def _gltf_base_textures(path: Path, header: dict, binary: bytes) -> dict[str, np.ndarray]:
    """Material name -> its base colour texture (linear), read here since trimesh needs Pillow
    for images. Materials are matched to trimesh's by name, so unnamed ones get no texture."""
    import base64
    import tempfile

    from .images import read_texture

    out = {}
    for material in header.get("materials", []):
        info = material.get("pbrMetallicRoughness", {}).get("baseColorTexture")
        if info is None or "name" not in material:
            continue
        image = header["images"][header["textures"][info["index"]]["source"]]
        uri = image.get("uri", "")
        where = f"{path}: material {material['name']!r}"
        if uri and not uri.startswith("data:"):
            out[material["name"]] = _texture(path.parent / uri, where)
            continue
        if uri:
            blob = base64.b64decode(uri.split(",", 1)[1])
        else:
            view = header["bufferViews"][image["bufferView"]]
            buffer = header["buffers"][view["buffer"]]
            data = binary if "uri" not in buffer else (
                base64.b64decode(buffer["uri"].split(",", 1)[1]) if buffer["uri"].startswith("data:")
                else check_input(path.parent / buffer["uri"], f"{path}: buffer", SceneError, "mesh file").read_bytes())
            start = view.get("byteOffset", 0)
            blob = data[start:start + view["byteLength"]]
        suffix = {"image/png": ".png", "image/jpeg": ".jpg"}.get(image.get("mimeType", ""), ".png")
        with tempfile.TemporaryDirectory() as folder:  # OpenImageIO's Python API reads files
            file = Path(folder) / f"texture{suffix}"
            file.write_bytes(blob)
            try:
                out[material["name"]] = read_texture(file)
            except ValueError:
                raise SceneError(f"{where}: its base colour image cannot be decoded") from None
    return out


def _gltf_scattering(material) -> dict:
    """A glTF material's metallic and roughness factors (absent: 1, as the format says) over its
    dielectric's normal reflectance 0.04 (IOR 1.5 at Blender's specular level 0.5); Lambert for
    the other formats' materials."""
    from trimesh.visual.material import PBRMaterial

    if not isinstance(material, PBRMaterial):
        return {}
    metallic, roughness = material.metallicFactor, material.roughnessFactor
    return dict(metallic=1.0 if metallic is None else float(metallic),
                roughness=1.0 if roughness is None else float(roughness), specular=0.5, ior=1.5)


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


def load_mesh_file(path: str | Path) -> list[SceneObject]:
    path = check_input(path, "scene file", SceneError, "OBJ file" if Path(path).suffix.lower() == ".obj" else "mesh file")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SceneError(f"{path}: unsupported file type {path.suffix!r} (mesh files: {', '.join(sorted(MESH_SUFFIXES))}; scenes: .toml)")
    try:
        objects = _read_obj(path) if path.suffix.lower() == ".obj" else _trimesh_objects(path)
    except SceneError:
        raise
    except Exception as exc:  # trimesh and the file system raise many types
        raise SceneError(f"cannot read mesh file {str(path)!r}: {_reader_failure(exc)}") from None
    if not objects:
        raise SceneError(f"{path}: the file holds no triangles")
    return [clean(o, str(path)) for o in objects]


def _reader_failure(exc: Exception) -> str:
    """What a mesh reader's exception says about the file, in words about the file where Python's
    own would show (a corrupt file makes the readers index, look up and decode past its data)."""
    if isinstance(exc, UnicodeDecodeError):
        return f"it is not UTF-8 text where text is expected (byte {exc.start})"
    if isinstance(exc, KeyError):
        return f"an entry it needs is missing ({exc})"
    if isinstance(exc, (IndexError, struct.error, EOFError)):
        return "it refers past the end of its data (truncated or corrupt)"
    if isinstance(exc, (TypeError, AttributeError)):
        return "an entry has the wrong type (corrupt)"
    if isinstance(exc, OSError) and exc.strerror:  # the file system's (the one a texture is unpacked to)
        return exc.strerror + (f" ({exc.filename})" if exc.filename else "")
    return str(exc)  # the reader's own words (trimesh's ValueErrors)


# --- scene files (TOML) ------------------------------------------------------------------------------
# The keys each table of a TOML scene file may have (any other key is an error naming the nearest
# valid one); a new key goes into its table's list here.
SCENE_KEYS = ("object", "light", "camera")
OBJECT_KEYS = ("color", "emission", "transforms", *(key for key, _, _ in SCATTERING))  # every [[object]]
FILE_OBJECT_KEYS = ("file",)  # an [[object]] read from a mesh file, besides OBJECT_KEYS
PRIMITIVE_KEYS = {  # an [[object]] with primitive = KIND, besides OBJECT_KEYS
    "sphere": ("primitive", "name", "center", "radius", "subdivisions"),
    "box": ("primitive", "name", "center", "size"),
    "torus": ("primitive", "name", "center", "radius", "tube"),
}
LIGHT_KEYS = {  # a [[light]] of each type
    "point": ("type", "position", "color", "power"),
    "spot": ("type", "position", "color", "power", "direction", "spot_size", "spot_blend"),
    "area": ("type", "position", "direction", "x_axis", "size", "shape", "emission"),
}
CAMERA_KEYS = ("position", "forward", "up", "fov", "shift", "clip_start", "clip_end")


def _vec(value, where, n=3):
    if not (isinstance(value, list) and len(value) == n and all(map(_is_number, value))):
        raise SceneError(f"{where}: expected {n} numbers, got {value!r}")
    v = np.array(value, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise SceneError(f"{where}: {value!r} is not finite")
    return v


def _number(spec: dict, key: str, default: float, where: str, positive: bool = False) -> float:
    value = spec.get(key, default)
    if not _is_number(value) or not math.isfinite(value):
        raise SceneError(f"{where}: {key} must be a finite number, got {value!r}")
    if positive and not value > 0:
        raise SceneError(f"{where}: {key} must be positive, got {value!r}")
    return float(value)


def _whole(spec: dict, key: str, default: int, where: str, low: int, high: int) -> int:
    value = spec.get(key, default)
    if not (_is_number(value) and math.isfinite(value) and value == int(value) and low <= value <= high):
        raise SceneError(f"{where}: {key} must be a whole number from {low} to {high}, got {value!r}")
    return int(value)


def _table(value, where: str, keys) -> dict:
    """A TOML table with none but `keys`."""
    if not isinstance(value, dict):
        raise SceneError(f"{where}: expected a table, got {value!r}")
    check_keys(value, keys, where, SceneError)
    return value


def _tables(data: dict, key: str, path: Path) -> list[dict]:
    """The [[key]] tables of a scene file (none if absent)."""
    value = data.get(key, [])
    if not (isinstance(value, list) and all(isinstance(v, dict) for v in value)):
        raise SceneError(f"{path}: {key} must be [[{key}]] tables, got {value!r}")
    return value


def load_scene_file(path: str | Path) -> Scene:
    """A mesh file, or a TOML scene file:

        [[object]]            # file = "mesh.obj" (relative to the scene file) or primitive = "sphere"
        file = "knot.glb"     # every object of the file, in its order
        color = [0.9, 0.3, 0.2]      # optional: overrides the file's materials and textures
        emission = [0, 0, 0]
        roughness = 0.3       # optional, as Blender's Principled BSDF (overriding the file's):
        metallic = 1.0        # roughness, metallic, specular (its Specular IOR Level; 0: no
        specular = 0.5        # specular layer) and ior; without them (and in files without
        ior = 1.5             # them) a Lambert surface
        [[object]]
        primitive = "sphere"  # sphere (radius), box (size), torus (radius, tube)
        center = [0.2, 0, 0]
        radius = 0.1
        transforms = [[[1, 0, 0, 0.3], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], ...]
                              # optional: the object instanced by these 4x4 chart-affine maps
        [[light]]
        position = [0, 0, 0.3]
        color = [1, 1, 1]
        power = 1.0
        type = "spot"         # optional: a spot light (point: the default), with
        direction = [0, 0, -1]  # its axis,
        spot_size = 45          # its cone's full angle (degrees) and blend, as Blender's
        spot_blend = 0.15
        [[light]]
        type = "area"         # an emissive rectangle or disc (an object, one-sided, black)
        position = [0, 0, 0.4]; direction = [0, 0, -1]; x_axis = [1, 0, 0]
        size = [0.2, 0.1]; shape = "rectangle"  # or "disc" (size: its diameters)
        emission = [4, 4, 4]  # radiance
        [camera]
        position = [0, 0, 0]; forward = [0, 1, 0]; up = [0, 0, 1]; fov = 90
        shift = [0, 0]; clip_start = 0  # lens shift in image widths; clip_end (absent: none)
    """
    path = Path(path)
    if path.suffix.lower() != ".toml":
        return Scene(objects=load_mesh_file(path))
    text = read_text(path, "scene file", SceneError, "scene file")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"cannot read scene file {str(path)!r}: {exc}") from None
    return _scene_from_toml(data, path)


def _scene_from_toml(data: dict, path: Path) -> Scene:
    check_keys(data, SCENE_KEYS, str(path), SceneError)
    scene = Scene()
    primitive_triangles = 0
    for i, spec in enumerate(_tables(data, "object", path)):
        where = f"{path}: object {i}"
        if "file" in spec and "primitive" in spec:
            raise SceneError(f"{where}: give 'file' or 'primitive', not both")
        if "file" in spec:
            check_keys(spec, FILE_OBJECT_KEYS + OBJECT_KEYS, f"{where} (a mesh file)", SceneError)
            if not isinstance(spec["file"], str):
                raise SceneError(f"{where}: file must be a path string, got {spec['file']!r}")
            try:
                objs = load_mesh_file(path.parent / spec["file"])
            except SceneError as exc:
                raise SceneError(f"{where}: {exc}") from None
        elif "primitive" in spec:
            objs = [primitive(spec, where)]
            primitive_triangles += len(objs[0].triangles)
            if primitive_triangles > MAX_PRIMITIVE_TRIANGLES:
                raise SceneError(f"{where}: the file's primitives have more than {MAX_PRIMITIVE_TRIANGLES} triangles; "
                                 "place copies of one with `transforms` (instances) instead")
        else:  # a misspelt file or primitive: the error names the nearest of every object key
            every_object_key = sorted({*OBJECT_KEYS, *FILE_OBJECT_KEYS, *(k for keys in PRIMITIVE_KEYS.values() for k in keys)})
            check_keys(spec, every_object_key, where, SceneError)
            raise SceneError(f"{where}: needs 'file' or 'primitive'")
        for o in objs:  # overrides apply to every material of the file (textures included)
            if "color" in spec:
                o.color = colour(spec["color"], f"{where}: color")
                for m in o.materials:
                    m.color, m.color_texture = o.color, None
            if "emission" in spec:
                o.emission = colour(spec["emission"], f"{where}: emission")
                for m in o.materials:
                    m.emission, m.emission_texture = o.emission, None
            scattering = {key: spec[key] for key, _, _ in SCATTERING if key in spec}
            if scattering:
                _scatter(o, scattering, where)
        if "transforms" in spec:
            for o in objs:
                try:
                    o.instances = checked_instances(spec["transforms"], o.name)
                except SceneError as exc:
                    raise SceneError(f"{where}: {exc}") from None
        scene.objects += objs
    for i, spec in enumerate(_tables(data, "light", path)):
        where = f"{path}: light {i}"
        kind = spec.get("type", "point")
        if not isinstance(kind, str) or kind not in LIGHT_KEYS:
            raise SceneError(f"{where}: unknown light type {kind!r} ({', '.join(LIGHT_KEYS)})")
        check_keys(spec, LIGHT_KEYS[kind], f"{where} ({kind} light)", SceneError)
        if "position" not in spec:
            raise SceneError(f"{where}: needs a position")
        position = _vec(spec["position"], f"{where}: position")
        if kind == "area":
            scene.objects.append(_area_light(spec, position, where))
            continue
        power = _number(spec, "power", 1.0, where)
        if power < 0:
            raise SceneError(f"{where}: power must be >= 0, got {power:g}")
        spot = {} if kind == "point" else dict(
            spot_direction=_vec(spec.get("direction"), f"{where}: direction"),
            spot_size=math.radians(_number(spec, "spot_size", 45.0, where)),
            spot_blend=_number(spec, "spot_blend", 0.15, where))
        try:
            scene.lights.append(PointLight(position, colour(spec.get("color", [1, 1, 1]), f"{where}: color"), power,
                                           **spot))
        except SceneError as exc:
            raise SceneError(f"{where}: {exc}") from None
    if "camera" in data:
        where = f"{path}: camera"
        c = _table(data["camera"], where, CAMERA_KEYS)
        fov = _number(c, "fov", 90.0, where)
        if not 0 < fov < 180:
            raise SceneError(f"{where}: fov must be between 0 and 180 degrees (exclusive), got {fov:g}")
        clip_start = _number(c, "clip_start", 0.0, where)
        clip_end = _number(c, "clip_end", 0.0, where, positive=True) if "clip_end" in c else None
        if clip_start < 0 or clip_end is not None and clip_start >= clip_end:
            raise SceneError(f"{where}: clip_start must be >= 0 and less than clip_end, got {clip_start:g}")
        scene.camera = Camera(
            _vec(c.get("position", [0, 0, 0]), f"{where}.position"),
            _vec(c.get("forward", [0, 1, 0]), f"{where}.forward"),
            _vec(c.get("up", [0, 0, 1]), f"{where}.up"),
            fov, shift=tuple(_vec(c.get("shift", [0, 0]), f"{where}.shift", 2)),
            clip_start=clip_start, clip_end=clip_end)
    return scene


def _scatter(obj: SceneObject, scattering: dict, where: str):
    """Sets the scattering keys (Material's roughness, metallic, specular, ior) on every material of
    the object (its one material made explicit where it has none)."""
    if not obj.materials:
        obj.materials = [Material(obj.color, obj.emission, name=obj.name)]
    try:
        obj.materials = [replace(m, **scattering) for m in obj.materials]
    except (SceneError, TypeError) as exc:
        raise SceneError(f"{where}: {exc}") from None


def _area_light(spec: dict, position, where: str) -> SceneObject:
    """A TOML area light: a rectangle or disc of `size` (width, height; diameters for a disc) at
    `position`, emitting `emission` (radiance) towards `direction`, its width along `x_axis`."""
    direction = _vec(spec.get("direction", [0, 0, -1]), f"{where}: direction")
    x_axis = _vec(spec.get("x_axis", [1, 0, 0] if abs(direction[0]) < 0.9 * np.linalg.norm(direction) else [0, 1, 0]),
                  f"{where}: x_axis")
    size = _vec(spec.get("size", [0.1, 0.1]), f"{where}: size", 2)
    shape = spec.get("shape", "rectangle")
    if shape not in ("rectangle", "disc"):
        raise SceneError(f"{where}: unknown area light shape {shape!r} (rectangle, disc)")
    emission = colour(spec.get("emission", [1, 1, 1]), f"{where}: emission")
    w = direction / max(np.linalg.norm(direction), 1e-300)
    u = x_axis - (x_axis @ w) * w
    if not (np.linalg.norm(direction) > 0 and np.linalg.norm(u) > 1e-9 * np.linalg.norm(x_axis)) or np.any(size <= 0):
        raise SceneError(f"{where}: an area light needs a non-zero direction, an x_axis not along it and a positive size")
    u = u / np.linalg.norm(u) * size[0] / 2
    v = np.cross(w, u) / np.linalg.norm(u) * size[1] / 2  # u x v along the direction it emits to
    return flat_light(f"area light {where}", position, u, v, emission, disc=shape == "disc")


def primitive(spec: dict, where: str) -> SceneObject:
    """A sphere (radius, subdivisions), box (size) or torus (radius, tube) at `center`, in the
    default colour (a scene file's object sets its colour and emission)."""
    import trimesh

    kind = spec.get("primitive")
    if not isinstance(kind, str) or kind not in PRIMITIVE_KEYS:
        raise SceneError(f"{where}: unknown primitive {kind!r} ({', '.join(PRIMITIVE_KEYS)})")
    check_keys(spec, PRIMITIVE_KEYS[kind] + OBJECT_KEYS, f"{where} (a {kind})", SceneError)
    center = _vec(spec.get("center", [0, 0, 0]), f"{where}: center")
    name = spec.get("name", kind)
    if not isinstance(name, str):
        raise SceneError(f"{where}: name must be a string, got {name!r}")
    if kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=_whole(spec, "subdivisions", 3, where, 0, MAX_SUBDIVISIONS),
                                          radius=_number(spec, "radius", 0.1, where, positive=True))
    elif kind == "box":
        size = _vec(spec.get("size", [0.2, 0.2, 0.2]), f"{where}: size")
        if not np.all(size > 0):
            raise SceneError(f"{where}: size must be positive, got {size.tolist()}")
        mesh = trimesh.creation.box(extents=size)
    else:
        mesh = trimesh.creation.torus(major_radius=_number(spec, "radius", 0.15, where, positive=True),
                                      minor_radius=_number(spec, "tube", 0.05, where, positive=True))
    return clean(SceneObject(name, mesh.vertices + center, mesh.faces), where)


def load_scenes(paths) -> Scene:
    scene = Scene()
    for p in paths:
        scene.extend(load_scene_file(p))
    return scene


# --- the default scene ---------------------------------------------------------------------------------
def default_scene(space) -> Scene:
    """The domain drawn as thin tubes coloured by class (as in the paper's figures: edges by edge
    class, or face frames by face class, see Space.outline), a torus ring and a sphere off the
    centre, and a light near the camera."""
    import trimesh

    # the domain's size, but no more than twice its inscribed ball (SL2's fibre is long beside its disk)
    size = min(space.extent, 4 * space.chart_inradius)
    radius = 0.012 * size
    palette = np.array([[0.9, 0.25, 0.2], [0.2, 0.7, 0.3], [0.25, 0.45, 0.95], [0.95, 0.8, 0.2],
                        [0.8, 0.3, 0.85], [0.2, 0.8, 0.85], [0.95, 0.55, 0.2], [0.6, 0.6, 0.6],
                        [0.55, 0.35, 0.2], [0.9, 0.5, 0.65]])
    objects = []
    for c, segments in enumerate(space.outline(inset=2 * radius)):
        tubes = trimesh.util.concatenate([trimesh.creation.cylinder(radius=radius, segment=[p, q], sections=10)
                                          for p, q in segments])
        objects.append(SceneObject(f"edges {c}", tubes.vertices, tubes.faces, palette[c % len(palette)]))
    inr = space.chart_inradius
    cam = space.camera
    forward = np.asarray(cam.forward, float) / np.linalg.norm(cam.forward)
    side = np.cross(forward, cam.up)
    side /= np.linalg.norm(side)
    up = np.cross(side, forward)
    ring = trimesh.creation.torus(major_radius=0.22 * inr, minor_radius=0.07 * inr, major_sections=48, minor_sections=16)
    ring.apply_transform(trimesh.geometry.align_vectors([0, 0, 1], forward + 0.6 * side + 0.4 * up))
    objects.append(SceneObject("ring", ring.vertices + cam.position + inr * (0.7 * forward + 0.25 * side), ring.faces, (0.95, 0.75, 0.3)))
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.12 * inr)
    objects.append(SceneObject("sphere", ball.vertices + cam.position + inr * (0.5 * forward - 0.45 * side - 0.1 * up), ball.faces,
                               (0.3, 0.6, 0.95)))
    # behind and above the camera; bright enough to light the walls one domain away
    position = np.asarray(cam.position, float) + 0.3 * inr * (up - 0.5 * forward)
    g = space.geometry
    X = g.to_model(position)
    falloff = float(g.falloff_along(X, g.normalize_tangent(X, g.tangent_to_model(position, forward)), space.inradius))
    if g.projective and g.curvature > 0:
        # the finite group: every copy lights every point (render.py). An exposure choice: the
        # copies within two circumradii of the light (the ones the domain's tubes do not hide),
        # summed at the point one inradius ahead, give 0.5 there
        ahead = g.geodesic(X, g.normalize_tangent(X, g.tangent_to_model(position, forward)), space.inradius)[0]
        d = g.distance(ahead, np.array([M @ X for M in space.elements_within(2 * space.circumradius)]))
        falloff = float(np.sum(g.falloff(d)))
    light = PointLight(position, np.ones(3), 0.5 / falloff)
    return Scene(objects=objects, lights=[light])
