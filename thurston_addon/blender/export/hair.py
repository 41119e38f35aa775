"""Hair as Cycles renders it, as thin tube meshes shaded with smooth normals round them. Hair
particle systems: each strand (the children where the system has any, else the parents, as
Cycles) along the path Blender evaluates for the render (its keys: 2^steps + 1 per strand), of
Cycles' radius tapering from root to tip by the system's shape, in the material the system names.
Curves objects (Blender's hair since 3.3): each curve through its evaluated points, of the radius
attribute (Cycles' 0.005 where there is none), in the object's first material."""

from __future__ import annotations

import math

import numpy as np

from ... import scenes

HAIR_SIDES = 6  # a tube's sides
HAIR_STRANDS_MOST = 100_000  # strands per system; beyond, every k-th is shown, and noted
# A regular polygon of circumradius R has mean width (over the directions it is seen from) its
# perimeter / pi; so that a tube covers as much as Cycles' round curve of radius r on average:
WIDTH_FACTOR = math.pi / (HAIR_SIDES * math.sin(math.pi / HAIR_SIDES))


def hair_systems(obj, render: bool) -> list:
    """The evaluated object's hair particle systems drawn as strands (Path), their modifier enabled
    for this depsgraph's mode (render or viewport)."""
    shown = {
        mod.particle_system.name
        for mod in obj.original.modifiers
        if mod.type == "PARTICLE_SYSTEM" and (mod.show_render if render else mod.show_viewport)
    }
    return [
        psys
        for psys in obj.particle_systems
        if psys.name in shown and psys.settings.type == "HAIR" and psys.settings.render_type == "PATH"
    ]


def strand_keys(obj, psys, render: bool) -> tuple[np.ndarray, int]:
    """(strands, keys, 3) world positions of the strands Cycles renders (children if any, unless
    the parents are asked for too), at most HAIR_STRANDS_MOST of them (evenly spaced), and how
    many there are in all."""
    settings = psys.settings
    steps = 2 ** (settings.render_step if render else settings.display_step) + 1
    parents, children = len(psys.particles), len(psys.child_particles)
    first = parents if children and not settings.use_parent_particles else 0
    total = parents + children - first
    chosen = first + np.linspace(0, total - 1, min(total, HAIR_STRANDS_MOST)).round().astype(int)
    keys = np.array(
        [[psys.co_hair(obj, particle_no=int(i), step=s)[:] for s in range(steps)] for i in chosen], float
    ).reshape(len(chosen), steps, 3)
    return keys, total


def radii(settings, keys: int) -> np.ndarray:
    """Cycles' radius at each key of a strand: root and tip (each times Radius Scale / 2) blended
    by the shape (Cycles' shaperadius), 0 at the tip when the tip is closed."""
    scale = settings.radius_scale * 0.5
    root, tip, shape = settings.root_radius * scale, settings.tip_radius * scale, settings.shape
    t = 1.0 - np.linspace(0.0, 1.0, keys)
    if shape < 0:
        t = t ** (1.0 + shape)
    elif shape > 0:
        t = t ** (1.0 / (1.0 - shape))
    r = t * (root - tip) + tip
    if settings.use_close_tip:
        r[-1] = 0.0
    return r


def tubes(keys: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tube meshes round polylines (strands, keys, 3) of the given radius at each key (keys, or
    strands x keys): vertices, triangles (wound outwards) and corner normals (round the tube).
    Where every strand's last radius is 0, the tubes close there in a point."""
    n, k, _ = keys.shape
    radius = np.broadcast_to(radius, (n, k))
    tangent = np.gradient(keys, axis=1)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=-1, keepdims=True), 1e-30)
    # a normal per strand, from the axis least along its mean direction
    mean = tangent.mean(axis=1)
    axis = np.eye(3)[np.argmin(np.abs(mean), axis=1)]
    normal = np.cross(tangent, axis[:, None, :])
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-30)
    binormal = np.cross(tangent, normal)
    angle = 2 * math.pi * np.arange(HAIR_SIDES) / HAIR_SIDES
    closed = bool(np.all(radius[:, -1] == 0))
    rings = k - 1 if closed else k
    around = (
        np.cos(angle)[None, None, :, None] * normal[:, :rings, None, :]
        + np.sin(angle)[None, None, :, None] * binormal[:, :rings, None, :]
    )  # (n, rings, sides, 3)
    ring_vertices = keys[:, :rings, None, :] + WIDTH_FACTOR * radius[:, :rings, None, None] * around
    per_strand = rings * HAIR_SIDES + (1 if closed else 0)
    s = np.arange(HAIR_SIDES)
    a = np.arange(rings - 1)[:, None] * HAIR_SIDES + s  # (rings - 1, sides): ring j, side s
    b = np.arange(rings - 1)[:, None] * HAIR_SIDES + (s + 1) % HAIR_SIDES
    local = np.concatenate(
        [
            np.stack([a, b, b + HAIR_SIDES], -1).reshape(-1, 3),
            np.stack([a, b + HAIR_SIDES, a + HAIR_SIDES], -1).reshape(-1, 3),
        ]
    )
    vertices = ring_vertices.reshape(n, rings * HAIR_SIDES, 3)
    vertex_normals = around.reshape(n, rings * HAIR_SIDES, 3)
    if closed:
        last = (rings - 1) * HAIR_SIDES
        apex = rings * HAIR_SIDES
        local = np.concatenate(
            [local, np.stack([last + s, last + (s + 1) % HAIR_SIDES, np.full(HAIR_SIDES, apex)], -1)]
        )
        vertices = np.concatenate([vertices, keys[:, -1:, :]], axis=1)
        vertex_normals = np.concatenate([vertex_normals, tangent[:, -1:, :]], axis=1)
    triangles = (local[None] + per_strand * np.arange(n)[:, None, None]).reshape(-1, 3)
    vertices, vertex_normals = vertices.reshape(-1, 3), vertex_normals.reshape(-1, 3)
    return vertices, triangles.astype(np.int32), vertex_normals[triangles]


def hair_objects(obj, scale: float, render: bool, material) -> tuple[list[scenes.SceneObject], list[str]]:
    """The evaluated object's hair as scene objects in chart coordinates (world / scale), one per
    system, with `material(slot material)` its scene material; and notes (systems thinned)."""
    objects, notes = [], []
    name = obj.original.name
    for psys in hair_systems(obj, render):
        settings = psys.settings
        keys, total = strand_keys(obj, psys, render)
        if len(keys) == 0:
            continue
        if len(keys) < total:
            notes.append(f"{name} ({psys.name}: {len(keys)} of its {total} strands)")
        vertices, triangles, normals = tubes(keys / scale, radii(settings, keys.shape[1]) / scale)
        slots = obj.material_slots
        slot = min(max(settings.material - 1, 0), len(slots) - 1) if len(slots) else None
        mat = material(slots[slot].material if slot is not None else None)
        objects.append(
            scenes.SceneObject(
                f"{name} ({psys.name})",
                vertices,
                triangles,
                mat.color,
                mat.emission,
                pass_index=obj.original.pass_index,
                corner_normals=normals,
                materials=[mat],
            )
        )
    return objects, notes


CURVES_RADIUS = 0.005  # Cycles' radius of curves without a radius attribute


def curves_object(inst, obj, scale: float, material) -> scenes.SceneObject | None:
    """A Curves object's evaluated curves as tubes in chart coordinates (world / scale), through
    their points (Catmull-Rom and Bezier curves: their control points joined straight), the radius
    scaled as the object's size; None where it has no curve of two points or more."""
    data = obj.data
    points, curves = len(data.points), len(data.curves)
    if curves == 0:
        return None
    position = np.empty(points * 3, np.float32)
    data.position_data.foreach_get("vector", position)
    offsets = np.empty(curves + 1, np.int32)
    data.curve_offset_data.foreach_get("value", offsets)
    attribute = data.attributes.get("radius")
    radius = np.full(points, CURVES_RADIUS, np.float32)
    if attribute is not None and attribute.domain == "POINT" and attribute.data_type == "FLOAT":
        attribute.data.foreach_get("value", radius)
    M = np.array(inst.matrix_world, float)
    world = position.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]
    size = abs(np.linalg.det(M[:3, :3])) ** (1 / 3)
    lengths = np.diff(offsets)
    parts = []
    for k in np.unique(lengths[lengths >= 2]):  # curves of k points together
        index = offsets[:-1][lengths == k][:, None] + np.arange(k)
        parts.append(tubes(world[index] / scale, radius[index] * size / scale))
    if not parts:
        return None
    base = np.cumsum([0] + [len(v) for v, _, _ in parts[:-1]])
    mat = material(obj.material_slots[0].material if len(obj.material_slots) else None)
    name = obj.original.name if not inst.is_instance else f"{obj.original.name} ({inst.parent.original.name})"
    return scenes.SceneObject(
        name,
        np.concatenate([v for v, _, _ in parts]),
        np.concatenate([t + b for (_, t, _), b in zip(parts, base)]).astype(np.int32),
        mat.color,
        mat.emission,
        pass_index=obj.original.pass_index,
        corner_normals=np.concatenate([n for _, _, n in parts]),
        materials=[mat],
    )
