"""Scene description, independent of Blender: meshes with a base colour and an emission, point
lights and a camera, all in chart coordinates of the space's fundamental domain.

Filled from mesh files (OBJ, PLY, STL, GLB/glTF via trimesh), from a scene file (TOML: objects,
lights, camera), from Blender's depsgraph (the add-on), or built as the default scene of a space.
Objects are numbered in the order given: files in order, inside a file in the file's order.
"""
from __future__ import annotations

import math
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

MESH_SUFFIXES = {".obj", ".ply", ".stl", ".glb", ".gltf"}
DEFAULT_COLOR = (0.8, 0.8, 0.8)


class SceneError(ValueError):
    """A scene file or scene object that cannot be used."""


@dataclass
class SceneObject:
    name: str
    vertices: np.ndarray  # (n, 3) float64, chart coordinates
    triangles: np.ndarray  # (m, 3) int32
    color: np.ndarray = field(default_factory=lambda: np.array(DEFAULT_COLOR))
    emission: np.ndarray = field(default_factory=lambda: np.zeros(3))
    pass_index: int = 0  # a user's index for the object (Blender's pass_index), kept for compositing

    def __post_init__(self):
        self.vertices = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.triangles = np.asarray(self.triangles, dtype=np.int32).reshape(-1, 3)
        self.color = np.asarray(self.color, dtype=np.float64).reshape(3)
        self.emission = np.asarray(self.emission, dtype=np.float64).reshape(3)


@dataclass
class PointLight:
    position: np.ndarray  # chart coordinates
    color: np.ndarray = field(default_factory=lambda: np.ones(3))
    power: float = 1.0  # radiant intensity scale: radiance at unit "area distance"


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
    """Reject non-finite vertices and bad indices; drop degenerate triangles with a warning."""
    V, T = obj.vertices, obj.triangles
    bad = ~np.all(np.isfinite(V), axis=1)
    if bad.any():
        raise SceneError(f"{where}: object {obj.name!r} has a NaN or infinite vertex (vertex {int(np.argmax(bad))})")
    if len(T) and (T.min() < 0 or T.max() >= len(V)):
        raise SceneError(f"{where}: object {obj.name!r} has a triangle index out of range")
    if len(T):
        area = np.linalg.norm(np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]]), axis=1)
        scale = max(np.ptp(V, axis=0).max(), 1e-300)
        keep = area > 1e-14 * scale * scale
        if not keep.all():
            warnings.warn(f"{where}: object {obj.name!r}: skipped {int((~keep).sum())} degenerate triangle(s)", stacklevel=2)
            obj.triangles = T[keep]
    return obj


# --- mesh files ------------------------------------------------------------------------------------
def _read_obj(path: Path) -> list[SceneObject]:
    """OBJ objects in file order (trimesh regroups OBJ objects by material and loses their order).
    Reads v, f (polygons fanned, negative indices), o/g, usemtl and mtllib (Kd, Ke)."""
    verts: list[list[float]] = []
    objects: list[tuple[str, list[list[int]], str | None]] = []
    materials: dict[str, dict[str, np.ndarray]] = {}
    name, faces, mtl = path.stem, [], None

    def flush():
        if faces:
            objects.append((name, faces, mtl))

    for lineno, raw in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        parts = raw.split("#", 1)[0].split()
        if not parts:
            continue
        tag, args = parts[0], parts[1:]
        try:
            if tag == "v":
                verts.append([float(a) for a in args[:3]])
            elif tag == "f":
                idx = [int(a.split("/")[0]) for a in args]
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                faces += [[idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1)]
            elif tag in ("o", "g") and args:
                flush()
                name, faces = " ".join(args), []
            elif tag == "usemtl" and args:
                if faces:
                    flush()
                    faces = []
                mtl = args[0]
            elif tag == "mtllib" and args:
                materials.update(_read_mtl(path.parent / " ".join(args)))
        except ValueError:
            raise SceneError(f"{path}:{lineno}: cannot parse {raw.strip()!r}") from None
    flush()
    V = np.array(verts, dtype=np.float64).reshape(-1, 3)
    out = []
    for name, faces, mtl in objects:
        T = np.array(faces, dtype=np.int64)
        used, T = np.unique(T, return_inverse=True)
        if used.min() < 0 or used.max() >= len(V):
            raise SceneError(f"{path}: object {name!r} refers to a vertex that does not exist")
        m = materials.get(mtl, {})
        out.append(SceneObject(name, V[used], T.reshape(-1, 3), m.get("Kd", DEFAULT_COLOR), m.get("Ke", np.zeros(3))))
    return out


def _read_mtl(path: Path) -> dict[str, dict[str, np.ndarray]]:
    if not path.is_file():
        warnings.warn(f"material library {path} not found; using default colours", stacklevel=3)
        return {}
    mats: dict[str, dict[str, np.ndarray]] = {}
    current = None
    for raw in path.read_text(encoding="utf-8", errors="replace").splitlines():
        parts = raw.split("#", 1)[0].split()
        if len(parts) >= 2 and parts[0] == "newmtl":
            current = mats.setdefault(parts[1], {})
        elif current is not None and len(parts) >= 4 and parts[0] in ("Kd", "Ke"):
            current[parts[0]] = np.array([float(p) for p in parts[1:4]])
    return mats


def _trimesh_objects(path: Path) -> list[SceneObject]:
    import trimesh

    loaded = trimesh.load(str(path), force="scene", process=False)
    out = []
    order = _gltf_node_order(path)
    for node in sorted(loaded.graph.nodes_geometry, key=lambda n: order.get(n, len(order))):
        transform, geom_name = loaded.graph[node]
        mesh = loaded.geometry[geom_name]
        if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
            continue
        V = trimesh.transform_points(np.asarray(mesh.vertices, dtype=np.float64), transform)
        color, emission = _trimesh_material(mesh)
        out.append(SceneObject(str(node), V, np.asarray(mesh.faces), color, emission))
    return out


def _gltf_node_order(path: Path) -> dict[str, int]:
    """Node name -> index in a glTF/GLB file's node list (trimesh's scene graph loses that order)."""
    import json
    import struct

    if path.suffix.lower() not in (".glb", ".gltf"):
        return {}
    data = path.read_bytes()
    if data[:4] == b"glTF":  # binary: 12-byte header, then the JSON chunk (length, type, data)
        length = struct.unpack_from("<I", data, 12)[0]
        data = data[20:20 + length]
    nodes = json.loads(data.decode("utf-8")).get("nodes", [])
    return {str(n.get("name", i)): i for i, n in enumerate(nodes)}


def _trimesh_material(mesh):
    visual = mesh.visual
    color, emission = np.array(DEFAULT_COLOR), np.zeros(3)
    material = getattr(visual, "material", None)
    if material is not None:
        base = getattr(material, "baseColorFactor", None)
        if base is None:
            base = getattr(material, "diffuse", None)
        if base is not None:
            base = np.asarray(base, dtype=np.float64)[:3]
            color = base / 255.0 if base.max() > 1.0 else base
        emissive = getattr(material, "emissiveFactor", None)
        if emissive is not None:
            emission = np.asarray(emissive, dtype=np.float64)[:3]
    elif getattr(visual, "kind", None) in ("face", "vertex"):
        rgba = visual.face_colors if visual.kind == "face" else visual.vertex_colors
        color = np.asarray(rgba, dtype=np.float64)[:, :3].mean(axis=0) / 255.0
    return color, emission


def load_mesh_file(path: str | Path) -> list[SceneObject]:
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"scene file {str(path)!r} does not exist")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SceneError(f"{path}: unsupported file type {path.suffix!r} (mesh files: {', '.join(sorted(MESH_SUFFIXES))}; scenes: .toml)")
    try:
        objects = _read_obj(path) if path.suffix.lower() == ".obj" else _trimesh_objects(path)
    except SceneError:
        raise
    except Exception as exc:  # trimesh and the file system raise many types
        raise SceneError(f"cannot read mesh file {str(path)!r}: {exc}") from None
    if not objects:
        raise SceneError(f"{path}: the file holds no triangles")
    return [clean(o, str(path)) for o in objects]


# --- scene files (TOML) ------------------------------------------------------------------------------
def _vec(value, where, n=3):
    try:
        v = np.array(value, dtype=np.float64).reshape(n)
    except (TypeError, ValueError):
        raise SceneError(f"{where}: expected {n} numbers, got {value!r}") from None
    if not np.all(np.isfinite(v)):
        raise SceneError(f"{where}: {value!r} is not finite")
    return v


def _number(spec: dict, key: str, default: float, where: str) -> float:
    value = spec.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SceneError(f"{where}: {key} must be a finite number, got {value!r}")
    return float(value)


def load_scene_file(path: str | Path) -> Scene:
    """A mesh file, or a TOML scene file:

        [[object]]            # file = "mesh.obj" (relative to the scene file) or primitive = "sphere"
        file = "knot.glb"     # every object of the file, in its order
        color = [0.9, 0.3, 0.2]      # optional: overrides the file's material
        emission = [0, 0, 0]
        [[object]]
        primitive = "sphere"  # sphere (radius), box (size), torus (radius, tube)
        center = [0.2, 0, 0]
        radius = 0.1
        [[light]]
        position = [0, 0, 0.3]
        color = [1, 1, 1]
        power = 1.0
        [camera]
        position = [0, 0, 0]; forward = [0, 1, 0]; up = [0, 0, 1]; fov = 90
        shift = [0, 0]; clip_start = 0  # lens shift in image widths; clip_end (absent: none)
    """
    path = Path(path)
    if path.suffix.lower() != ".toml":
        return Scene(objects=load_mesh_file(path))
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SceneError(f"scene file {str(path)!r} does not exist") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise SceneError(f"cannot read scene file {str(path)!r}: {exc}") from None
    try:
        return _scene_from_toml(data, path)
    except (TypeError, ValueError, AttributeError) as exc:
        if isinstance(exc, SceneError):
            raise
        raise SceneError(f"{path}: a value has the wrong type: {exc}") from None


def _scene_from_toml(data: dict, path: Path) -> Scene:
    scene = Scene()
    for i, spec in enumerate(data.get("object", [])):
        where = f"{path}: object {i}"
        if "file" in spec:
            if not isinstance(spec["file"], str):
                raise SceneError(f"{where}: file must be a path string, got {spec['file']!r}")
            objs = load_mesh_file(path.parent / spec["file"])
        elif "primitive" in spec:
            objs = [primitive(spec, where)]
        else:
            raise SceneError(f"{where}: needs 'file' or 'primitive'")
        for o in objs:
            if "color" in spec:
                o.color = _vec(spec["color"], f"{where}: color")
            if "emission" in spec:
                o.emission = _vec(spec["emission"], f"{where}: emission")
        scene.objects += objs
    for i, spec in enumerate(data.get("light", [])):
        where = f"{path}: light {i}"
        power = _number(spec, "power", 1.0, where)
        if power < 0:
            raise SceneError(f"{where}: power must be >= 0, got {power:g}")
        scene.lights.append(PointLight(
            _vec(spec.get("position"), f"{where}: position"),
            _vec(spec.get("color", [1, 1, 1]), f"{where}: color"),
            power,
        ))
    if "camera" in data:
        c = data["camera"]
        scene.camera = Camera(
            _vec(c.get("position", [0, 0, 0]), f"{path}: camera.position"),
            _vec(c.get("forward", [0, 1, 0]), f"{path}: camera.forward"),
            _vec(c.get("up", [0, 0, 1]), f"{path}: camera.up"),
            _number(c, "fov", 90.0, f"{path}: camera"),
            shift=tuple(_vec(c.get("shift", [0, 0]), f"{path}: camera.shift", 2)),
            clip_start=_number(c, "clip_start", 0.0, f"{path}: camera"),
            clip_end=_number(c, "clip_end", 0.0, f"{path}: camera") if "clip_end" in c else None,
        )
    return scene


def primitive(spec: dict, where: str) -> SceneObject:
    import trimesh

    kind = spec["primitive"]
    center = _vec(spec.get("center", [0, 0, 0]), f"{where}: center")
    if kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=int(_number(spec, "subdivisions", 3, where)), radius=_number(spec, "radius", 0.1, where))
    elif kind == "box":
        mesh = trimesh.creation.box(extents=_vec(spec.get("size", [0.2, 0.2, 0.2]), f"{where}: size"))
    elif kind == "torus":
        mesh = trimesh.creation.torus(major_radius=_number(spec, "radius", 0.15, where), minor_radius=_number(spec, "tube", 0.05, where))
    else:
        raise SceneError(f"{where}: unknown primitive {kind!r} (sphere, box, torus)")
    obj = SceneObject(str(spec.get("name", kind)), mesh.vertices + center, mesh.faces,
                      spec.get("color", DEFAULT_COLOR), spec.get("emission", [0, 0, 0]))
    return clean(obj, where)


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

    size = space.extent
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
    light = PointLight(position, np.ones(3), 0.5 / falloff)
    return Scene(objects=objects, lights=[light])
