"""From a space and a scene to passes: the scene compiled for the tracer (with the copies that
objects sticking out of the domain need), camera rays, the C++ trace, pseudo-colour modes, and the
render's statistics (cost and accuracy)."""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from . import checks
from .files import physical_memory
from .scene import Camera, Scene, SceneError
from .spaces import Space, SpaceError


@dataclass(frozen=True)
class Quality:
    """A quality level: samples per pixel (antialiasing), and the bound of the hit-position error
    as a fraction of the pixel footprint at the hit's distance (where geodesics bend in the chart
    and are followed in chords; in E3, S3 and H3 they are exact chart lines)."""
    samples: int
    footprint_fraction: float


# The same names are used by the add-on. The fractions keep what the chords do to the image below
# what the sampling does at each quality (benchmarks/bench_curved.py, its image table).
QUALITY = {"draft": Quality(1, 1.0), "preview": Quality(2, 0.5), "standard": Quality(4, 0.25),
           "final": Quality(16, 0.1)}
# `thurston trace` has no pixels: its qualities use the pixel of the default view (640 pixels
# across 90 degrees).
REFERENCE_PIXEL_ANGLE = math.radians(90.0) / 640
# The bound stays positive at the camera: distances are counted from this fraction of the
# domain's metric extent behind it.
NEAR_FRACTION = 0.05
RETRACE_FACTOR = 100  # the measured error: sampled rays traced again at tolerance / this
# A chord tolerance's chords grow as 1 / sqrt(tolerance) (Nil: about 65 a ray at 1e-6), and the
# measured error retraces at tolerance / RETRACE_FACTOR: below this a ray takes unbounded time.
MIN_TOLERANCE = 1e-10
SHADING = ("lambert", "normal", "position", "depth", "crossings", "object")
PASSES = ("color", "depth", "normal", "position", "object", "crossings", "stop")
STOP_REASONS = ("hit", "distance", "crossings", "cancelled")


# Peak memory of render() per pixel, whatever the sample count (samples are traced one after the
# other): the rays of one sample (origins, directions and their temporaries), the tracer's output
# for it and for the centre ray, and the colour sum. Measured at about 330 bytes (2000 x 1000, all
# shading modes and projections; tests/test_render.py measures it again); rounded up.
BYTES_PER_PIXEL = 400
MAX_BOUNCES = 1024
MEMORY_FRACTION = 0.8  # refuse renders that would need more than this share of physical memory
# More threads than this gain nothing on any machine, and starting them all could take every
# process id of the system for a moment (each thread has one; 32768 by default).
MAX_THREADS = 4096


def memory_needed(width: int, height: int) -> int:
    return BYTES_PER_PIXEL * int(width) * int(height)


class RenderError(ValueError):
    """Input that cannot be rendered, with a message naming the problem."""


class Cancelled(RuntimeError):
    pass


@dataclass
class Settings:
    width: int = 640
    height: int = 360
    projection: str = "perspective"  # or "equirect"
    quality: str = "standard"
    samples: int | None = None  # samples per pixel; None: the quality's
    shading: str = "lambert"
    max_distance: float | None = None  # None: the space's default
    max_crossings: int | None = None
    fog: float | None = None  # distance at which colour falls to 1/e; None: no fog
    # geodesics to lights longer than this are not summed; None: default_light_reach
    light_reach: float | None = None
    threads: int = 0
    tolerance: float | None = None  # chord tolerance in chart units (S2xR: metric); None: the quality's bound
    light_samples: int = 4  # points sampled on the emissive meshes per shaded point (each sample)
    bounces: int = 0  # bounces after each camera hit (path tracing, any quality); 0: direct light only
    seed: int = 0  # sample k's random numbers (light samples, bounces) come from seed + k
    transparent: bool = False  # alpha: the share of a pixel's samples that hit something (else 1)
    # (x, y, w, h): render only this window of the width x height image, x, y its top-left pixel
    # (rows top-down); None: the whole image
    region: tuple[int, int, int, int] | None = None

    @property
    def window(self) -> tuple[int, int, int, int]:
        return self.region or (0, 0, self.width, self.height)

    @property
    def samples_per_pixel(self) -> int:
        """The samples per pixel: the given count, else the quality's."""
        return self.samples or QUALITY[self.quality].samples

    def check(self):
        if self.width < 1 or self.height < 1:
            raise RenderError(f"image size {self.width}x{self.height} is not usable")
        if self.region is not None:
            x, y, w, h = self.region
            if not (all(_whole(v) for v in self.region) and w >= 1 and h >= 1 and 0 <= x and x + w <= self.width
                    and 0 <= y and y + h <= self.height):
                raise RenderError(f"render region {self.region} is not a window of the {self.width}x{self.height} image")
        need, have = memory_needed(self.width, self.height), physical_memory()
        if have is not None and need > MEMORY_FRACTION * have:
            raise RenderError(f"image size {self.width}x{self.height} needs about {need / 2**30:.1f} GiB of memory "
                              f"to render, more than {MEMORY_FRACTION:.0%} of this machine's {have / 2**30:.1f} GiB")
        if self.width * self.height > 2**28:
            raise RenderError(f"image size {self.width}x{self.height} is not usable (more than 2^28 pixels)")
        if self.projection not in ("perspective", "equirect"):
            raise RenderError(f"unknown projection {self.projection!r} (perspective, equirect)")
        if self.quality not in QUALITY:
            raise RenderError(f"unknown quality {self.quality!r} ({', '.join(QUALITY)})")
        if self.samples is not None and not 1 <= self.samples <= 4096:
            raise RenderError(f"samples per pixel must be between 1 and 4096, got {self.samples}")
        if self.shading not in SHADING:
            raise RenderError(f"unknown shading {self.shading!r} ({', '.join(SHADING)})")
        if self.max_distance is not None and not (self.max_distance > 0 and math.isfinite(self.max_distance)):
            raise RenderError(f"max distance must be a positive number, got {self.max_distance}")
        if self.max_crossings is not None and not (_whole(self.max_crossings) and 0 <= self.max_crossings <= 2**31 - 1):
            raise RenderError(f"max crossings must be a whole number >= 0, got {self.max_crossings}")
        if self.fog is not None and not (self.fog > 0 and math.isfinite(self.fog)):
            raise RenderError(f"fog distance must be a positive number (None: no fog), got {self.fog}")
        if self.light_reach is not None and not self.light_reach >= 0:
            raise RenderError(f"light reach must be a distance >= 0 (None: the space's default), got {self.light_reach}")
        if not (_whole(self.light_samples) and 1 <= self.light_samples <= 4096):
            raise RenderError(f"light samples must be a whole number between 1 and 4096, got {self.light_samples}")
        if not (_whole(self.bounces) and 0 <= self.bounces <= MAX_BOUNCES):
            raise RenderError(f"bounces must be a whole number between 0 (direct light only) and {MAX_BOUNCES}, "
                              f"got {self.bounces}")
        if not (_whole(self.seed) and 0 <= self.seed < 2**63):
            raise RenderError(f"seed must be a whole number >= 0, got {self.seed}")
        if not (_whole(self.threads) and 0 <= self.threads <= MAX_THREADS):
            raise RenderError(f"threads must be a whole number from 0 (all cores) to {MAX_THREADS}, got {self.threads}")
        if self.tolerance is not None and not (MIN_TOLERANCE <= self.tolerance < math.inf):
            raise RenderError(f"tolerance must be a number of chart units of at least {MIN_TOLERANCE:g} (None: the "
                              f"quality's), got {self.tolerance}")

    def tolerances(self, space: Space, pixel_angle: float) -> tuple[float, float]:
        """(tolerance at distance 0, growth per unit of distance) of the chords, chart units (S2xR:
        metric, which its walk scales to the chart): the given tolerance, or the quality's fraction
        of the pixel footprint (footprint()) times the geometry's chord_scale, which
        benchmarks/bench_front.py derives from the measured error/time front (docs/front.md, "The
        chord rule")."""
        if self.tolerance is not None:
            return self.tolerance, 0.0
        fraction = space.geometry.chord_scale * QUALITY[self.quality].footprint_fraction
        return fraction * footprint(space, pixel_angle, 0.0), fraction * pixel_angle


def footprint(space: Space, pixel_angle: float, depth):
    """The pixel footprint at geodesic distance depth that the qualities' bounds are fractions of
    (a straight-line view's, with distances counted from NEAR_FRACTION of the domain's metric
    extent behind the camera)."""
    return pixel_angle * (depth + NEAR_FRACTION * space.metric_extent)


def _whole(n) -> bool:
    return isinstance(n, (int, np.integer)) and not isinstance(n, bool)


@dataclass
class Result:
    passes: dict  # name -> (h, w, C) or (h, w) arrays of the rendered window, rows top-down
    stats: dict = field(default_factory=dict)

    def summary(self) -> str:
        s = self.stats
        rays = s.get("rays_traced", s["rays"])
        return (f"{rays} rays, {s['crossings_per_ray']:.2f} crossings/ray, {s['chords_per_ray']:.2f} chords/ray, "
                f"{s['hit_fraction'] * 100:.1f}% hits, {s['seconds']:.2f} s "
                f"({rays / max(s['seconds'], 1e-9) / 1e6:.2f} Mrays/s, {s['threads']} threads); "
                f"accuracy: {s['samples_per_pixel']} samples/pixel, pixel footprint {s['footprint']:.2e} "
                f"chart units at median depth; {s['bound']}; measured error {s['measured_error']:.1e} "
                f"chart units = {s['measured_error_pixels']:.2g} pixel footprints (re-traced at 1/{RETRACE_FACTOR} "
                f"of the tolerance; {s['retrace_changed'] * 100:.1f}% of them met another object), geodesic error "
                f"{s['geodesic_error']:.1e} (against the reference geodesic); {light_summary(s)}; "
                f"{illumination_summary(s)}")


def illumination_summary(s: dict) -> str:
    bounces = (f"path tracing, bounce limit {s['bounces']} ({s['bounce_paths_per_point']:.2f} bounce geodesics per "
               f"camera hit)" if s["bounces"] else "direct light only")
    noise = ("noise: one sample per pixel, not estimated" if s["noise"] is None else
             f"noise {s['noise']:.2e} (RMS standard error of the pixel means, from {s['samples_per_pixel']} samples)")
    return f"{bounces}, {noise}"


def light_summary(s: dict) -> str:
    emitters = (f"; {s['emitter_triangles']} emissive triangles in {s['emitter_copies']} copies, "
                f"{s['light_samples']} points sampled on them per shaded point" if s["emitter_triangles"] else "")
    return (f"light: {s['light_copies']} copies within reach {s['light_reach']:.3g} ({s['light_paths_per_point']:.1f} "
            f"geodesics per shaded point), energy beyond the reach up to the distance limit about "
            f"{s['light_energy_left_out']:.3g} x the summed (estimate){emitters}")


# --- compiling the scene -------------------------------------------------------------------------------


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
    for rings in range(1, g.copy_rings + 1):
        copies = []
        covered = np.zeros(len(X), bool)
        for M in space.neighbourhood(rings):
            Y = X @ M.T
            ok = g.charted(Y)  # the copy stays on the chart's side
            H = g.plane_coordinates(Y)
            outside = (H / np.linalg.norm(H, axis=1)[:, None]) @ C.T > 1e-9
            covered |= ok & ~outside.any(axis=1)
            # drop triangles wholly outside one face plane: they cannot meet the domain
            keep = ~np.any(outside[T[:, 0]] & outside[T[:, 1]] & outside[T[:, 2]], axis=1) & ok[T].all(axis=1)
            if keep.any():
                copies.append((Y, np.flatnonzero(keep), M @ home))
        if covered.all():
            break
    return copies, covered


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
        self.with_uvs = any(o.corner_uvs is not None for o in objects)
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
        self.material.append(obj.surface_materials()[1][kept] + self.material_offset[index])
        if self.with_uvs:
            self.uvs.append(obj.corner_uvs[kept] if obj.corner_uvs is not None else np.zeros((len(kept), 3, 2)))
        if self.with_normals:
            self.normals.append(normals())

    def arrays(self, triangles: int) -> dict:
        textures = {key: i for i, key in enumerate(self.textures)}

        def texture_index(t):
            return -1 if t is None else textures[id(t)]

        def stacked(parts, shape):
            return np.ascontiguousarray(np.concatenate(parts) if parts else np.zeros((0, *shape)), np.float32)

        out = dict(
            triangle_material=np.ascontiguousarray(np.concatenate(self.material) if self.material else
                                                   np.zeros(0), np.int32),
            material_color=np.array([m.color for m in self.materials], np.float32).reshape(-1, 3),
            material_emission=np.array([m.emission for m in self.materials], np.float32).reshape(-1, 3),
            material_color_texture=np.array([texture_index(m.color_texture) for m in self.materials], np.int32),
            material_emission_texture=np.array([texture_index(m.emission_texture) for m in self.materials], np.int32),
            material_one_sided=np.array([m.one_sided for m in self.materials], np.int32),
            material_scattering=np.array([[m.roughness, m.metallic, m.specular, m.ior] for m in self.materials],
                                         np.float32).reshape(-1, 4),
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
    T = obj.triangles[kept]
    n = _own_normals(obj, kept)
    used, local = np.unique(T, return_inverse=True)
    # the differential's columns: the images of the chart's unit vectors at each used vertex
    J = np.stack([g.tangent_to_chart(Y[used], g.tangent_to_model(x[used], np.broadcast_to(e, (len(used), 3))) @ M.T)
                  for e in np.eye(3)], axis=-1)
    Jt = np.swapaxes(J, 1, 2)[local.reshape(-1, 3)]  # (m, 3, 3, 3): J^T at each corner
    return _unit(np.linalg.solve(Jt, n[..., None])[..., 0])


def _own_normals(obj, kept):
    """The corner normals of the kept triangles, or for flat shading each face's chart normal at
    its corners."""
    if obj.corner_normals is not None:
        return obj.corner_normals[kept]
    P = obj.vertices[obj.triangles[kept]]
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
    normals = None if obj.corner_normals is None else _unit(fold.vectors(
        obj.vertices[obj.triangles], obj.corner_normals))
    return replace(obj, vertices=fold.points(obj.vertices), corner_normals=normals)


def _unit(n):
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)


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
        one = obj.placed(A[j:j + 1])
        if not np.all(g.in_chart(one.vertices)):
            raise SceneError(f"object {obj.name!r}: instance {j} has vertices outside the chart of {g.name} "
                             f"(the Klein chart is the open unit ball)")
        copies, covered = _object_copies(space, one, C)
        missing += not copies
        beyond += bool(copies) and not covered.all()
        for Y, kept, M in copies:
            if affine or np.allclose(M, np.eye(4), rtol=0, atol=1e-12):
                instances.append((M @ A[j])[None])
            else:
                flat.append((one, Y, kept, M))
    return np.concatenate(instances) if instances else np.zeros((0, 4, 4)), flat, missing, beyond


def default_light_reach(space: Space) -> float:
    """A finite group (S3): everything, both arcs (the long arcs are shorter than 2 pi). Else the
    geometry's multiple of the circumradius (light_reach_circumradii): E3 and S2xR twice it (E3: the
    domain's diameter at most, so every point has its light's own copy and the ring around it;
    S2xR: the copies one period up and down and the arcs round the sphere both ways), H3 and H2xR
    once (the light's nearest copy for a light near the centre), as the copies within R grow as
    exp(2R), exp(R); Nil, Sol and SL2 as their modules say. The cost: benchmarks/bench_light.py."""
    if space.group_order is not None:
        return 2 * space.geometry.diameter
    return space.geometry.light_reach_circumradii * space.circumradius


def light_reach_for(space: Space, settings: Settings) -> float:
    """The reach a render sums light over: the setting (or the default), within the distance limit."""
    reach = default_light_reach(space) if settings.light_reach is None else settings.light_reach
    return min(reach, settings.max_distance or space.max_distance)


def light_copies(space: Space, L, reach: float) -> np.ndarray:
    """The elements g (N,4,4) whose copies g L of the light L (a model point in the domain D) the
    tracer lights with, those that can lie within `reach` of D: in E3 and H3 those in tiles gD
    within reach of D (light_tiles) with every face plane of D within reach, in the coordinate
    domains (H2xR, S2xR, Nil, Sol, SL2) those within reach (cover_copies), in S3 all."""
    g = space.geometry
    if space.group_order is not None:  # finite (S3): all of it
        return np.array(space.elements_within(g.diameter + 1e-6))
    if not g.projective:
        return cover_copies(space, L, reach)
    tiles = light_tiles(space, reach)
    return tiles[[np.max(space.face_distances(g.normalize_point(M @ L))) <= reach + 1e-9 for M in tiles]]


def cover_copies(space: Space, L, reach: float) -> np.ndarray:
    """The elements g (N,4,4) of the copies g L of the light L (a model point in the domain D)
    within reach of D (the geometry's domain_distance), by a breadth-first walk from L over
    g L -> s g L (s a face's element), level by level in numpy, through the copies within
    reach + rho of D (rho = space.farthest_distance(L)). None is missed: the geodesic from L to a
    copy g L within reach passes through a chain of face-neighbouring tiles D, t1 D, t1 t2 D, ...,
    g D (g = t1 ... tk), and the walk reaches g L through the copies of the suffixes,
    tj ... tk L = (t1 ... tj-1)^-1 g L, each as near D as g L is to the tile t1 ... tj-1 D, which
    the geodesic crosses: within its length d(L, g L) <= reach + rho. A lower bound of the distance
    to D serves as well (the walk then passes more copies, and keeps more: the tracer drops those
    out of reach), and an upper bound of rho. Cached per light and reach."""
    cached = space.__dict__.setdefault("_cover_copies", {})  # the viewport renders one scene again and again
    (light,) = _copy_keys(np.asarray(L, float)[None])
    if (light, reach) not in cached:
        if len(cached) >= COVER_COPIES_CACHED:
            cached.pop(next(iter(cached)))
        cached[light, reach] = _walk_cover_copies(space, L, reach)
    return cached[light, reach]


def _copy_keys(Y) -> list[tuple]:
    """Keys of model points (rows): relative, as far copies have large model vectors, known to ~1e-16
    of their size."""
    return list(map(tuple, np.round(Y / np.linalg.norm(Y, axis=1)[:, None], 8).tolist()))


COVER_COPIES_CACHED = 64  # lights and reaches whose copies a space keeps


def _walk_cover_copies(space: Space, L, reach: float) -> np.ndarray:
    g = space.geometry
    rho = space.farthest_distance(L)
    steps = np.array([f.element for f in space.domain.faces])

    found = set(_copy_keys(np.asarray(L, float)[None]))
    kept = [np.eye(4)]
    frontier = np.eye(4)[None]
    while len(frontier):
        candidates = {}
        products = np.einsum("sij,njk->nsik", steps, frontier).reshape(-1, 4, 4)
        for k, M in zip(_copy_keys(g.normalize_point(products @ L)), products):
            candidates.setdefault(k, M)
        fresh = [k for k in candidates if k not in found]
        new = np.array([candidates[k] for k in fresh]).reshape(-1, 4, 4)
        distance = g.domain_distance(g.normalize_point(new @ L), space.domain)
        walk = distance <= reach + rho + 1e-9
        found.update(k for k, w in zip(fresh, walk) if w)
        kept += list(new[walk & (distance <= reach + 1e-9)])
        frontier = new[walk]
        if len(found) > LIGHT_TILE_LIMIT:
            raise RenderError(f"{space.name}: light reach {reach:g} needs more than {LIGHT_TILE_LIMIT} copies of the "
                              "light; choose a smaller light reach")
    # a copy whose key rounded two ways would light twice: keep one of each point
    kept = np.array(kept)
    Y = g.normalize_point(kept @ L)
    Y = Y / np.linalg.norm(Y, axis=1)[:, None]
    near = np.linalg.norm(Y[:, None] - Y[None], axis=2) < 1e-6
    return kept[~np.any(np.triu(near, 1), axis=0)]


LIGHT_TILE_LIMIT = 20000  # tiles a light reach may need (an H3 reach of a few domain sizes has more)


def light_tiles(space: Space, reach: float) -> np.ndarray:
    """The elements g (N,4,4) whose tiles gD can lie within reach of D (an infinite group), cached
    per reach. Such a tile has a vertex within reach of each face plane of D, and D a vertex within
    reach of each face plane of gD (else a plane separates them by more); those tiles are connected
    through faces, so a breadth-first walk over the face neighbours that pass both tests finds them
    (level by level in numpy; a tile is known by its image of the origin)."""
    cached = space.__dict__.setdefault("_light_tiles", {})
    if reach in cached:
        return cached[reach]
    g = space.geometry
    C = space.domain.covectors()
    corners = g.to_model(space.domain.vertices)
    steps = np.array([f.element for f in space.domain.faces])

    def near(X):  # (n, V, 4) -> whether each row has a point within reach of each face plane of D
        d = g.plane_distances(g.normalize_point(X.reshape(-1, 4)), C).reshape(len(X), -1, len(C))
        return np.all(d.min(axis=1) <= reach + 1e-9, axis=1)

    def key(M):
        return tuple(np.round(M[:, 3], 6))

    tiles = {key(np.eye(4)): np.eye(4)}
    frontier = np.eye(4)[None]
    while len(frontier):
        candidates = {}
        for M in (frontier[:, None] @ steps[None]).reshape(-1, 4, 4):
            candidates.setdefault(key(M), M)
        new = [k for k in candidates if k not in tiles]
        M = np.array([candidates[k] for k in new]).reshape(-1, 4, 4)
        pulled_back = np.linalg.solve(M, np.broadcast_to(corners.T, (len(M), 4, len(corners)))).swapaxes(1, 2)
        ok = near(np.einsum("nij,vj->nvi", M, corners)) & near(pulled_back)
        tiles.update((k, m) for k, m, keep in zip(new, M, ok) if keep)
        frontier = M[ok]
        if len(tiles) > LIGHT_TILE_LIMIT:
            raise RenderError(f"{space.name}: light reach {reach:g} needs more than {LIGHT_TILE_LIMIT} copies of the "
                              "domain; choose a smaller light reach")
    cached[reach] = np.array(list(tiles.values()))
    return cached[reach]


def geodesic_loop(space: Space) -> float:
    """The length after which every geodesic returns to its start: pi in S3 where -1 is in the group
    (the Poincare sphere), as X and -X are one point; inf elsewhere."""
    if space.geometry.name == "S3" and any(np.allclose(M, -np.eye(4)) for M in space.elements_within(math.pi + 1e-6)):
        return math.pi
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
                warnings.warn(f"object {obj.name!r}: {missing} of its {len(obj.instances)} instances lie outside the "
                              f"domain and its neighbouring copies: not shown", stacklevel=2)
            if beyond:
                warnings.warn(f"object {obj.name!r}: {beyond} of its {len(obj.instances)} instances reach beyond the "
                              f"copies of the domain around them: parts of them are missing", stacklevel=2)
        for placed in ([] if obj.instances is not None else [obj]) + mirrored:
            if not np.all(g.in_chart(placed.vertices)):
                raise SceneError(f"object {obj.name!r} has vertices outside the chart of {g.name} (the Klein chart is the open unit ball)")
            copies, covered = _object_copies(space, placed, C)
            flat += [(index, placed, *copy) for copy in copies]
            if not copies and placed is obj:
                warnings.warn(f"object {obj.name!r} lies outside the domain and its neighbouring copies: not shown", stacklevel=2)
            elif not covered.all():
                warnings.warn(f"object {obj.name!r} reaches beyond the copies of the domain around it: "
                              f"{int((~covered).sum())} of its vertices are farther out and parts of it are missing", stacklevel=2)
    # The triangles: the flat copies (mesh 0, placed by the identity), then each instanced mesh.
    verts, tris, owner = [], [], []
    surfaces = _Surfaces(scene.objects)
    offset = 0
    for index, source, Y, kept, M in flat:
        used, local = np.unique(source.triangles[kept], return_inverse=True)
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
            mesh_first_triangle=np.array(first, np.int32), instance_mesh=np.array(mesh_of, np.int32),
            instance_transform=np.ascontiguousarray(np.vstack([np.reshape(m, (-1, 4, 4)) for m in maps_of])[:, :3]),
            instance_object=np.array(object_of, np.int32))
    V = np.vstack(verts) if verts else np.zeros((0, 3))
    T = np.vstack(tris).astype(np.int32) if tris else np.zeros((0, 3), np.int32)
    O = np.concatenate(owner) if owner else np.zeros(0, np.int32)
    colors = np.array([o.color for o in scene.objects], np.float32).reshape(-1, 3)
    emission = np.array([o.emission for o in scene.objects], np.float32).reshape(-1, 3)
    lifts, axes, of_lift, radiance = [], [], [], []
    for i, light in enumerate(scene.lights):
        if not np.all(g.in_chart(light.position)):
            raise SceneError(f"light {i} at {light.position} is outside the chart of {g.name}")
        if not (math.isfinite(light.power) and light.power >= 0):
            raise SceneError(f"light {i}: power must be a finite number >= 0, got {light.power}")
        # a folded space's double cover holds the light's image under the fold too
        images = [(light.position, light.spot_direction)] + ([] if space.fold is None else [(
            space.fold.points(light.position),
            None if light.spot_direction is None else space.fold.vectors(light.position, light.spot_direction))])
        for position, direction in images:
            copies, light_axes = _light_lifts(space, position, direction, i, light_reach)
            lifts += copies
            axes += light_axes
            of_lift += [i] * len(copies)
        radiance.append(np.asarray(light.color, float) * light.power)
    return dict(
        geometry=g.name, face_covectors=np.ascontiguousarray(space.domain.covectors()),
        face_maps=np.ascontiguousarray(np.array([f.pairing for f in space.domain.faces])),
        vertices=np.ascontiguousarray(V, np.float64), triangles=np.ascontiguousarray(T),
        triangle_object=np.ascontiguousarray(O), object_color=colors, object_emission=emission,
        **surfaces.arrays(len(T)), **instancing,
        light_lifts=np.array(lifts, np.float64).reshape(-1, 4), light_of_lift=np.array(of_lift, np.int32),
        light_radiance=np.array(radiance, np.float32).reshape(-1, 3), light_reach=light_reach,
        geodesic_loop=geodesic_loop(space), **_spot_arrays(scene.lights, axes),
        **_emitter_arrays(space, scene, light_reach),
    )


def _light_lifts(space: Space, position, direction, index: int, reach: float):
    """The copies of light `index` at `position` that the tracer lights with (model points,
    light_copies), and the unit axis at each where it is a spot light along `direction` (else zero)."""
    g = space.geometry
    try:  # its copies are taken around the domain, so start from the copy inside
        L, _, M0 = space.bring_inside(g.to_model(position))
    except SpaceError as exc:
        raise SceneError(f"light {index}: {exc}") from None
    elements = light_copies(space, L, reach)
    axis = np.zeros(4)
    if direction is not None:
        axis = g.normalize_tangent(L, M0 @ g.tangent_to_model(position, direction))
    return [g.normalize_point(M @ L) for M in elements], [M @ axis for M in elements]


def _spot_arrays(lights, axes) -> dict:
    """The tracer's cones (Cycles' smoothstep, scene.PointLight.cone) and axes where a light is a spot."""
    if not any(light.spot_direction is not None for light in lights):
        return {}
    return dict(light_cone=np.array([light.cone() for light in lights], np.float64).reshape(-1, 2),
                light_axis=np.array(axes, np.float64).reshape(-1, 4))


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
    for index, obj in enumerate(scene.objects):
        materials, of_triangle = obj.surface_materials()
        glow = np.array([m.emission * (1.0 if m.emission_texture is None else
                                       m.emission_texture[..., :3].reshape(-1, 3).mean(axis=0)) for m in materials])
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
    return dict(emitter_triangles=np.ascontiguousarray(np.concatenate(triangles), np.float64),
                emitter_radiance=np.ascontiguousarray(np.concatenate(radiance), np.float32),
                emitter_one_sided=np.concatenate(one_sided), emitter_group=np.concatenate(group),
                emitter_copies=np.ascontiguousarray(np.concatenate(copies), np.float64),
                emitter_copy_group=np.concatenate(copy_group))


def core_scene(data: dict):
    """The core's record of a compiled scene (compile_scene's arrays): a thurston_core.Scene whose
    parts take the arrays of their fields' names (a part's optional arrays left out: None)."""
    import thurston_core as core

    kinds = dict(domain=core.Domain, meshes=core.Meshes, surfaces=core.Surfaces, lights=core.Lights,
                 instances=core.Instances, emitters=core.Emitters)
    given = {part: {name: value for name, value in data.items() if hasattr(kind, name)} for part, kind in kinds.items()}
    unknown = set(data) - {"geometry"} - set().union(*given.values())
    if unknown:
        raise TypeError(f"no part of the core's scene takes {sorted(unknown)}")
    return core.Scene(data["geometry"], **{part: kinds[part](**arrays) for part, arrays in given.items()})


def make_tracer(space: Space, scene: Scene, threads: int = 0, light_reach: float | None = None):
    """The C++ tracer for a scene, summing light over light_reach (None: default_light_reach); what
    the core rejects (ValueError) is raised as RenderError."""
    import thurston_core

    data = compile_scene(space, scene, light_reach)
    try:
        return thurston_core.Tracer(core_scene(data), threads=threads)
    except thurston_core.ThreadStartError as exc:
        raise RenderError(f"{exc}; ask for fewer threads") from None
    except ValueError as exc:
        raise RenderError(f"the tracer rejected the scene: {exc}") from None


def trace(tracer, origins, directions, max_distance, max_crossings, tolerance=1e-3, tolerance_per_distance=0.0,
          shade=True, progress=None, fog=None, light_samples=1, seed=0, bounces=0):
    """tracer.trace, with what the core rejects (ValueError) raised as RenderError. Exceptions
    from the progress callback pass through unchanged (they are the caller's, not the input's)."""
    raised = []

    def report(done, total):
        try:
            return progress(done, total)
        except BaseException as exc:
            raised.append(exc)
            raise

    try:
        return tracer.trace(origins, directions, max_distance, max_crossings, shade=shade,
                            progress=None if progress is None else report, tolerance=tolerance,
                            tolerance_per_distance=tolerance_per_distance, fog=fog or math.inf,
                            light_samples=light_samples, seed=seed, bounces=bounces)
    except ValueError as exc:
        if raised:
            raise
        raise RenderError(f"the tracer rejected the rays: {exc}") from None


# --- camera --------------------------------------------------------------------------------------------
def camera_frame(space: Space, camera: Camera):
    """Camera point (model) brought into the domain and an orthonormal frame (forward, right, up)
    there in the metric."""
    g = space.geometry
    p = np.asarray(camera.position, float)
    if not (np.all(np.isfinite(p)) and g.in_chart(p)):
        raise RenderError(f"camera position {p.tolist()} is not a point of {g.name}")
    f, u = np.asarray(camera.forward, float), np.asarray(camera.up, float)
    for label, v in (("forward", f), ("up", u)):
        if not np.all(np.isfinite(v)) or not np.any(v):
            raise RenderError(f"camera {label} {v.tolist()} must be a finite non-zero vector")
    f, u = f / np.abs(f).max(), u / np.abs(u).max()  # only the directions count (1e200 or 1e-200 alike)
    r = np.cross(f, u)
    if not np.linalg.norm(r) > 1e-12 * np.linalg.norm(f) * np.linalg.norm(u):
        raise RenderError(f"camera forward {np.asarray(camera.forward, float).tolist()} and up "
                          f"{np.asarray(camera.up, float).tolist()} are parallel")
    frame = [g.tangent_to_model(p, v) for v in (f, r, u)]
    try:
        X, _, M = space.bring_inside(space.to_model(p[None], label=None)[0])
    except SpaceError as exc:
        raise RenderError(f"camera: {exc}") from None
    basis = []
    for v in frame:
        v = M @ v
        for b in basis:
            v = v - g.dot(X, v, b) * b
        basis.append(g.normalize_tangent(X, v))
    return X, basis


def view_directions(camera: Camera, settings: Settings, jitter=(0.5, 0.5)):
    """Unit directions of the window's pixels in the camera's orthonormal frame: the components
    (forward, right, up), each (h, w), rows top-down. The forward component is the cosine between a
    ray's initial direction and the optical axis."""
    W, H = settings.width, settings.height
    x0, y0, w, h = settings.window
    j = (x0 + np.arange(w) + jitter[0]) / W
    i = (y0 + np.arange(h) + jitter[1]) / H
    if settings.projection == "perspective":
        t = math.tan(math.radians(camera.fov) / 2)
        sx = (2 * j - 1 + 2 * camera.shift[0]) * t
        sy = ((1 - 2 * i) * H / W + 2 * camera.shift[1]) * t
        a, b, c = np.ones((h, w)), np.broadcast_to(sx, (h, w)), np.broadcast_to(sy[:, None], (h, w))
        n = np.sqrt(a * a + b * b + c * c)
        return a / n, b / n, c / n
    # equirectangular: longitude 0 is forward, increasing to the right; latitude up
    lon = (2 * j - 1) * math.pi
    lat = (0.5 - i) * math.pi
    return (np.cos(lat)[:, None] * np.cos(lon)[None, :], np.cos(lat)[:, None] * np.sin(lon)[None, :],
            np.broadcast_to(np.sin(lat)[:, None], (h, w)))


def camera_rays(space: Space, camera: Camera, settings: Settings, jitter=(0.5, 0.5), frame=None, view=None):
    """Origins and unit directions (model) for every pixel of the window, rows top-down. `frame`:
    the result of camera_frame(space, camera), computed once per render and passed in for every
    sample; `view`: view_directions(camera, settings, jitter), where the caller has it. Rays start
    at their clip start (clip_range) along their geodesics, moved into the domain."""
    g = space.geometry
    X, (f, r, u) = frame if frame is not None else camera_frame(space, camera)
    a, b, c = view if view is not None else view_directions(camera, settings, jitter)
    D = np.ascontiguousarray((a[..., None] * f + b[..., None] * r + c[..., None] * u).reshape(-1, 4))
    origins = np.broadcast_to(X, (len(D), 4)).copy()
    if camera.clip_start > 0:
        origins, D = g.geodesic(origins, D, clip_range(camera, settings, a, math.inf)[0])
        origins, D, _ = space.move_inside(origins, D)
        origins, D = np.ascontiguousarray(origins, float), np.ascontiguousarray(D, float)
    return origins, D


def clip_range(camera: Camera, settings: Settings, along_axis, reach: float):
    """Per ray of the window, the geodesic distances (start, end) between which it sees: Blender's
    clipping, by planes square to the view axis at the clip distances (the ray's distance over its
    cosine to the axis, `along_axis`: view_directions' first part; panoramas: spheres), the end no
    farther than `reach`."""
    cos = np.ravel(along_axis) if settings.projection == "perspective" else 1.0
    start = np.broadcast_to(camera.clip_start / cos, (settings.window[2] * settings.window[3],))
    return start, np.minimum(reach, (camera.clip_end or math.inf) / cos)


def _miss_beyond(out: dict, limit):
    """Hits farther than each ray's limit (its clip end) become misses at the distance limit."""
    beyond = out["depth"] > limit
    if not beyond.any():
        return
    out["depth"][beyond] = np.inf
    out["stop"][beyond] = STOP_REASONS.index("distance")
    out["object"][beyond] = -1
    out["color"][beyond] = 0
    for name in ("normal", "position", "error"):
        out[name][beyond] = np.nan


CENTRE = (0.5, 0.5)


def _sample_offsets(n):
    """n sub-pixel positions (x, y in [0, 1)) for the colour, stratified and jittered, the jitter
    antithetic: every sample is paired with its mirror image through the pixel centre, so the mean
    position is exactly the centre and no part of the pixel counts twice.
    n = k * k (the quality levels 1, 4, 16): one sample in each of the k x k sub-squares.
    Other n: n-rooks (a Latin square): one sample in each of n columns and in each of n rows of
    width 1/n, the rows a random permutation of the columns that commutes with the mirror.
    A stratum that is its own mirror image (odd k, odd n) has its sample at the centre."""
    rng = np.random.default_rng(12345)
    k = math.isqrt(n)
    if k * k == n:
        m = k
        strata = [(a, b) for a in range(k) for b in range(k)]
    else:  # n-rooks: column i, row sigma(i), sigma(n - 1 - i) = n - 1 - sigma(i)
        m = n
        half = n // 2
        pi = rng.permutation(half)
        flip = rng.random(half) < 0.5
        sigma = np.empty(n, int)
        for i in range(half):
            sigma[i] = n - 1 - pi[i] if flip[i] else pi[i]
            sigma[n - 1 - i] = n - 1 - sigma[i]
        if n % 2:
            sigma[half] = half
        strata = [(i, int(sigma[i])) for i in range(n)]
    index = {s: i for i, s in enumerate(strata)}
    offsets = [None] * n
    for i, (a, b) in enumerate(strata):
        mirror = index[(m - 1 - a, m - 1 - b)]
        if mirror == i:
            offsets[i] = CENTRE
        elif mirror > i:
            ja, jb = rng.random(2)
            offsets[i] = ((a + ja) / m, (b + jb) / m)
            offsets[mirror] = ((m - 1 - a + 1 - ja) / m, (m - 1 - b + 1 - jb) / m)
    return offsets


# --- rendering -----------------------------------------------------------------------------------------
def render(space: Space, scene: Scene, settings: Settings, camera: Camera | None = None,
           progress=None, tracer=None) -> Result:
    """Render a view. progress(done, total) -> bool is called during tracing (False cancels).
    Raises RenderError for settings that cannot be rendered, a size too large for this machine's
    memory (checked before anything is allocated) and a MemoryError on the way."""
    settings.check()
    try:
        return _render(space, scene, settings, camera, progress, tracer)
    except MemoryError:
        raise RenderError(f"out of memory rendering {settings.width}x{settings.height} "
                          f"(about {memory_needed(settings.width, settings.height) / 2**30:.1f} GiB needed)") from None


def _render(space, scene, settings, camera, progress, tracer) -> Result:
    """render() after the settings' check.
    Colour: the average of the stratified samples of _sample_offsets. The other passes (depth,
    normal, position, object, crossings, stop): the ray through the pixel centre, traced unshaded
    on its own unless a colour sample lies at the centre (one sample per pixel, odd counts)."""
    camera = camera or scene.camera or Camera(space.camera.position, space.camera.forward, space.camera.up, space.camera.fov)
    if not (0 < camera.fov < 180):
        raise RenderError(f"camera field of view must be between 0 and 180 degrees, got {camera.fov}")
    reach = settings.max_distance or space.max_distance
    if not (0 <= camera.clip_start < min(reach, camera.clip_end or math.inf)):
        raise RenderError(f"camera clip start {camera.clip_start} must be at least 0 and less than the clip end "
                          f"({camera.clip_end}) and the distance the rays reach ({reach})")
    max_crossings = space.max_crossings if settings.max_crossings is None else settings.max_crossings
    t0 = time.perf_counter()
    frame = camera_frame(space, camera)  # once: bring_inside and the re-orthonormalised frame
    tracer = tracer or make_tracer(space, scene, settings.threads, light_reach_for(space, settings))
    offsets = _sample_offsets(settings.samples_per_pixel)
    W = settings.width
    _, _, w, h = settings.window  # the pixels rendered
    pixel_angle = (math.radians(camera.fov) if settings.projection == "perspective" else 2 * math.pi) / W
    tolerances = settings.tolerances(space, pixel_angle)
    shade = settings.shading == "lambert"
    # (jitter, shade, is colour sample): the centre pass first where no colour sample gives it
    jobs = [(o, shade, True) for o in offsets]
    if CENTRE not in offsets:
        jobs.insert(0, (CENTRE, False, False))
    pixels = w * h
    total = len(jobs) * pixels
    color_sum = None
    brightness_squares = np.zeros(w * h)  # per pixel: the sum over samples of (mean of RGB)^2
    hit_sum = np.zeros(w * h)
    first = None
    chords = light_failures = light_paths = shaded_points = bounce_paths = 0
    light_energy = 0.0
    for k, (jitter, shaded, colour) in enumerate(jobs):
        view = view_directions(camera, settings, jitter)
        origins, directions = camera_rays(space, camera, settings, jitter, frame=frame, view=view)
        # every ray is traced from its clip start, as far as this sample's farthest clip end needs
        start, end = clip_range(camera, settings, view[0], reach)
        limits = (float(np.max(end - start)), max_crossings, *tolerances)
        base = k * pixels
        report = None if progress is None else (lambda done, _n, base=base: progress(base + done, total))
        out = trace(tracer, origins, directions, *limits, shade=shaded, progress=report, fog=settings.fog,
                    light_samples=settings.light_samples, seed=settings.seed + k, bounces=settings.bounces)
        if np.any(out["stop"] == 3):
            raise Cancelled("render cancelled")
        _miss_beyond(out, end - start)
        chords += int(out["chords"])
        light_failures += int(out["light_failures"])
        light_paths += int(out["light_paths"]) + int(out["emitter_paths"])
        light_energy += float(out["light_energy"]) + float(out["emitter_energy"])
        bounce_paths += int(out["bounce_paths"])
        shaded_points += int(np.sum(out["stop"] == 0)) if shaded else 0
        if jitter == CENTRE:
            first, first_start, first_limits = out, start, limits
            sample = _error_sample(out, space.geometry)
            probe = (origins[sample], directions[sample])
        del origins, directions
        if colour:
            hit_sum += out["stop"] == 0
            color = _colorize(out, settings, space)
            brightness_squares += color.mean(axis=1) ** 2
            if color_sum is None:
                color_sum = color
            else:
                color_sum += color
            del color
        del out
    seconds = time.perf_counter() - t0
    position, normal = own_hits(space, first)
    passes = {
        "color": (color_sum / len(offsets)).reshape(h, w, 3).astype(np.float32),
        # the colour of a miss is 0, so the colour is premultiplied by this alpha
        "alpha": (hit_sum / len(offsets) if settings.transparent else np.ones(w * h)).reshape(h, w).astype(np.float32),
        "depth": (first["depth"] + first_start).reshape(h, w),
        "normal": normal.reshape(h, w, 3),
        "position": position.reshape(h, w, 3),
        "object": first["object"].reshape(h, w),
        "crossings": first["crossings"].reshape(h, w),
        "stop": first["stop"].reshape(h, w),
    }
    hits = first["stop"] == 0
    median_depth = float(np.median(first["depth"][hits])) if hits.any() else 0.0
    origins, directions = probe
    measured, measured_pixels, changed = retrace_error(space, tracer, origins, directions, first, sample, first_limits,
                                                       pixel_angle)
    stats = {
        "rays": len(offsets) * pixels, "rays_traced": total, "chords": chords, "seconds": seconds,
        "chords_per_ray": chords / total, "threads": tracer.num_threads,
        "crossings_per_ray": float(first["crossings"].mean()), "hit_fraction": float(hits.mean()),
        "samples_per_pixel": len(offsets), "triangles": tracer.num_triangles,
        "instances": tracer.num_instances, "instanced_triangles": tracer.num_instanced_triangles,
        # angular size of a pixel over sqrt(samples), at the median hit depth, in chart-scale units
        "footprint": pixel_angle / math.sqrt(len(offsets)) * median_depth,
        "tolerance": tolerances[0], "tolerance_per_distance": tolerances[1],
        "bound": accuracy_bound(space, settings, tolerances),
        # the per-ray error estimate of the hits: the largest and the median, chart units
        "error_estimate_max": float(np.max(first["error"][hits])) if hits.any() else 0.0,
        "error_estimate_median": float(np.median(first["error"][hits])) if hits.any() else 0.0,
        # measured: sampled hits traced again at 1/RETRACE_FACTOR of the tolerance (the largest
        # distance of a hit from the re-traced geodesic, in chart units and pixel footprints, and
        # the fraction of them that met another object)
        "measured_error": measured, "measured_error_pixels": measured_pixels, "retrace_changed": changed,
        # measured: the largest distance of a (sampled) hit point from the reference geodesic
        "geodesic_error": geodesic_error(space, origins, directions, first["depth"][sample],
                                         first["position"][sample]),
        "light_failures": light_failures,
        "bounces": settings.bounces, "bounce_paths_per_point": bounce_paths / shaded_points if shaded_points else 0.0,
        "noise": pixel_noise(color_sum, brightness_squares, len(offsets)),
        **light_stats(space, settings, tracer, light_paths, light_energy, shaded_points),
        "stop_counts": {name: int((first["stop"] == i).sum()) for i, name in enumerate(STOP_REASONS)},
    }
    return Result(passes, stats)


def pixel_noise(color_sum, brightness_squares, n: int) -> float | None:
    """The RMS over the pixels of the standard error of each pixel's mean brightness (mean of RGB),
    from the spread of its n samples (None for one sample). The samples of a pixel are stratified
    over it, so across its edges this overstates the error of the mean; inside surfaces it measures
    the Monte Carlo noise (light samples, bounces)."""
    if n < 2:
        return None
    mean = color_sum.mean(axis=1) / n
    variance = np.maximum(brightness_squares / n - mean ** 2, 0.0) * n / (n - 1)
    return float(np.sqrt(np.mean(variance / n)))


def light_stats(space: Space, settings: Settings, tracer, paths: int, energy: float, shaded: int) -> dict:
    """The light a render summed: its reach, the copies of the lights the tracer has, the light paths
    per shaded point, and the energy left out beyond the reach (up to the distance limit D, within
    the geometry's longest geodesic to a light: 2 pi in S3), relative to what was summed (before
    cosines and shadows, averaged over the shaded points). The estimate takes the copies of a light
    of power p as spread uniformly, 1/vol per volume: a shell of radius r holds area(r) / vol of
    them and each sends p / area(r), so the part from R to D is 4 pi p (D - R) / vol in E3, H3
    and S3 alike (with fog f: 4 pi p f (exp(-R/f) - exp(-D/f)) / vol), and in every geometry: averaged
    over the points of the space, the geodesics from the light of lengths in [r, r + dr] bring
    4 pi dr p / vol (the exponential map's Jacobian, which the falloff divides by, is the change of
    variables from the light's directions to the points). Without the limit the sum diverges
    (Olbers) wherever it is not cut at S3's two arcs."""
    reach = tracer.light_reach
    longest = min(settings.max_distance or space.max_distance, 2 * space.geometry.diameter)
    if reach >= longest:
        left_out = 0.0
    else:
        f = settings.fog
        shell = f * (math.exp(-reach / f) - math.exp(-longest / f)) if f else longest - reach
        left_out = 4 * math.pi * tracer.light_power * shell / space.volume
    summed = energy / shaded if shaded else 0.0
    return {"light_copies": tracer.num_light_lifts, "light_paths_per_point": paths / shaded if shaded else 0.0,
            "emitter_triangles": tracer.num_emitter_triangles, "emitter_copies": tracer.num_emitter_copies,
            "light_samples": settings.light_samples, "light_reach": reach,
            "light_energy_left_out": left_out / summed if summed > 0 else (0.0 if left_out == 0 else math.inf)}


def accuracy_bound(space: Space, settings: Settings, tolerances) -> str:
    """The accuracy a render promises, in words."""
    if space.geometry.projective:
        return "geodesics exact (chart lines)"
    if settings.tolerance is not None:
        return f"hit positions within {settings.tolerance:.1e} chart units of the geodesic's"
    return (f"hit positions within {QUALITY[settings.quality].footprint_fraction:g} of the pixel footprint "
            f"(chord tolerance {tolerances[0]:.1e} + {tolerances[1]:.1e} per unit distance)")


ERROR_SAMPLES = 1000  # hit pixels checked for the measured errors


def _error_sample(out, geometry, n=ERROR_SAMPLES):
    """Indices of up to n hit rays within the geometry's reference depth, drawn at random (fixed
    seed)."""
    ok = (out["stop"] == 0) & (out["depth"] <= geometry.reference_depth)
    hit = np.flatnonzero(ok)
    if len(hit) > n:
        hit = np.sort(np.random.default_rng(2024).choice(hit, n, replace=False))
    return hit


def _image_distance(space: Space, X, Z) -> np.ndarray:
    """The distance between model points X and the nearest copy of Z around the domain (points on
    a face have two images), for nearby points."""
    g = space.geometry
    best = np.full(len(X), np.inf)
    for M in space.neighbourhood(1):
        best = np.minimum(best, np.asarray(g.chord_distance(X, Z @ np.asarray(M, Z.dtype).T), float))
    return best


PATH_SAMPLES = 200  # of them, hits whose path error is measured (one re-trace each)


def retrace_error(space: Space, tracer, origins, directions, out, sample, limits, pixel_angle):
    """The measured error: sampled hit rays traced again at 1/RETRACE_FACTOR of the tolerance.
    Returns (error, pixels, changed): the largest distance between a hit point and the re-traced
    geodesic at the hit's arclength (chart units, and over the pixel footprint there), and the
    fraction of the sampled rays that met another object (or none) when re-traced with the scene:
    silhouettes the chords moved."""
    if len(sample) == 0:
        return 0.0, 0.0, 0.0
    max_distance, max_crossings, tolerance, per_distance = limits
    fine = (tolerance / RETRACE_FACTOR, per_distance / RETRACE_FACTOR)
    P, D = np.ascontiguousarray(origins), np.ascontiguousarray(directions)
    again = trace(tracer, P, D, max_distance, max_crossings, *fine, shade=False)
    changed = float(np.mean(again["object"] != out["object"][sample]))
    g = space.geometry
    path = make_tracer(space, Scene(), threads=1)  # the geodesics alone, one ray at a time
    paths = np.linspace(0, len(sample) - 1, min(len(sample), PATH_SAMPLES)).astype(int)
    depth = out["depth"][sample][paths]
    ends = np.array([trace(path, P[i:i + 1], D[i:i + 1], depth[k], max_crossings, *fine, shade=False)["end"][0]
                     for k, i in enumerate(paths)])
    error = _image_distance(space, g.to_model(out["position"][sample][paths]), g.to_model(ends))
    return float(error.max()), float((error / footprint(space, pixel_angle, depth)).max()), changed


def geodesic_error(space: Space, origins, directions, depth, position) -> float:
    """The largest distance between traced hit points (chart, in the domain) and the reference
    geodesic: the point at the hit's arclength along the geodesic from the ray's origin with its
    direction, computed by the geometry's own reference (closed forms in extended precision for
    E3, S3, H3; Nil's closed form; Sol's integrator) in the universal cover, brought into the
    domain by the face pairings and matched over the ring of copies around the domain. What this
    measures is the drift the tracer accumulates chord by chord through the pairings' matrices,
    renormalisations and flows; it does not see errors of the scene's triangles (those move the
    hit along the geodesic, not off it). 0.0 where there are no hits."""
    if len(depth) == 0:
        return 0.0
    g = space.geometry
    ld = np.longdouble
    Y, _ = g.geodesic(np.asarray(origins, ld), np.asarray(directions, ld), np.asarray(depth, ld))
    try:
        Z, _, _ = space.move_inside(Y)
    except SpaceError as exc:
        raise RenderError(f"measuring the geodesic error: {exc}") from None
    X = np.asarray(g.to_model(np.asarray(position, float)), ld)
    return float(_image_distance(space, X, Z).max())


def _colorize(out, settings: Settings, space: Space):
    hit = out["stop"] == 0
    mode = settings.shading
    if mode == "lambert":
        color = out["color"].astype(np.float64)
    elif mode == "normal":
        color = np.where(hit[:, None], 0.5 + 0.5 * np.nan_to_num(out["normal"]), 0.0)
    elif mode == "position":
        lo, hi = space.domain.vertices.min(axis=0), space.domain.vertices.max(axis=0)
        color = np.where(hit[:, None], np.clip((np.nan_to_num(out["position"]) - lo) / (hi - lo), 0, 1), 0.0)
    elif mode == "depth":
        d = np.where(hit, out["depth"], 0.0)
        scale = np.percentile(d[hit], 95) if hit.any() else 1.0
        color = np.repeat(np.where(hit, 1 - np.clip(d / max(scale, 1e-12), 0, 1), 0.0)[:, None], 3, axis=1)
    elif mode == "crossings":
        n = out["crossings"].astype(np.float64)
        color = np.repeat((n / max(1.0, n.max()))[:, None], 3, axis=1)
    else:  # object: a distinct hue per object index, base colour for lookups
        idx = out["object"]
        hue = (idx * 0.618034) % 1.0
        color = np.where(hit[:, None], np.stack([_hue(hue + o) for o in (0, 1 / 3, 2 / 3)], axis=1), 0.0)
    if settings.fog is not None:
        color = color * np.exp(-np.where(hit, out["depth"], 0.0) / settings.fog)[:, None]
    return color


def _hue(h):
    return 0.5 + 0.5 * np.cos(2 * math.pi * h)
