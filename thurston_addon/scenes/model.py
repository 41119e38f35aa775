"""The scene model, independent of Blender and of files: materials, meshes (scene objects,
optionally instanced), point, spot and area lights, the camera and the scene that holds them,
with the checks every source of a scene shares (finite values within float32, clean meshes)."""

from __future__ import annotations

import math
import numbers
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..files import check_input

DEFAULT_COLOR = (0.8, 0.8, 0.8)
# The tracer keeps colours, radiance and (in Embree) vertices as float32: larger values become inf.
FLOAT32_MAX = float(np.finfo(np.float32).max)


class SceneError(ValueError):
    """A scene file or scene object that cannot be used."""


def is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def check_float32(values, what: str):
    """SceneError unless `values` are finite and within float32's range, which the tracer keeps."""
    a = np.asarray(values, np.float64)
    if not np.all(np.isfinite(a)):
        raise SceneError(f"{what} has NaN or infinite values")
    if a.size and np.abs(a).max() > FLOAT32_MAX:
        raise SceneError(
            f"{what} has a value of {np.abs(a).max():.3g}, beyond the {FLOAT32_MAX:.3g} of the tracer's float32 numbers"
        )


def checked_texture(value, what: str):
    """A texture given as an image file (read as Blender reads a colour image) or an array."""
    if value is None:
        return None
    if isinstance(value, (str, Path)):
        from ..images import read_texture

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
        self.color_texture = checked_texture(self.color_texture, f"material {self.name!r}: base colour")
        self.emission_texture = checked_texture(self.emission_texture, f"material {self.name!r}: emission")
        for key, (low, high), meaning in SCATTERING:
            value = getattr(self, key)
            # (the tracer keeps them as float32: the IOR must stay positive there)
            if not (is_number(value) and low <= value <= high and (key != "ior" or np.float32(value) > 0)):
                raise SceneError(f"material {self.name!r}: {key} must be {meaning}, got {value!r}")
            setattr(self, key, float(value))


# The scattering parameters of a material, their ranges (as Cycles clamps the Principled BSDF's,
# within the tracer's float32) and what the error says.
SCATTERING = (
    ("roughness", (0.0, 1.0), "a number in [0, 1]"),
    ("metallic", (0.0, 1.0), "a number in [0, 1]"),
    ("specular", (0.0, FLOAT32_MAX), f"a number >= 0 within the tracer's float32 (at most {FLOAT32_MAX:.3g})"),
    ("ior", (0.0, FLOAT32_MAX), f"a number > 0 within the tracer's float32 (1.4e-45 to {FLOAT32_MAX:.3g})"),
)


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
        if (
            self.triangle_material is not None
            and m
            and not (0 <= self.triangle_material.min() and self.triangle_material.max() < max(len(self.materials), 1))
        ):
            raise SceneError(
                f"object {self.name!r}: triangle_material refers to a material it does not have "
                f"(it has {len(self.materials)})"
            )

    def _per_triangle(self, what, value, shape, dtype):
        if value is None:
            return None
        a = np.asarray(value, dtype=dtype)
        if a.shape != shape:
            raise SceneError(
                f"object {self.name!r}: {what} must have shape {shape} (one row per triangle), got {a.shape}"
            )
        if not np.all(np.isfinite(a)):
            raise SceneError(f"object {self.name!r}: {what} has NaN or infinite values")
        return a

    def placed(self, transforms=None) -> SceneObject:
        """The object with the copies of its mesh by `transforms` (default: its instances) as its
        own triangles, in one object without instances: what the instances show, flattened. Corner
        normals are covectors: they move by the inverse of each map's linear part."""
        A = self.instances if transforms is None else np.asarray(transforms, float).reshape(-1, 4, 4)
        if A is None:
            return self
        k, n = len(A), len(self.vertices)
        L, t = A[:, :3, :3], A[:, :3, 3]
        tiled = lambda a: None if a is None else np.concatenate([a] * k)
        normals = (
            None
            if self.corner_normals is None
            else np.einsum("mcj,kji->kmci", self.corner_normals, np.linalg.inv(L)).reshape(-1, 3, 3)
        )
        return SceneObject(
            self.name,
            (np.einsum("kij,nj->kni", L, self.vertices) + t[:, None]).reshape(-1, 3),
            (self.triangles[None] + (n * np.arange(k))[:, None, None]).reshape(-1, 3),
            self.color,
            self.emission,
            self.pass_index,
            normals,
            tiled(self.corner_uvs),
            tiled(self.triangle_material),
            self.materials,
        )

    def surface_materials(self) -> tuple[list[Material], np.ndarray]:
        """The materials and each triangle's index into them (one material where none are given)."""
        materials = self.materials or [Material(self.color, self.emission, name=self.name)]
        index = (
            self.triangle_material if self.triangle_material is not None else np.zeros(len(self.triangles), np.int32)
        )
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
            raise SceneError(
                f"object {name!r}: instance {j} is not affine (its last row must be 0 0 0 1, got {M[3].tolist()})"
            )
        if singular(M):
            raise SceneError(f"object {name!r}: instance {j} has a singular transform (it flattens the mesh)")
    return A


def singular(M) -> bool:
    """Whether a transform's linear part flattens a mesh (a scale of 0 on some axis)."""
    L = np.asarray(M, np.float64)[:3, :3]
    return not abs(np.linalg.det(L)) > 1e-12 * np.prod(np.linalg.norm(L, axis=1))


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
        if not (is_number(self.power) and self.power >= 0):
            raise SceneError(f"{where}: power must be a number >= 0, got {self.power!r}")
        with np.errstate(over="ignore"):
            check_float32(np.asarray(self.color, np.float64) * float(self.power), f"{where}: power times colour")
        if self.spot_direction is None:
            return
        self.spot_direction = np.asarray(self.spot_direction, np.float64).reshape(3)
        if not (np.all(np.isfinite(self.spot_direction)) and np.linalg.norm(self.spot_direction) > 0):
            raise SceneError(
                f"spot light at {np.asarray(self.position).tolist()}: its direction must be a "
                f"non-zero vector, got {self.spot_direction.tolist()}"
            )
        if not 0 < self.spot_size <= math.pi:
            raise SceneError(
                f"spot light at {np.asarray(self.position).tolist()}: spot size must be an angle in "
                f"(0, pi], got {self.spot_size}"
            )
        if not 0 <= self.spot_blend <= 1:
            raise SceneError(
                f"spot light at {np.asarray(self.position).tolist()}: spot blend must be in [0, 1], "
                f"got {self.spot_blend}"
            )

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

    def extend(self, other: Scene):
        self.objects += other.objects
        self.lights += other.lights
        self.camera = other.camera or self.camera


BLOCK = 1 << 16  # triangles measured at once by clean


def clean(obj: SceneObject, where: str) -> SceneObject:
    """Reject non-finite vertices, vertices beyond float32 (Embree's) and bad indices; drop
    degenerate triangles with a warning."""
    V, T = obj.vertices, obj.triangles
    bad = ~np.all(np.isfinite(V), axis=1)
    if bad.any():
        raise SceneError(f"{where}: object {obj.name!r} has a NaN or infinite vertex (vertex {int(np.argmax(bad))})")
    far = np.abs(V).max(axis=1, initial=0.0) > FLOAT32_MAX
    if far.any():
        raise SceneError(
            f"{where}: object {obj.name!r}: vertex {int(np.argmax(far))} {V[np.argmax(far)].tolist()} is "
            f"beyond the {FLOAT32_MAX:.3g} of the tracer's float32 numbers"
        )
    if len(T) and (T.min() < 0 or T.max() >= len(V)):
        raise SceneError(f"{where}: object {obj.name!r} has a triangle index out of range")
    if len(T):
        # in blocks: the measure's temporaries stay small (each triangle is measured alone)
        keep = np.concatenate([~degenerate(V[T[i : i + BLOCK]]) for i in range(0, len(T), BLOCK)])
        if not keep.all():
            warnings.warn(
                f"{where}: object {obj.name!r}: skipped {int((~keep).sum())} degenerate triangle(s)", stacklevel=2
            )
            obj.triangles = T[keep]
            for name in ("corner_normals", "corner_uvs", "triangle_material"):
                if getattr(obj, name) is not None:
                    setattr(obj, name, getattr(obj, name)[keep])
    return obj


def colour(values, what: str) -> np.ndarray:
    """A colour or emission from a file: three numbers >= 0 that the tracer's float32 holds."""
    if not (isinstance(values, (list, np.ndarray)) and len(values) == 3 and all(map(is_number, values))):
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
