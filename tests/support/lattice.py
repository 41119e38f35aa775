"""Truth for Nil's and Sol's lattices: a point of the universal cover reduced into the domain in
closed form and extended precision (Nil: the integer Heisenberg group; Sol: the monodromy power,
then the lattice of u1, u2), finished by Space.move_inside."""

import numpy as np

ld = np.longdouble
PHI = (1 + np.sqrt(ld(5))) / 2
SOL_PERIOD = 2 * np.log(PHI)  # the monodromy's shift in z
SOL_NORM = np.sqrt(1 + PHI * PHI)
SOL_U1 = np.array([1 / SOL_NORM, PHI / SOL_NORM], ld)  # the lattice of the fibre torus
SOL_U2 = np.array([-PHI / SOL_NORM, 1 / SOL_NORM], ld)


def lattice_reduction(sid, Y):
    """Affine matrices (n, 4, 4), extended precision, of the lattice elements that take the cover
    points Y (n, 4) into the domain, in closed form: Nil [-1/2, 1/2)^3 by the integer Heisenberg
    group (y, then x, which shifts z by a y, then z); Sol by the monodromy power that brings z
    into [-ln phi, ln phi), then the lattice of u1, u2."""
    Y = np.asarray(Y, ld)
    x, y, z = (Y[:, k] / Y[:, 3] for k in range(3))
    n = len(Y)
    M = np.zeros((n, 4, 4), ld)
    M[:, 3, 3] = 1
    half = ld(0.5)
    if sid == "nil":
        a, b = np.floor(x + half), np.floor(y + half)
        c = np.floor(z - a * (y - b) + half)
        # left multiplication by (a, b, c)^-1 = (-a, -b, -c + a b): (x - a, y - b, z - c + a b - a y)
        M[:, 0, 0] = M[:, 1, 1] = M[:, 2, 2] = 1
        M[:, 2, 1] = -a
        M[:, 0, 3], M[:, 1, 3], M[:, 2, 3] = -a, -b, -c + a * b
        return M
    k = np.floor(z / SOL_PERIOD + half)
    s = PHI ** (2 * k)  # the monodromy to the power -k: (phi^2k x, phi^-2k y, z - 2k ln phi)
    xs, ys = x * s, y / s
    i = np.floor(xs * SOL_U1[0] + ys * SOL_U1[1] + half)
    j = np.floor(xs * SOL_U2[0] + ys * SOL_U2[1] + half)
    M[:, 0, 0], M[:, 1, 1], M[:, 2, 2] = s, 1 / s, 1
    M[:, 0, 3] = -(i * SOL_U1[0] + j * SOL_U2[0])
    M[:, 1, 3] = -(i * SOL_U1[1] + j * SOL_U2[1])
    M[:, 2, 3] = -k * SOL_PERIOD
    return M


def into_domain(space, Y, V=None):
    """Cover points (and tangent vectors) reduced into the domain: the closed-form lattice
    reduction, then Space.move_inside. Returns (X, V, M), M the whole isometry."""
    Y = np.asarray(Y, ld)
    M = lattice_reduction(space.id, Y)
    X = np.einsum("nij,nj->ni", M, Y)
    W = None if V is None else np.einsum("nij,nj->ni", M, np.asarray(V, ld))
    X, W, R = space.move_inside(X, W)
    return X, W, np.einsum("nij,njk->nik", R, M)
