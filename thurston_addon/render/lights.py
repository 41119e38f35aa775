"""Which copies of a light the tracer lights with: the light reach, the copies within it in the
coordinate domains (cover_copies) and the tiles within it in the projective ones (light_tiles)."""

from __future__ import annotations

import numpy as np

from ..spaces import DirichletSpace, Space
from .settings import RenderError, Settings


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
    if not isinstance(space, DirichletSpace):  # a coordinate domain: no tiling by Dirichlet cells
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
    (light,) = _copy_keys(space.geometry, np.asarray(L, float)[None])
    if (light, reach) not in cached:
        if len(cached) >= COVER_COPIES_CACHED:
            cached.pop(next(iter(cached)))
        cached[light, reach] = _walk_cover_copies(space, L, reach)
    return cached[light, reach]


def _copy_keys(g, Y) -> list[tuple]:
    """Keys of model points (rows): their geometry's point_coordinates, in which distinct copies stay
    apart (far copies have model vectors known to ~1e-16 of their size), rounded."""
    return list(map(tuple, np.round(g.point_coordinates(Y), 8).tolist()))


COVER_COPIES_CACHED = 64  # lights and reaches whose copies a space keeps


def _walk_cover_copies(space: Space, L, reach: float) -> np.ndarray:
    g = space.geometry
    rho = space.farthest_distance(L)
    steps = np.array([f.element for f in space.domain.faces])

    found = set(_copy_keys(g, np.asarray(L, float)[None]))
    kept = [np.eye(4)]
    frontier = np.eye(4)[None]
    while len(frontier):
        candidates = {}
        products = np.einsum("sij,njk->nsik", steps, frontier).reshape(-1, 4, 4)
        for k, M in zip(_copy_keys(g, g.normalize_point(products @ L)), products):
            candidates.setdefault(k, M)
        fresh = [k for k in candidates if k not in found]
        new = g.repair_products(np.array([candidates[k] for k in fresh]).reshape(-1, 4, 4))
        distance = g.domain_distance(g.normalize_point(new @ L), space.domain)
        walk = distance <= reach + rho + 1e-9
        found.update(k for k, w in zip(fresh, walk) if w)
        kept += list(new[walk & (distance <= reach + 1e-9)])
        frontier = new[walk]
        if len(found) > LIGHT_TILE_LIMIT:
            raise RenderError(
                f"{space.name}: light reach {reach:g} needs more than {LIGHT_TILE_LIMIT} copies of the "
                "light; choose a smaller light reach"
            )
    # a copy whose key rounded two ways would light twice: keep one of each point
    kept = np.array(kept)
    Y = g.point_coordinates(g.normalize_point(kept @ L))
    near = np.linalg.norm(Y[:, None] - Y[None], axis=2) < 1e-6
    return kept[~np.any(np.triu(near, 1), axis=0)]


LIGHT_TILE_LIMIT = 50000  # tiles a light reach may need (an H3 reach of a few domain sizes has more; the
# default reach of genus 3's bundles walks 21000 (H2xR) and 31000 (SL2~) copies, in a few seconds)


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
            raise RenderError(
                f"{space.name}: light reach {reach:g} needs more than {LIGHT_TILE_LIMIT} copies of the "
                "domain; choose a smaller light reach"
            )
    cached[reach] = np.array(list(tiles.values()))
    return cached[reach]
