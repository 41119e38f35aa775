"""The scene compiled for the tracer: the triangles of every object and of its copies g(object)
that can reach the domain (instanced or flattened), their surfaces, and the lights' and emitters'
copies."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np

from .. import checks
from ..geometries import faces
from ..scenes import Scene, SceneError
from ..spaces import Space, SpaceError
from .lights import light_copies, light_reach_for
from .settings import RenderError, Settings


def _object_copies(space: Space, obj, C):
    """The copies g(obj) that can reach the domain, each as (model vertices, indices of the kept
    triangles, the isometry g), and whether every vertex of the object is brought into the domain
    by one of them. The copies are taken around the copy that has the most of its vertices in the
    domain, so an object anywhere in the universal cover is shown, as the camera is
    (checks.home_element)."""
    g = space.geometry
    try:
        home = checks.home_element(space, obj.vertices)
    except SpaceError as exc:
        raise SceneError(f"object {obj.name!r}: {exc}") from None
    X = g.to_model(obj.vertices) @ home.T
    T = obj.triangles
    box = _box_corners(g, obj.vertices)
    for rings in range(1, g.copy_rings + 1):
        copies = []
        covered = np.zeros(len(X), bool)
        for M in space.neighbourhood(rings):
            verdict = None if box is None else _box_verdict(box @ (M @ home).T, C)
            if verdict is False:
                continue  # the object's box is beyond a face: no vertex of this copy meets the domain
            Y = X @ M.T
            if verdict is True:  # the box is inside every face: every vertex and triangle stays
                covered[:] = True
                copies.append((Y, np.arange(len(T)), M @ home))
                continue
            ok = g.charted(Y)  # the copy stays on the chart's side
            H = g.plane_coordinates(Y)
            outside = (H / np.linalg.norm(H, axis=1)[:, None]) @ C.T > 1e-9
            covered |= ok & ~outside.any(axis=1)
            keep = _kept_triangles(T, ok, outside)
            if len(keep):
                copies.append((Y, keep, M @ home))
        if covered.all():
            break
    return copies, covered


def _box_corners(g, x):
    """The homogeneous corners (x, 1) (8, 4) of the chart box of the points x, where the domain's face
    tests and the chart test of every copy are linear in (x, 1) up to a positive factor (projective
    geometries, and chart planes with affine isometries: Nil, Sol); else None."""
    if not (g.projective or (g.affine_isometries and isinstance(g.face_shape, faces.ChartPlanes))):
        return None
    lo, hi = np.min(x, axis=0), np.max(x, axis=0)
    corners = np.array([[(lo, hi)[(k >> i) & 1][i] for i in range(3)] for k in range(8)])
    return np.concatenate([corners, np.ones((8, 1))], axis=1)


def _box_verdict(Z, C):
    """What the copy's box corners Z (8, 4) say of every point in the box, for _object_copies' tests
    (a vertex is outside face f where c_f . Y > 1e-9 |Y|, charted where Y[3] > 1e-9 |Y|): False where
    all are outside one face, True where all are charted and inside every face, None where the
    vertices must be tested. Sound: each c_f . Y is linear over the box, so its least and largest
    values are at corners, and |Y| is convex, so its largest is at a corner."""
    largest = 1e-9 * np.max(np.linalg.norm(Z, axis=1))
    sides = Z @ C.T
    if np.any(np.min(sides, axis=0) > largest):
        return False
    if np.max(sides) <= 0 and np.min(Z[:, 3]) > largest:
        return True
    return None


def _kept_triangles(T, ok, outside) -> np.ndarray:
    """The indices of the triangles T that are not wholly outside one face plane (`outside`: (n,
    faces), each vertex's side of each face) and whose vertices all stay on the chart's side
    (`ok`). Each vertex's faces are packed into the bits of one integer, so a triangle is tested
    by two gathers of its corners, not one per face."""
    faces = outside.shape[1]
    if ok.all() and not outside.any():
        return np.arange(len(T))  # the copy holds every vertex: every triangle stays
    if outside.all(axis=0).any():
        return np.zeros(0, np.intp)  # every vertex beyond one face: no triangle meets the domain
    if faces > 64:
        keep = ~np.any(outside[T[:, 0]] & outside[T[:, 1]] & outside[T[:, 2]], axis=1) & ok[T].all(axis=1)
        return np.flatnonzero(keep)
    bits = next(t for t in (np.uint8, np.uint16, np.uint32, np.uint64) if np.dtype(t).itemsize * 8 >= faces)
    code = np.zeros(len(outside), bits)
    for f in range(faces):
        code |= outside[:, f].astype(bits) << bits(f)
    corner = code[T]
    bad = ~ok[T]
    keep = ((corner[:, 0] & corner[:, 1] & corner[:, 2]) == 0) & ~(bad[:, 0] | bad[:, 1] | bad[:, 2])
    return np.flatnonzero(keep)


def _used_vertices(T, count: int):
    """(the vertices that the triangles T use, in order; T numbered among them): what
    np.unique(T, return_inverse=True) gives, by marking instead of sorting."""
    used = np.zeros(count, bool)
    used[T] = True
    index = np.flatnonzero(used)
    renumber = np.cumsum(used) - 1
    return index, renumber[T]


def _taken(a, kept):
    """a[kept], or a itself where `kept` is all of its rows (kept is increasing)."""
    return a if len(kept) == len(a) else a[kept]


class _Surfaces:
    """The tracer's surface arrays of the objects' copies: each triangle's material (the objects'
    materials numbered in one table, their textures shared), corner UVs, and corner normals
    carried to each copy."""

    def __init__(self, objects):
        self.objects = objects
        self.material_offset, self.materials, self.textures = [], [], {}
        for obj in objects:
            self.material_offset.append(len(self.materials))
            self.materials += obj.surface_materials()[0]
        for m in self.materials:
            for t in (m.color_texture, m.emission_texture):
                if t is not None:
                    self.textures.setdefault(id(t), t)
        self.with_normals = any(o.corner_normals is not None for o in objects)
        # objects without UVs read their textures at UV (0, 0), as Cycles does (and an OBJ corner without vt)
        self.with_uvs = bool(self.textures) or any(o.corner_uvs is not None for o in objects)
        self.material, self.normals, self.uvs = [], [], []

    def add_copy(self, space: Space, index: int, obj, Y, kept, M):
        """The copy Y = M X (model vertices) of `obj` (object `index`, or one of its placements),
        with its triangles `kept`."""
        self._add(index, obj, kept, lambda: _copy_normals(space, obj, Y, kept, M))

    def add_mesh(self, index: int):
        """Object `index`'s mesh as it is, for its instances (which carry its normals themselves)."""
        obj = self.objects[index]
        kept = np.arange(len(obj.triangles))
        self._add(index, obj, kept, lambda: _unit(_own_normals(obj, kept)))

    def _add(self, index, obj, kept, normals):
        self.material.append(_taken(obj.surface_materials()[1], kept) + self.material_offset[index])
        if self.with_uvs:
            self.uvs.append(_taken(obj.corner_uvs, kept) if obj.corner_uvs is not None else np.zeros((len(kept), 3, 2)))
        if self.with_normals:
            self.normals.append(normals())

    def arrays(self, triangles: int) -> dict:
        textures = {key: i for i, key in enumerate(self.textures)}

        def texture_index(t):
            return -1 if t is None else textures[id(t)]

        def stacked(parts, shape):
            whole = parts[0] if len(parts) == 1 else np.concatenate(parts) if parts else np.zeros((0, *shape))
            return np.ascontiguousarray(whole, np.float32)

        out = dict(
            triangle_material=np.ascontiguousarray(
                np.concatenate(self.material) if self.material else np.zeros(0), np.int32
            ),
            material_color=np.array([m.color for m in self.materials], np.float32).reshape(-1, 3),
            material_emission=np.array([m.emission for m in self.materials], np.float32).reshape(-1, 3),
            material_color_texture=np.array([texture_index(m.color_texture) for m in self.materials], np.int32),
            material_emission_texture=np.array([texture_index(m.emission_texture) for m in self.materials], np.int32),
            material_one_sided=np.array([m.one_sided for m in self.materials], np.int32),
            material_scattering=np.array(
                [[m.roughness, m.metallic, m.specular, m.ior] for m in self.materials], np.float32
            ).reshape(-1, 4),
            textures=[np.ascontiguousarray(t, np.float32) for t in self.textures.values()],
        )
        if self.with_uvs:
            out["corner_uvs"] = stacked(self.uvs, (3, 2))
        if self.with_normals:
            out["corner_normals"] = stacked(self.normals, (3, 3))
        return out


def _copy_normals(space: Space, obj, Y, kept, M):
    """The object's corner normals (or its face normals) on its copy Y = M X: chart covectors move
    by the inverse transpose of the differential of x -> chart(M model(x)) at each vertex,
    computed by the geometry's own differentials of the chart."""
    g = space.geometry
    x = obj.vertices
    T = _taken(obj.triangles, kept)
    n = _own_normals(obj, kept)
    if np.array_equal(M, np.eye(4)):
        return _unit(n)  # the object's own copy: normals stay
    if g.affine_isometries:  # M acts on (x, 1): its differential is M's linear part everywhere
        J = np.asarray(M, float)[:3, :3]
        return _unit(np.linalg.solve(J.T, n.reshape(-1, 3).T).T.reshape(n.shape))
    used, local = _used_vertices(T, len(x))
    # the differential's columns: the images of the chart's unit vectors at each used vertex
    J = np.stack(
        [
            g.tangent_to_chart(Y[used], g.tangent_to_model(x[used], np.broadcast_to(e, (len(used), 3))) @ M.T)
            for e in np.eye(3)
        ],
        axis=-1,
    )
    Jt = np.swapaxes(J, 1, 2)[local.reshape(-1, 3)]  # (m, 3, 3, 3): J^T at each corner
    return _unit(np.linalg.solve(Jt, n[..., None])[..., 0])


def _own_normals(obj, kept):
    """The corner normals of the kept triangles, or for flat shading each face's chart normal at
    its corners."""
    if obj.corner_normals is not None:
        return _taken(obj.corner_normals, kept)
    P = obj.vertices[_taken(obj.triangles, kept)]
    return np.repeat(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])[:, None, :], 3, axis=1)


def own_hits(space: Space, out: dict):
    """The hits' chart points and unit normals in the space's own domain (a folded space's tracer
    walks its double cover: space.unfolded)."""
    position, normal = space.unfolded(out["position"], out["normal"])
    return position, _unit(normal)


def _folded(obj, fold):
    """A flat object's image under a space's fold: its vertices moved by it, its corner normals by
    its differential (the folds are conformal, so normals stay normal), its triangles and surfaces
    kept (the folds preserve orientation)."""
    normals = (
        None if obj.corner_normals is None else _unit(fold.vectors(obj.vertices[obj.triangles], obj.corner_normals))
    )
    return replace(obj, vertices=fold.points(obj.vertices), corner_normals=normals)


def _unit(n):
    return n / np.maximum(np.sqrt(np.einsum("...i,...i->...", n, n))[..., None], 1e-300)


def _instance_copies(space: Space, obj, C):
    """The copies g(placement) of an instanced object's placements that can reach the domain:
    (chart maps of the copies that stay instances, (placed object, Y, kept, M) of the copies that
    are flattened, how many placements are not shown, how many reach beyond the copies searched).
    E3, Nil and Sol: isometries are affine in the chart, so every copy is an instance, its map
    g A. A placement is tested by its mesh's bounding box (its 8 corners: a copy whose corners
    all lie beyond one face cannot meet the domain, and a box inside one copy of the domain is
    covered); a placement whose box no copy holds is tested by its vertices, as flat objects are.
    S3, H3, H2xR: their isometries are not affine in the chart, so only a placement's identity copy
    stays an instance; its other copies reaching the domain are flattened (transformed triangles)."""
    g = space.geometry
    A = obj.instances
    affine = g.affine_isometries
    exact = np.ones(len(A), bool)  # placements tested by their vertices
    instances, flat = [], []
    if affine:
        homes = checks.home_elements(space, A[:, :3, :3] @ obj.vertices.mean(axis=0) + A[:, :3, 3])
        lo, hi = obj.vertices.min(axis=0), obj.vertices.max(axis=0)
        corners = g.to_model(np.array([[(hi if (i >> a) & 1 else lo)[a] for a in range(3)] for i in range(8)]))
        placed = np.einsum("kij,kjl,cl->kci", homes, A, corners)
        covered = np.zeros(len(A), bool)
        reaching = []
        for M in space.neighbourhood(1):
            Y = placed @ M.T
            outside = (Y / np.linalg.norm(Y, axis=-1, keepdims=True)) @ C.T > 1e-9  # (k, 8, faces)
            reaching.append((M, ~outside.all(axis=1).any(axis=1)))
            covered |= ~outside.any(axis=(1, 2))
        instances = [(M @ homes @ A)[reach & covered] for M, reach in reaching]
        exact = ~covered
    missing = beyond = 0
    for j in np.flatnonzero(exact):
        one = obj.placed(A[j : j + 1])
        if not np.all(g.in_chart(one.vertices)):
            raise SceneError(
                f"object {obj.name!r}: instance {j} has vertices outside the chart of {g.name} "
                f"(the Klein chart is the open unit ball)"
            )
        copies, covered = _object_copies(space, one, C)
        missing += not copies
        beyond += bool(copies) and not covered.all()
        for Y, kept, M in copies:
            if affine or np.allclose(M, np.eye(4), rtol=0, atol=1e-12):
                instances.append((M @ A[j])[None])
            else:
                flat.append((one, Y, kept, M))
    return np.concatenate(instances) if instances else np.zeros((0, 4, 4)), flat, missing, beyond


def geodesic_loop(space: Space) -> float:
    """The length after which every geodesic returns to its start: pi in S3 where -1 is in the group
    (the Poincare sphere), as X and -X are one point; inf elsewhere."""
    loop = space.geometry.antipode_distance
    if math.isfinite(loop) and any(np.allclose(M, -np.eye(4)) for M in space.elements_within(loop + 1e-6)):
        return loop
    return math.inf


def compile_scene(space: Space, scene: Scene, light_reach: float | None = None):
    """Tracer arrays: triangles of every object and of its copies g(object) that can reach the domain
    (parts sticking out re-enter through the paired faces), and the lights' copies: every copy
    within light_reach of the domain (None: the default within the distance limit; each lights
    every point within its reach: an infinite reach needs a finite group)."""
    g = space.geometry
    C = space.domain.covectors()
    C = C / np.linalg.norm(C, axis=1)[:, None]
    if light_reach is None:
        light_reach = light_reach_for(space, Settings())
    if space.group_order is None and not math.isfinite(light_reach):
        raise RenderError(f"{space.name}: an infinite group needs a finite light reach")
    flat, meshes = [], []  # flat: (object index, source object, Y, kept, M); meshes: (index, chart maps)
    for index, obj in enumerate(scene.objects):
        if len(obj.triangles) == 0:  # (not "outside the domain": there is nothing to place)
            warnings.warn(
                f"object {obj.name!r} has no triangle with an area (every one is degenerate, its corners "
                "on one line): not shown",
                stacklevel=2,
            )
            continue
        # a folded space's double cover holds the object's image under the fold too (flattened)
        mirrored = [] if space.fold is None else [_folded(obj.placed(), space.fold)]
        if obj.instances is not None:
            try:
                maps, flattened, missing, beyond = _instance_copies(space, obj, C)
            except SpaceError as exc:
                raise SceneError(f"object {obj.name!r}: {exc}") from None
            meshes += [(index, maps)] if len(maps) else []
            flat += [(index, *copy) for copy in flattened]
            if missing:
                warnings.warn(
                    f"object {obj.name!r}: {missing} of its {len(obj.instances)} instances lie outside the "
                    f"domain and its neighbouring copies: not shown",
                    stacklevel=2,
                )
            if beyond:
                warnings.warn(
                    f"object {obj.name!r}: {beyond} of its {len(obj.instances)} instances reach beyond the "
                    f"copies of the domain around them: parts of them are missing",
                    stacklevel=2,
                )
        for placed in ([] if obj.instances is not None else [obj]) + mirrored:
            if not np.all(g.in_chart(placed.vertices)):
                raise SceneError(
                    f"object {obj.name!r} has vertices outside the chart of {g.name} (the Klein chart is the open unit ball)"
                )
            copies, covered = _object_copies(space, placed, C)
            flat += [(index, placed, *copy) for copy in copies]
            if not copies and placed is obj:
                warnings.warn(
                    f"object {obj.name!r} lies outside the domain and its neighbouring copies: not shown", stacklevel=2
                )
            elif not covered.all():
                warnings.warn(
                    f"object {obj.name!r} reaches beyond the copies of the domain around it: "
                    f"{int((~covered).sum())} of its vertices are farther out and parts of it are missing",
                    stacklevel=2,
                )
    # The triangles: the flat copies (mesh 0, placed by the identity), then each instanced mesh.
    verts, tris, owner = [], [], []
    surfaces = _Surfaces(scene.objects)
    offset = 0
    for index, source, Y, kept, M in flat:
        used, local = _used_vertices(_taken(source.triangles, kept), len(source.vertices))
        verts.append(g.mesh_to_chart(Y[used]))
        tris.append(local.reshape(-1, 3) + offset)
        owner.append(np.full(len(kept), index, np.int32))
        offset += len(used)
        surfaces.add_copy(space, index, source, Y, kept, M)
    instancing = {}
    if meshes:
        first, mesh_of, maps_of, object_of = [0], [0], [np.eye(4)], [0]
        for index, maps in meshes:
            obj = scene.objects[index]
            first.append(sum(len(t) for t in tris))
            verts.append(obj.vertices)
            tris.append(obj.triangles + offset)
            owner.append(np.zeros(len(obj.triangles), np.int32))  # the instances give the object
            offset += len(obj.vertices)
            surfaces.add_mesh(index)
            mesh_of += [len(first) - 1] * len(maps)
            maps_of.append(maps)
            object_of += [index] * len(maps)
        instancing = dict(
            mesh_first_triangle=np.array(first, np.int32),
            instance_mesh=np.array(mesh_of, np.int32),
            instance_transform=np.ascontiguousarray(np.vstack([np.reshape(m, (-1, 4, 4)) for m in maps_of])[:, :3]),
            instance_object=np.array(object_of, np.int32),
        )
    V = verts[0] if len(verts) == 1 else np.vstack(verts) if verts else np.zeros((0, 3))
    T = np.vstack(tris).astype(np.int32) if tris else np.zeros((0, 3), np.int32)
    O = np.concatenate(owner) if owner else np.zeros(0, np.int32)
    colors = np.array([o.color for o in scene.objects], np.float32).reshape(-1, 3)
    emission = np.array([o.emission for o in scene.objects], np.float32).reshape(-1, 3)
    lifts, axes, elements, of_lift, radiance = [], [], [], [], []
    if scene.lights and not g.point_lights:
        raise SceneError(
            f"{g.name} spaces have no point lights (their light paths are not traced): remove the scene's "
            f"{len(scene.lights)} light(s) and render with a pseudo-colour shading (normal, depth, position, "
            "object, crossings)"
        )
    for i, light in enumerate(scene.lights):
        if not np.all(g.in_chart(light.position)):
            raise SceneError(f"light {i} at {light.position} is outside the chart of {g.name}")
        if not (math.isfinite(light.power) and light.power >= 0):
            raise SceneError(f"light {i}: power must be a finite number >= 0, got {light.power}")
        # a folded space's double cover holds the light's image under the fold too
        images = [(light.position, light.spot_direction)] + (
            []
            if space.fold is None
            else [
                (
                    space.fold.points(light.position),
                    None if light.spot_direction is None else space.fold.vectors(light.position, light.spot_direction),
                )
            ]
        )
        for position, direction in images:
            copies, light_axes, light_elements = _light_lifts(space, position, direction, i, light_reach)
            lifts += copies
            axes += light_axes
            elements += light_elements
            of_lift += [i] * len(copies)
        radiance.append(np.asarray(light.color, float) * light.power)
    return dict(
        geometry=g.kernel,
        # what configures the kernel (graph's bumps; none for the others)
        geometry_parameters=list(g.kernel_parameters),
        face_covectors=np.ascontiguousarray(space.domain.covectors()),
        face_maps=np.ascontiguousarray(np.array([f.pairing for f in space.domain.faces])),
        vertices=np.ascontiguousarray(V, np.float64),
        triangles=np.ascontiguousarray(T),
        triangle_object=np.ascontiguousarray(O),
        object_color=colors,
        object_emission=emission,
        **surfaces.arrays(len(T)),
        **instancing,
        light_lifts=np.array(lifts, np.float64).reshape(-1, 4),
        light_of_lift=np.array(of_lift, np.int32),
        light_radiance=np.array(radiance, np.float32).reshape(-1, 3),
        light_reach=light_reach,
        geodesic_loop=geodesic_loop(space),
        **_spot_arrays(scene.lights, axes),
        # the group elements that carry each light's frame to its lifts (its visibility map); not
        # in a folded space, where a light's lifts are copies of two points
        **({} if space.fold is not None else {"light_copies": np.array(elements, np.float64).reshape(-1, 4, 4)}),
        **_emitter_arrays(space, scene, light_reach),
    )


def _light_lifts(space: Space, position, direction, index: int, reach: float):
    """The copies of light `index` at `position` that the tracer lights with (model points,
    light_copies), the unit axis at each where it is a spot light along `direction` (else zero),
    and the group element that takes the light (its copy in the domain) to each."""
    g = space.geometry
    try:  # its copies are taken around the domain, so start from the copy inside
        L, _, M0 = space.bring_inside(g.to_model(position))
    except SpaceError as exc:
        raise SceneError(f"light {index}: {exc}") from None
    elements = light_copies(space, L, reach)
    axis = np.zeros(4)
    if direction is not None:
        axis = g.normalize_tangent(L, M0 @ g.tangent_to_model(position, direction))
    return [g.normalize_point(M @ L) for M in elements], [M @ axis for M in elements], list(elements)


def _spot_arrays(lights, axes) -> dict:
    """The tracer's cones (Cycles' smoothstep, scenes.PointLight.cone) and axes where a light is a spot."""
    if not any(light.spot_direction is not None for light in lights):
        return {}
    return dict(
        light_cone=np.array([light.cone() for light in lights], np.float64).reshape(-1, 2),
        light_axis=np.array(axes, np.float64).reshape(-1, 4),
    )


EMITTER_RADIUS_MARGIN = 1.25  # chart triangles of curved charts bulge a little beyond their corners' distances


def _emitter_arrays(space: Space, scene: Scene, reach: float) -> dict:
    """The emissive triangles as lights: per emissive object (each placement of an instanced one,
    and in a folded space each one's image under the fold)
    its emitting triangles in one copy, the one that brings its first vertex into the domain (their
    group), and the group elements of the copies of it that can come within `reach` of the domain:
    the copies of that vertex within reach + the group's radius about it (light_copies), a point's
    copies lighting the domain as a point light's do. Radiance: the material's emission times its
    texture's mean (emission textures light as their average colour)."""
    g = space.geometry
    triangles, radiance, one_sided, group, copies, copy_group = [], [], [], [], [], []
    for obj in scene.objects:
        materials, of_triangle = obj.surface_materials()
        glow = np.array(
            [
                m.emission
                * (1.0 if m.emission_texture is None else m.emission_texture[..., :3].reshape(-1, 3).mean(axis=0))
                for m in materials
            ]
        )
        emitting = np.flatnonzero(np.any(glow[of_triangle] > 0, axis=1))
        if not len(emitting):
            continue
        placements = [obj] if obj.instances is None else [obj.placed(A[None]) for A in obj.instances]
        # a folded space's double cover holds each placement's image under the fold too
        for placed in placements + ([] if space.fold is None else [_folded(p, space.fold) for p in placements]):
            try:
                L, _, M0 = space.bring_inside(g.to_model(placed.vertices[placed.triangles[emitting[0], 0]]))
            except SpaceError as exc:
                raise SceneError(f"object {obj.name!r}: {exc}") from None
            used = np.unique(placed.triangles[emitting])
            X = g.normalize_point(g.to_model(placed.vertices[used]) @ M0.T)
            radius = EMITTER_RADIUS_MARGIN * float(np.max(g.distance_bound(L, X)))
            corners = np.zeros((len(placed.vertices), 3))
            corners[used] = g.mesh_to_chart(X)
            triangles.append(corners[placed.triangles[emitting]])
            radiance.append(glow[of_triangle[emitting]])
            one_sided.append(np.array([materials[m].one_sided for m in of_triangle[emitting]], np.int32))
            group.append(np.full(len(emitting), len(copies), np.int32))
            elements = light_copies(space, L, reach + radius)
            copy_group.append(np.full(len(elements), len(copies), np.int32))
            copies.append(elements)
    if not triangles:
        return {}
    return dict(
        emitter_triangles=np.ascontiguousarray(np.concatenate(triangles), np.float64),
        emitter_radiance=np.ascontiguousarray(np.concatenate(radiance), np.float32),
        emitter_one_sided=np.concatenate(one_sided),
        emitter_group=np.concatenate(group),
        emitter_copies=np.ascontiguousarray(np.concatenate(copies), np.float64),
        emitter_copy_group=np.concatenate(copy_group),
    )
