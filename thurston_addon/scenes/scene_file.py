"""TOML scene files: objects (mesh files or primitives, optionally instanced), point, spot and
area lights and the camera, each table checked against its keys."""

from __future__ import annotations

import math
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..files import check_keys, check_reference, read_text, reference_folders
from .meshes import load_mesh_file
from .model import (
    SCATTERING,
    Camera,
    Material,
    PointLight,
    Scene,
    SceneError,
    SceneObject,
    checked_instances,
    clean,
    colour,
    flat_light,
    is_number,
)

MAX_SUBDIVISIONS = 7  # an icosphere's: 20 * 4^7 = 327680 triangles
MAX_PRIMITIVE_TRIANGLES = 2**24  # of a scene file's primitives together (copies: `transforms`)

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
    if not (isinstance(value, list) and len(value) == n and all(map(is_number, value))):
        raise SceneError(f"{where}: expected {n} numbers, got {value!r}")
    v = np.array(value, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise SceneError(f"{where}: {value!r} is not finite")
    return v


def _number(spec: dict, key: str, default: float, where: str, positive: bool = False) -> float:
    value = spec.get(key, default)
    if not is_number(value) or not math.isfinite(value):
        raise SceneError(f"{where}: {key} must be a finite number, got {value!r}")
    if positive and not value > 0:
        raise SceneError(f"{where}: {key} must be positive, got {value!r}")
    return float(value)


def _whole(spec: dict, key: str, default: int, where: str, low: int, high: int) -> int:
    value = spec.get(key, default)
    if not (is_number(value) and math.isfinite(value) and value == int(value) and low <= value <= high):
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


def load_scene_file(path: str | Path, allowed=()) -> Scene:
    """A mesh file, or a TOML scene file:

    The files it refers to (mesh files, their material libraries, textures and buffers) are read
    from its folder and below, and from the `allowed` folders (files.check_reference).

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
    folders = reference_folders(path, allowed)
    if path.suffix.lower() != ".toml":
        return Scene(objects=load_mesh_file(path, folders))
    text = read_text(path, "scene file", SceneError, "scene file")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"cannot read scene file {str(path)!r}: {exc}") from None
    except RecursionError:
        raise SceneError(
            f"cannot read scene file {str(path)!r}: its tables or arrays nest too deeply; a scene needs a few levels"
        ) from None
    return _scene_from_toml(data, path, folders)


def _scene_from_toml(data: dict, path: Path, folders: tuple[Path, ...]) -> Scene:
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
                mesh_file = check_reference(path.parent / spec["file"], folders, "mesh file", SceneError)
                objs = load_mesh_file(mesh_file, folders)
            except SceneError as exc:
                raise SceneError(f"{where}: {exc}") from None
        elif "primitive" in spec:
            objs = [primitive(spec, where)]
            primitive_triangles += len(objs[0].triangles)
            if primitive_triangles > MAX_PRIMITIVE_TRIANGLES:
                raise SceneError(
                    f"{where}: the file's primitives have more than {MAX_PRIMITIVE_TRIANGLES} triangles; "
                    "place copies of one with `transforms` (instances) instead"
                )
        else:  # a misspelt file or primitive: the error names the nearest of every object key
            every_object_key = sorted(
                {*OBJECT_KEYS, *FILE_OBJECT_KEYS, *(k for keys in PRIMITIVE_KEYS.values() for k in keys)}
            )
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
        spot = (
            {}
            if kind == "point"
            else dict(
                spot_direction=_vec(spec.get("direction"), f"{where}: direction"),
                spot_size=math.radians(_number(spec, "spot_size", 45.0, where)),
                spot_blend=_number(spec, "spot_blend", 0.15, where),
            )
        )
        try:
            scene.lights.append(
                PointLight(position, colour(spec.get("color", [1, 1, 1]), f"{where}: color"), power, **spot)
            )
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
            fov,
            shift=tuple(_vec(c.get("shift", [0, 0]), f"{where}.shift", 2)),
            clip_start=clip_start,
            clip_end=clip_end,
        )
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
    x_axis = _vec(
        spec.get("x_axis", [1, 0, 0] if abs(direction[0]) < 0.9 * np.linalg.norm(direction) else [0, 1, 0]),
        f"{where}: x_axis",
    )
    size = _vec(spec.get("size", [0.1, 0.1]), f"{where}: size", 2)
    shape = spec.get("shape", "rectangle")
    if shape not in ("rectangle", "disc"):
        raise SceneError(f"{where}: unknown area light shape {shape!r} (rectangle, disc)")
    emission = colour(spec.get("emission", [1, 1, 1]), f"{where}: emission")
    w = direction / max(np.linalg.norm(direction), 1e-300)
    u = x_axis - (x_axis @ w) * w
    if not (np.linalg.norm(direction) > 0 and np.linalg.norm(u) > 1e-9 * np.linalg.norm(x_axis)) or np.any(size <= 0):
        raise SceneError(
            f"{where}: an area light needs a non-zero direction, an x_axis not along it and a positive size"
        )
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
        mesh = trimesh.creation.icosphere(
            subdivisions=_whole(spec, "subdivisions", 3, where, 0, MAX_SUBDIVISIONS),
            radius=_number(spec, "radius", 0.1, where, positive=True),
        )
    elif kind == "box":
        size = _vec(spec.get("size", [0.2, 0.2, 0.2]), f"{where}: size")
        if not np.all(size > 0):
            raise SceneError(f"{where}: size must be positive, got {size.tolist()}")
        mesh = trimesh.creation.box(extents=size)
    else:
        mesh = trimesh.creation.torus(
            major_radius=_number(spec, "radius", 0.15, where, positive=True),
            minor_radius=_number(spec, "tube", 0.05, where, positive=True),
        )
    return clean(SceneObject(name, mesh.vertices + center, mesh.faces), where)


def load_scenes(paths, allowed=()) -> Scene:
    """The scene files' objects and lights in order; `allowed`: folders beyond each file's own that
    the files they refer to may be read from."""
    scene = Scene()
    for p in paths:
        scene.extend(load_scene_file(p, allowed))
    return scene
