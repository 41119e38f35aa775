"""The presets the tests run over, taken from the spaces' own listing (spaces.preset_ids()) and
filtered by what a test needs of a space. BUILT_IN is the one list written by hand: the truth that
listing (and the command line's) is checked against."""

from __future__ import annotations

from functools import cache

import numpy as np

from thurston_addon import spaces

# The built-in presets and their geometries (with no THURSTON_SPACE_PATH set).
BUILT_IN = {
    "torus": "E3",
    "half_turn": "E3",
    "quarter_turn": "E3",
    "third_turn": "E3",
    "sixth_turn": "E3",
    "hantzsche_wendt": "E3",
    "poincare": "S3",
    "seifert_weber": "H3",
    "nil": "Nil",
    "sol": "Sol",
    "genus2xs1": "H2xR",
    "s2xs1": "S2xR",
    "rp3_rp3": "S2xR",
    "sl2": "SL2",
    "graph_flat": "graph",
    "graph_local": "graph",
    "graph_global": "graph",
    "graph_two": "graph",
    "graph_r3": "graph",
}

# Geometries the shared sweeps leave out, with why: graph spaces render in the pseudo-colour modes
# only (no point lights, no emitters' light) and their integrator makes the sweeps of 10^5-10^6 rays
# too slow for CI; tests/geometries/test_graph.py, tests/render/test_graph.py and the contract
# tests (test_contract.py, its own list) cover them.
SWEPT_APART = {"graph"}


@cache
def _space(sid):
    return spaces.load(sid)


def presets(where=lambda space: True) -> list[str]:
    """The listed preset ids, sorted, whose space satisfies `where` (of the geometries not in
    SWEPT_APART)."""
    return [sid for sid in spaces.preset_ids() if _space(sid).geometry.name not in SWEPT_APART and where(_space(sid))]


def _twists(space):
    """How many generators are not translations (their linear part not the identity)."""
    return sum(not np.allclose(np.asarray(M, float)[:3, :3], np.eye(3)) for M in space.generators)


def simplest_per_geometry(where=lambda space: True) -> list[str]:
    """One preset of each geometry among those satisfying `where`, sorted: the simplest of its
    geometry, unfolded and with the fewest generators that are not translations (E3: the torus,
    S2xR: S2 x S1)."""
    simplest = {}
    for sid in presets(where):
        space = _space(sid)
        key = (space.fold is not None, _twists(space), sid)
        if space.geometry.name not in simplest or key < simplest[space.geometry.name]:
            simplest[space.geometry.name] = key
    return sorted(key[-1] for key in simplest.values())
