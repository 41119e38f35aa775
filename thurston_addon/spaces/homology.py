"""The group of a Dirichlet space as a presentation (its face pairings as generators, its edge
cycles as relations: Poincaré's polyhedron theorem), how far the matrices are from satisfying the
relations, and the first homology: the Smith normal form of the abelianised relations, in exact
integers."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Presentation:
    generators: list[int]  # a face index per generator (the face of the pair with the smaller index)
    relators: list[list[tuple[int, int]]]  # words: (generator, +1 or -1), in the order applied


def presentation(space) -> Presentation:
    """A Dirichlet space's group: a generator per pair of faces, a relator per edge cycle (walking
    around an edge, each crossed face contributes its pairing; their product is the identity)."""
    faces = space.domain.faces
    generators = [i for i, f in enumerate(faces) if i < f.partner]
    index = {face: k for k, face in enumerate(generators)}
    relators = []
    for cycle in space.edge_cycles:
        word = []
        for _, f in cycle:
            partner = faces[f].partner
            word.append((index[f], 1) if f in index else (index[partner], -1))
        relators.append(word)
    return Presentation(generators, relators)


def relation_residual(space) -> float:
    """The largest entry of (relator's product - identity) over the edge cycles, the products of
    the face pairings taken in the order the cycle applies them."""
    faces = space.domain.faces
    worst = 0.0
    for cycle in space.edge_cycles:
        P = np.eye(4)
        for _, f in cycle:
            P = faces[f].pairing @ P
        worst = max(worst, float(np.max(np.abs(P - np.eye(4)))))
    return worst


def abelianised(p: Presentation) -> list[list[int]]:
    """The relation matrix of the abelianised group: a row per relator, the exponent sum of each generator."""
    rows = []
    for word in p.relators:
        row = [0] * len(p.generators)
        for g, e in word:
            row[g] += e
        rows.append(row)
    return rows


def invariant_factors(rows: list[list[int]], n: int) -> list[int]:
    """The abelian group Z^n / (the rows' span) as its Smith normal form's factors: a 0 per free Z,
    d > 1 per Z/d (the factors dividing each other in order, then the zeros). Exact integers."""
    A = [list(map(int, r)) for r in rows if any(r)]
    diagonal = []
    while A and any(any(r) for r in A):
        # the pivot: the entry of least absolute value (elimination shrinks it until it divides its row and column)
        _, i, j = min((abs(v), i, j) for i, r in enumerate(A) for j, v in enumerate(r) if v)
        while True:
            p = A[i][j]
            done = True
            for k in range(len(A)):  # clear the column
                if k != i and A[k][j]:
                    q = A[k][j] // p
                    A[k] = [a - q * b for a, b in zip(A[k], A[i])]
                    if A[k][j]:
                        done = False
            for c in range(len(A[i])):  # clear the row
                if c != j and A[i][c]:
                    q = A[i][c] // p
                    for r in A:
                        r[c] -= q * r[j]
                    if A[i][c]:
                        done = False
            if not done:  # a smaller remainder: it becomes the pivot
                _, i, j = min(
                    (abs(v), k, c) for k, r in enumerate(A) for c, v in enumerate(r) if v and (k == i or c == j)
                )
                continue
            # the pivot must divide every other entry (else add that row and go on)
            bad = next((k for k, r in enumerate(A) if k != i and any(v % p for v in r)), None)
            if bad is None:
                break
            A[i] = [a + b for a, b in zip(A[i], A[bad])]
        diagonal.append(abs(A[i][j]))
        A = [r[:j] + r[j + 1 :] for k, r in enumerate(A) if k != i]
        n -= 1
    return sorted(d for d in diagonal if d != 1) + [0] * n


def homology_text(factors: list[int]) -> str:
    """An abelian group as SnapPy writes one: 'Z/5 + Z/5', 'Z + Z/2' (free part first), '0'."""
    free = ["Z"] * factors.count(0)
    return " + ".join(free + [f"Z/{d}" for d in factors if d]) or "0"


def first_homology(space) -> list[int]:
    """The invariant factors of H1 of a Dirichlet space (see invariant_factors)."""
    p = presentation(space)
    return invariant_factors(abelianised(p), len(p.generators))
