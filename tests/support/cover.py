"""Independent truth for depth: a geodesic's first entry into chart balls, found by a fine march of
the geometry's closed form in the universal cover (each piece carried into the domain by the
isometry that reduces its start), then a root of the distance to the ball's centre. The march is
the geometry's model (cover_first_hits) or the caller's own (first_hits: SL2's cover elements)."""

import math

import numpy as np
from scipy.optimize import brentq


def cover_first_hits(G, space, P, V, length, centres, outer, inner, step=0.01):
    """(t_outer, t_inner, margin): the first arclengths at which the geodesic (P, V) meets a chart
    sphere |x - c| = rho, for rho the circumscribed (`outer`) and inscribed (`inner`) radii of each
    centre's mesh (inf where it does not meet), and its closest approach to a circumscribed sphere."""
    t = np.arange(0.0, length + step, step)
    Y, _ = G.geodesic(P[None], V[None], t)
    _, _, M = space.move_inside(Y)

    def chart(k, s):
        X, _ = G.geodesic(P, V, s)
        return G.to_chart(M[k] @ X)

    x = G.to_chart(np.einsum("kij,kj->ki", M, Y))
    x_next = G.to_chart(np.einsum("kij,kj->ki", M[:-1], Y[1:]))  # each piece's end by its start's map
    return first_hits(t, x, x_next, chart, centres, outer, inner)


def first_hits(t, x, x_next, chart, centres, outer, inner):
    """cover_first_hits from a march: the reduced chart points x at the times t, each piece's end
    x_next reduced by its start's isometry, and chart(k, s), the point at s in [t[k], t[k + 1]]
    reduced by piece k's isometry."""
    centres, outer, inner = np.asarray(centres, float), np.asarray(outer, float), np.asarray(inner, float)
    margin = np.min(np.linalg.norm(x[:, None] - centres[None], axis=-1) - outer)
    start = np.linalg.norm(x[: len(t) - 1, None] - centres[None], axis=-1)  # (pieces, centres)
    end = np.linalg.norm(x_next[: len(t) - 1, None] - centres[None], axis=-1)
    found = []
    for rho in (outer, inner):
        entering = (start - rho > 0) & (end - rho <= 0)  # the pieces that enter a sphere
        pieces = np.flatnonzero(entering.any(axis=1))
        first = math.inf
        if len(pieces):
            k = int(pieces[0])
            i = int(np.argmax(entering[k]))  # the first sphere that piece enters
            c, r = centres[i], rho[i]
            first = brentq(lambda s: np.linalg.norm(chart(k, s) - c) - r, t[k], t[k + 1], xtol=1e-13)
        found.append(first)
    return found[0], found[1], margin


def check_depths(G, space, out, P, V, length, centres, outer, inner, truth=None):
    """Each traced ray against cover_first_hits (or truth(i), the same for ray i): a miss where the
    cover geodesic passes clear of every ball, a hit between the circumscribed and inscribed entries
    where it enters one (grazing rays are not compared). Returns (compared, hits)."""
    compared = hits = 0
    for i in range(len(P)):
        if truth is None:
            t_outer, t_inner, margin = cover_first_hits(G, space, P[i], V[i], length, centres, outer, inner)
        else:
            t_outer, t_inner, margin = truth(i)
        if math.isinf(t_outer) and margin > 0.01:
            assert out["stop"][i] == 1, i
            compared += 1
        elif math.isfinite(t_inner) and t_inner - t_outer < 0.01:  # not grazing
            assert out["stop"][i] == 0, i
            assert t_outer - 1e-5 <= out["depth"][i] <= t_inner + 1e-5, (i, t_outer, out["depth"][i], t_inner)
            compared += 1
            hits += 1
    return compared, hits


def assert_no_leak_at_the_prism_edges(space, half_height, ball_radius, seed, n=100_000):
    """n rays from inside a prism domain (an octagon times [-h, h]: genus2xs1, sl2), aimed at its
    vertices and (half of them) at points of its vertical edges: each stops by distance (empty
    scene) or hits (a ball at the centre), none escapes or stops otherwise, none ends outside."""
    import trimesh

    from thurston_addon import render
    from thurston_addon.scenes import Scene, SceneObject

    G = space.geometry
    rng = np.random.default_rng(seed)
    V0 = space.domain.vertices
    target = V0[rng.integers(len(V0), size=n)]
    target[n // 2 :, 2] = rng.uniform(-half_height, half_height, n - n // 2)
    x = 0.5 * space._interior_points(rng, n)
    P = G.to_model(x)
    V = G.normalize_tangent(P, G.tangent_to_model(x, target - x))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=ball_radius)
    for scene in (Scene(), Scene(objects=[SceneObject("ball", ball.vertices, ball.faces, (1, 1, 1))])):
        out = render.make_tracer(space, scene).trace(
            np.ascontiguousarray(P), np.ascontiguousarray(V), 8.0, 1000, shade=False, tolerance=1e-3
        )
        assert np.all((out["stop"] == 0) | (out["stop"] == 1)), np.bincount(out["stop"])
        assert np.all(np.isfinite(out["end"]))
        assert space.domain.contains(G.to_model(out["end"]), tol=1e-6).all()
