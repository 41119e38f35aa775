"""SnapPy's closed hyperbolic manifolds as spaces (`snappy:NAME`): a census name or Dehn filling
SnapPy accepts (`snappy:m003(-3,1)`), the closed census by index (`snappy:closed:17`) or a few
named manifolds (`snappy:weeks`). SnapPy computes the Dirichlet domain and its face pairings; they
become a space file (H3, the pairings as generators, SnapPy's volume as the covolume) written to
the cache folder and loaded like any other, then checked against SnapPy: the domain's faces and
vertices, the relations of its edge cycles, its first homology. SnapPy (the package's `census`
extra) is imported only here, and only when such a name is asked for."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .dirichlet import DirichletSpace
from .homology import first_homology, homology_text, relation_residual
from .values import SpaceError
from .writing import cache_dir, file_name, write_space

PREFIX = "snappy:"
CLOSED_PREFIX = "closed:"  # snappy:closed:N, the N-th manifold of SnapPy's OrientableClosedCensus
NAMED = {"weeks": "m003(-3,1)", "meyerhoff": "m004(5,1)"}
SUMMARY = "a closed hyperbolic manifold SnapPy names (census name, Dehn filling, closed:N, weeks), e.g. snappy:m003(-3,1); needs the census extra"
RELATION_TOLERANCE = 1e-10  # the largest entry of an edge cycle's product minus the identity
# SnapPy's coordinates are (t, x, y, z) with the form diag(-1, 1, 1, 1); H3's are (x, y, z, t)
_TIME_LAST = [1, 2, 3, 0]
_CHECKS = "volume, relations, homology"


def is_snappy_name(name) -> bool:
    return isinstance(name, str) and name.startswith(PREFIX)


def _snappy():
    try:
        import snappy
    except ImportError:
        raise SpaceError(
            "snappy: spaces need SnapPy, the package's 'census' extra: pip install 'thurston[census]' "
            "(scripts/setup.sh installs it)"
        ) from None
    return snappy


def _manifold(snappy, name: str, high_precision: bool):
    """SnapPy's manifold of a name (after snappy:), in double or quad-double precision."""
    kind = snappy.ManifoldHP if high_precision else snappy.Manifold
    if name.startswith(CLOSED_PREFIX):
        index = name[len(CLOSED_PREFIX) :]
        count = len(snappy.OrientableClosedCensus)
        if not index.isdigit() or int(index) >= count:
            raise SpaceError(f"snappy:{name}: the closed census is indexed 0 to {count - 1}, got {index!r}")
        name = str(snappy.OrientableClosedCensus[int(index)])
    try:
        return kind(NAMED.get(name.lower(), name))
    except (OSError, ValueError, RuntimeError, IndexError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise SpaceError(
            f"snappy:{name}: SnapPy does not know this manifold ({first}); give a census name or Dehn "
            "filling such as m003(-3,1), or snappy:closed:N"
        ) from None


def _refuse_unless_closed_hyperbolic(M, name: str):
    if not M.is_orientable():
        raise SpaceError(f"snappy:{name} is not orientable: only closed orientable manifolds are supported")
    unfilled = [i for i, c in enumerate(M.cusp_info()) if c.get("filling", (0, 0)) == (0, 0) or c["is_complete"]]
    if unfilled:
        raise SpaceError(
            f"snappy:{name} has cusps ({len(unfilled)} left unfilled): cusped manifolds are not "
            f"supported, a ray would run into the cusp forever; fill every cusp, e.g. snappy:{M.name()}(5,1)"
        )
    for c in M.cusp_info():
        p, q = c["filling"]
        if p != int(p) or q != int(q) or math.gcd(int(p), int(q)) != 1:
            raise SpaceError(
                f"snappy:{name}: the Dehn filling ({p:g}, {q:g}) is not of two coprime integers: the filled "
                "space is an orbifold or a cone manifold, not a manifold"
            )
    kind = M.solution_type()
    if kind not in ("all tetrahedra positively oriented", "contains negatively oriented tetrahedra"):
        raise SpaceError(
            f"snappy:{name}: SnapPy finds no hyperbolic structure ({kind}): it is not a hyperbolic manifold"
        )


def _space_data(M, name: str, volume: float) -> tuple[dict, object]:
    """The space file's fields for SnapPy's Dirichlet domain of M (centred at the origin, which
    is the domain centre the space's construction uses), and the domain."""
    try:
        D = M.dirichlet_domain(centroid_at_origin=False)
    except (RuntimeError, ValueError) as exc:
        raise SpaceError(f"snappy:{name}: SnapPy cannot compute a Dirichlet domain ({exc})") from None
    generators = []
    for i, P in enumerate(D.pairing_matrices()):
        A = np.array([[float(P[r, c]) for c in range(4)] for r in range(4)])
        generators.append({"name": f"g{i}", "matrix": A[np.ix_(_TIME_LAST, _TIME_LAST)].tolist()})
    data = {
        "id": PREFIX + name,
        "name": f"{M} (SnapPy)",
        "geometry": "H3",
        "description": f"Closed hyperbolic manifold {M} from SnapPy: volume {volume:.10f}, H1 = {M.homology()}",
        "scale": 1.0,
        "max_distance": 12.0,
        "max_crossings": 48,
        "covolume": volume,
        "camera": {"position": [0.05, -0.08, 0.03], "forward": [0.2, 1.0, 0.1], "up": [0, 0, 1], "fov": 90},
        "generator": generators,
    }
    return data, D


def _checked(data: dict, D, M, source: str) -> DirichletSpace:
    """The space of the fields (validated on load, its volume SnapPy's), checked against SnapPy's
    domain and homology and its relations to RELATION_TOLERANCE; SpaceError saying which fails."""
    space = DirichletSpace(data, source)
    faces, vertices = len(space.domain.faces), len(space.domain.vertices)
    if (faces, vertices) != (D.num_faces(), D.num_vertices()):
        raise SpaceError(
            f"{source}: the domain has {faces} faces and {vertices} vertices, SnapPy's "
            f"{D.num_faces()} and {D.num_vertices()}"
        )
    residual = relation_residual(space)
    if residual > RELATION_TOLERANCE:
        raise SpaceError(
            f"{source}: the edge cycles' relations hold only to {residual:.2g}, not {RELATION_TOLERANCE:g}"
        )
    ours, theirs = first_homology(space), sorted(M.homology().coefficients, key=lambda d: (d == 0, d))
    if ours != theirs:
        raise SpaceError(f"{source}: the first homology is {homology_text(ours)}, SnapPy's {M.homology()}")
    return space


def census_file(name: str) -> Path:
    """The space file of `snappy:NAME` (name without the prefix), written to the cache folder if
    it is not there yet: from SnapPy's double-precision domain, or its quad-double one where the
    double one fails a check; SpaceError with both reasons where neither passes."""
    path = cache_dir("snappy") / file_name(name)
    if path.is_file():
        return path
    snappy = _snappy()
    reasons = []
    for high_precision in (False, True):
        precision = "quad-double" if high_precision else "double"
        M = _manifold(snappy, name, high_precision)
        _refuse_unless_closed_hyperbolic(M, name)
        try:
            volume = float(M.volume())
            data, D = _space_data(M, name, volume)
            _checked(data, D, M, f"snappy:{name} ({precision} precision)")
        except SpaceError as exc:
            reasons.append(str(exc))
            continue
        comment = (
            f"Written by Thurston from SnapPy {snappy.__version__}'s Dirichlet domain of {M} ({precision} precision).\n"
            + "".join(f"Double precision was not enough: {r}\n" for r in reasons)
            + f"Checked: {_CHECKS} against SnapPy. Edit freely; loading validates it again."
        )
        return write_space(path, data, comment)
    raise SpaceError(f"snappy:{name}: neither precision gives a valid space: " + "; ".join(reasons))
